"""Change a motion's frame rate: slerp for rotations, lerp for translations."""

from __future__ import annotations

import numpy as np

from styleerd.motion import quat
from styleerd.motion.motion import Motion


def resample(motion: Motion, fps: float, n_frames: int | None = None) -> Motion:
    """The motion sampled at ``fps`` over the same time span (first frame kept; the last new
    frame is the last one that does not pass the source's last frame), or, with ``n_frames``,
    exactly that many frames (times past the source's end hold its last frame). Rates within
    1e-5 of each other count as equal (BVH frame times are printed to about six digits)."""
    if not fps > 0:
        raise ValueError(f"resample: fps must be positive, got {fps}")
    T = motion.n_frames
    same_rate = np.isclose(fps, motion.fps, rtol=1e-5, atol=0.0)
    if T == 0 or (same_rate and n_frames in (None, T)) or (T == 1 and n_frames in (None, 1)):
        return Motion(motion.skeleton, motion.rotations, motion.positions, fps, motion.euler_hint)
    if T == 1:
        idx = np.zeros(n_frames, int)
        return Motion(motion.skeleton, motion.rotations[idx], motion.positions[idx], fps)
    step = 1.0 if same_rate else motion.fps / fps
    n = n_frames if n_frames is not None else int(np.floor((T - 1) / step + 1e-6)) + 1
    x = np.minimum(np.arange(n) * step, T - 1)  # position in source frames
    i0 = np.minimum(np.floor(x).astype(int), T - 2)
    w = (x - i0)[:, None]
    rot = quat.slerp(motion.rotations[i0], motion.rotations[i0 + 1], np.broadcast_to(w, (n, motion.skeleton.n_joints)))
    pos = motion.positions[i0] * (1 - w[..., None]) + motion.positions[i0 + 1] * w[..., None]
    return Motion(motion.skeleton, rot, pos, fps)
