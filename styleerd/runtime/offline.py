"""Stylise whole motions and BVH files: exactly the streaming path, frame by frame."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.generator import StyleERD
from styleerd.motion import bvh, quat
from styleerd.motion.motion import Motion, drop_root
from styleerd.motion.resample import resample
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.stylizer import StreamStylizer


def stylise_motion(model: StyleERD, motion: Motion, input_style: str, content: str, target: dict[str, float]) -> Motion:
    """The motion in the target style(s): joint rotations from the network, root trajectory
    (position and facing) and joint translations from the input."""
    stylizer = StreamStylizer(model, input_style, content, target, fps=motion.fps)
    out = np.empty_like(motion.rotations)
    for t in range(motion.n_frames):
        out[t] = stylizer.step(motion.rotations[t : t + 1], motion.positions[t : t + 1])[0][0]
    return Motion(motion.skeleton, out, motion.positions.copy(), motion.fps)


def to_model_skeleton(motion: Motion, model_skeleton: Skeleton) -> tuple[Motion, Callable[[Motion], Motion]]:
    """The motion on the model's skeleton, and the function that puts a motion on the model's
    skeleton back onto the source skeleton (its channel layout and Euler branches). Accepts the
    model's own skeleton, with or without a placeholder root above it (Bandai's joint_Root)."""
    names = model_skeleton.names
    if motion.skeleton.names == names:
        return motion, lambda m: Motion(motion.skeleton, m.rotations, m.positions, m.fps, motion.euler_hint)
    if motion.skeleton.names[1:] == names and len(motion.skeleton.children(0)) == 1:
        root_rot, root_pos = motion.rotations[:, :1], motion.positions[:, :1]

        def restore(m: Motion) -> Motion:
            inv = quat.inv(root_rot[:, 0])
            rot = np.concatenate([root_rot, m.rotations], axis=1)
            pos = np.concatenate([root_pos, m.positions], axis=1)
            rot[:, 1] = quat.mul(inv, m.rotations[:, 0])
            pos[:, 1] = quat.mul_vec(inv, m.positions[:, 0] - root_pos[:, 0])
            return Motion(motion.skeleton, rot, pos, m.fps, motion.euler_hint)

        return drop_root(motion), restore
    missing = [n for n in names if n not in motion.skeleton.names]
    raise StyleERDError(
        f"the skeleton cannot be mapped to the model's {len(names)}-joint skeleton (retargeting other skeletons "
        f"is not built yet); model joints missing: {', '.join(missing) or 'none (different hierarchy)'}"
    )


def transfer_file(source: str | Path, output: str | Path, model: StyleERD, fps: float, input_style: str, content: str, target: dict[str, float]) -> Motion:
    """BVH in -> BVH out in the target style: same skeleton, channel layout, fps, frame count and
    root trajectory as the input. Nothing is written unless the whole transfer succeeded."""
    motion = bvh.read(source)
    if motion.n_frames == 0:
        raise StyleERDError(f"{source}: the motion has no frames")
    if not 10 <= motion.fps <= 480:
        raise StyleERDError(f"{source}: {motion.fps:.6g} fps is outside [10, 480]")
    on_model, restore = to_model_skeleton(motion, model.skeleton)
    styled = stylise_motion(model, resample(on_model, fps), input_style, content, target)
    out = restore(resample(styled, motion.fps, n_frames=motion.n_frames))
    if not (np.isfinite(out.rotations).all() and np.isfinite(out.positions).all()):
        raise StyleERDError(f"{source}: the transfer produced non-finite values; nothing written")
    bvh.write(output, out)
    return out
