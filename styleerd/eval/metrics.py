"""Runtime quality figures on the test split: online label inference, foot skate before and
after cleanup, and the size of the pop when the target style switches mid-stream.

Streams are the test clips of at least ``frames`` frames, cut to that length and run as one
batch through StreamStylizer (the per-frame path users run), each into its transfer target
(neutral -> one of the other styles in turn, styled -> neutral).
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from styleerd.data.datasets import data_root, find_clips, load_motion
from styleerd.model.generator import StyleERD
from styleerd.motion.kinematics import foot_contacts, forward_kinematics
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.cleanup import FootLock
from styleerd.runtime.stylizer import StreamStylizer
from styleerd.train.config import TrainConfig
from styleerd.train.labeller import stream_accuracy
from styleerd.train.trainer import setup


def foot_skate(global_positions: np.ndarray, ankles: tuple[int, int], planted: np.ndarray) -> float:
    """Mean horizontal ankle travel per frame (data units) over the frames where a foot is
    planted now and was planted the frame before. ``global_positions [N, T, J, 3]``,
    ``planted [N, T, 2]``."""
    step = np.linalg.norm(np.diff(global_positions[:, :, list(ankles)][..., [0, 2]], axis=1), axis=-1)  # [N, T-1, 2]
    both = planted[:, 1:] & planted[:, :-1]
    return float(step[both].mean()) if both.any() else 0.0


def _streams(model: StyleERD, data_dir: str | None, frames: int):
    """Test clips of >= ``frames`` frames cut to that length: rotations/positions [N, T, J, *],
    their labels and transfer targets."""
    from styleerd.data.windows import split_takes

    clips = find_clips(data_root(data_dir), "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    motions, styles, contents = [], [], []
    for c in tqdm([c for c in clips if split[c.name] == "test"], desc="test clips", leave=False):
        m = load_motion(c)
        if m.n_frames >= frames:
            motions.append(m[:frames])
            styles.append(c.style)
            contents.append(c.content)
    neutral = model.config.neutral_style
    others = [s for s in model.config.styles if s != neutral]
    targets = [others[i % len(others)] if s == neutral else neutral for i, s in enumerate(styles)]
    rot = np.stack([m.rotations for m in motions], 0)
    pos = np.stack([m.positions for m in motions], 0)
    return rot, pos, styles, contents, targets


def _run(model: StyleERD, rot, pos, styles, contents, targets, switch: dict | None = None, blend_frames: int = 8, cleanup: bool = False):
    """Stream every clip at once; returns output local rotations [N, T, J, 4]."""
    N, T = rot.shape[:2]
    st = StreamStylizer(model, styles, contents, [{t: 1.0} for t in targets], n_streams=N, blend_frames=blend_frames)
    lock = FootLock(model.skeleton, N) if cleanup else None
    out = np.empty_like(rot)
    for t in range(T):
        if switch and t == switch["frame"]:
            for k, target in enumerate(switch["targets"]):
                st.set_target({target: 1.0}, [k])
        r, _ = st.step(rot[:, t], pos[:, t])
        out[:, t] = lock.step(r, pos[:, t], rot[:, t], pos[:, t]) if lock else r
    return out


def runtime_report(model: StyleERD, labeller, data_dir: str | None = None, frames: int = 90, blend_frames: int = 8) -> dict:
    s = setup(TrainConfig(), data_dir, progress=False)
    report: dict = {"labels": stream_accuracy(labeller, s.fs, s.data, "test")}
    rot, pos, styles, contents, targets = _streams(model, data_dir, frames)
    sk = model.skeleton
    roles = BodyRoles.of(sk)
    ankles = (roles.feet[0], roles.feet[2])

    def world(r):
        return forward_kinematics(r, pos, sk.parents)[1]

    g_in = world(rot)
    previous = np.concatenate([g_in[:, :1], g_in[:, :-1]], 1)
    planted = foot_contacts(g_in, previous, ankles, 30.0, 0.25 * roles.leg_length) > 0
    raw = _run(model, rot, pos, styles, contents, targets)
    cleaned = _run(model, rot, pos, styles, contents, targets, cleanup=True)
    report["foot_skate_cm_per_frame"] = {
        "streams": len(rot),
        "frames": frames,
        "input": round(foot_skate(g_in, ankles, planted), 4),
        "raw_output": round(foot_skate(world(raw), ankles, planted), 4),
        "cleaned_output": round(foot_skate(world(cleaned), ankles, planted), 4),
    }
    # switch every stream to another style halfway, blended and not; compare the largest joint
    # move per frame around the switch with the same frames of the stream that does not switch
    half = frames // 2
    others = [x for x in model.config.styles if x != model.config.neutral_style]
    new = [others[(others.index(t) + 1) % len(others)] if t in others else others[i % len(others)] for i, t in enumerate(targets)]
    window = slice(half - 1, half + blend_frames)  # moves into frames half .. half + blend_frames

    def largest_move(g):
        return np.linalg.norm(np.diff(g, axis=1), axis=-1).max(-1)  # [N, T-1]

    steady = largest_move(world(raw))
    switch = {"frame": half, "blend_frames": blend_frames, "no_switch_cm": round(float(steady[:, window].max(1).mean()), 3)}
    for name, n in (("blended_cm", blend_frames), ("unblended_cm", 1)):
        moved = largest_move(world(_run(model, rot, pos, styles, contents, targets, {"frame": half, "targets": new}, n)))
        switch[name] = round(float(moved[:, window].max(1).mean()), 3)
    switch["normal_p99_cm"] = round(float(np.percentile(steady, 99)), 3)
    report["style_switch"] = switch
    return report
