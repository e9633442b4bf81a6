"""Change a motion's frame rate: slerp for rotations, lerp for translations."""

from __future__ import annotations

import numpy as np

from styleerd.motion import quat
from styleerd.motion.motion import Motion


def resample(motion: Motion, fps: float) -> Motion:
    """The motion sampled at ``fps`` over the same time span (first frame kept; the last new
    frame is the last one that does not pass the source's last frame). Rates within 1e-5 of
    each other count as equal (BVH frame times are printed to about six digits)."""
    if not fps > 0:
        raise ValueError(f"resample: fps must be positive, got {fps}")
    T = motion.n_frames
    if T <= 1 or np.isclose(fps, motion.fps, rtol=1e-5, atol=0.0):
        return Motion(motion.skeleton, motion.rotations, motion.positions, fps, motion.euler_hint)
    duration = (T - 1) / motion.fps
    n = int(np.floor(duration * fps + 1e-6)) + 1
    x = np.arange(n) * (motion.fps / fps)  # position in source frames
    i0 = np.minimum(np.floor(x).astype(int), T - 2)
    w = (x - i0)[:, None]
    rot = quat.slerp(motion.rotations[i0], motion.rotations[i0 + 1], np.broadcast_to(w, (n, motion.skeleton.n_joints)))
    pos = motion.positions[i0] * (1 - w[..., None]) + motion.positions[i0 + 1] * w[..., None]
    return Motion(motion.skeleton, rot, pos, fps)
