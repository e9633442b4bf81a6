"""A style's posture: the change it makes to the network's own pose, joint by joint, averaged over
neutral walks of the model's training data (a rotation vector per joint and style).

Where the input is an action the network never learnt (``runtime.stylizer``, pose "input"), the
network's identity and target outputs are both rebuilt from walks and waves, so the change between
them points anywhere (on held-out actions, a cosine of 0.2-0.6 with the same change on walks). The
posture is the part of a style that does not depend on the action (a bent back, lowered arms,
turned-in knees): the input's own pose turned by it keeps the action and shows the style the way it
shows on walks (measurements: docs/RESULTS.md, "Any action, any performer"). It is kept two ways:
per joint the mean rotation, and where the style moves the joint relative to the root along the
body's own axes (up from the hips to the head: the mean offset), which the stylizer then turns the
joints towards (``runtime.stylizer._reach``), as the same rotations move a body in another pose
elsewhere. Along the body's axes, not its heading's, a swimmer's back bends as a walker's does
(docs/RESULTS.md, "Any action, any performer"); model files measured before keep their heading
frame (``model.stored.posture_frame``).

``styleerd posture`` measures it once after training and stores it in the model file."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from tqdm import tqdm

from styleerd.data.datasets import data_root, find_clips, load_motion
from styleerd.data.windows import split_takes
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import quat
from styleerd.motion.kinematics import body_axes, forward_positions, heading_axes
from styleerd.motion.motion import Motion
from styleerd.runtime.stylizer import StreamStylizer

SECONDS = 12.0  # of each walk: enough steps for a stable mean; the shipped model's 71 walks take 25 s


def training_walks(model: GeneratorWeights, data_dir: str | None = None) -> Iterator[tuple[Motion, str]]:
    """(motion, content) of every neutral walk in the model's training split, cut to ``SECONDS``."""
    clips = find_clips(data_root(data_dir), model.meta["data"]["dataset"])
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    for c in clips:
        if split[c.name] == "train" and c.style == model.config.neutral_style and c.content.startswith("walk"):
            motion = load_motion(c)
            yield motion[: int(round(SECONDS * motion.fps))], c.content


def measure_posture(
    model: GeneratorWeights, walks: list[tuple[Motion, str]], frame: str = "body"
) -> tuple[np.ndarray, np.ndarray]:
    """Each style's posture over every frame of ``walks``, as the network gives it: ``[styles, J, 3]``
    the mean rotation vector of inv(identity) * styled per joint (its root's in the world), and
    ``[styles, J, 3]`` the mean of styled - identity joint positions relative to the root, in
    ``frame`` (the body's heading, or its own: ``model.stored.posture_frame``) on the input's pose
    (the skeleton's units)."""
    styles = model.config.styles
    neutral = styles.index(model.config.neutral_style)
    total = np.zeros((len(styles), model.config.n_joints, 3))
    moved = np.zeros_like(total)
    frames = 0
    parents = model.skeleton.parents
    for motion, content in tqdm(walks, desc="posture", unit="walk"):
        stylizer = StreamStylizer(
            model,
            model.config.neutral_style,
            content,
            [{s: 1.0} for s in styles],
            n_streams=len(styles),
            fps=motion.fps,
            pose="network",
        )
        for t in range(motion.n_frames):
            rot = np.repeat(motion.rotations[t : t + 1], len(styles), 0)
            pos = np.repeat(motion.positions[t : t + 1], len(styles), 0)
            out = stylizer.step(rot, pos)[0]
            same = out[neutral : neutral + 1]
            total += quat.to_scaled_angle_axis(quat.mul(quat.inv(same), out))
            g = forward_positions(out, pos, parents)
            g -= g[:, :1]
            if frame == "body":  # on the input's global positions, which the stylizer keeps
                axes = body_axes(
                    stylizer.previous[0], *stylizer.frame_joints[:2], stylizer.roles.left, stylizer.roles.right
                )
            else:
                axes = heading_axes(stylizer.facing[0])
            moved += (g - g[neutral : neutral + 1]) @ axes.T  # each offset's coordinates along the axes
        frames += motion.n_frames
    return total / max(frames, 1), moved / max(frames, 1)


def with_posture(
    meta: dict,
    model: GeneratorWeights,
    posture: tuple[np.ndarray, np.ndarray],
    walks: int,
    frames: int,
    frame: str = "body",
) -> dict:
    """``meta`` (a model file's configuration) with the measured posture (``measure_posture``, its
    offsets in ``frame``) in it."""
    vectors, offsets = posture
    neutral = model.config.neutral_style
    return {
        **meta,
        "posture": {
            "measured_on": f"{walks} neutral walks of the training split, {frames} frames (styleerd posture)",
            "frame": frame,
            "rotation_vectors": {
                s: np.round(vectors[k], 6).tolist() for k, s in enumerate(model.config.styles) if s != neutral
            },
            "offsets": {s: np.round(offsets[k], 6).tolist() for k, s in enumerate(model.config.styles) if s != neutral},
        },
    }
