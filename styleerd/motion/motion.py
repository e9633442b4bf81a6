"""Motion: a skeleton plus per-frame local joint rotations and translations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from styleerd.motion import quat
from styleerd.motion.skeleton import Skeleton


@dataclass(eq=False)
class Motion:
    """``rotations [T, J, 4]`` local unit quaternions (w, x, y, z); ``positions [T, J, 3]``
    local translations (a joint without BVH position channels holds its rest offset).

    ``euler_hint [T, J, 3]`` (degrees, each joint in its channel order) is optional: the Euler
    angles a BVH file stored, so writing picks the same angle branches (exact round trips, and
    outputs whose curves follow their input's). Operations that change timing drop it.
    """

    skeleton: Skeleton
    rotations: np.ndarray
    positions: np.ndarray
    fps: float
    euler_hint: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.rotations = np.asarray(self.rotations, dtype=np.float64)
        self.positions = np.asarray(self.positions, dtype=np.float64)
        J = self.skeleton.n_joints
        if self.rotations.shape[1:] != (J, 4) or self.positions.shape != self.rotations.shape[:2] + (3,):
            raise ValueError(
                f"motion: rotations {self.rotations.shape} / positions {self.positions.shape} "
                f"do not fit a {J}-joint skeleton"
            )

    @property
    def n_frames(self) -> int:
        return len(self.rotations)

    def __getitem__(self, frames: slice) -> Motion:
        hint = None if self.euler_hint is None else self.euler_hint[frames]
        return Motion(self.skeleton, self.rotations[frames], self.positions[frames], self.fps, hint)


def drop_root(motion: Motion) -> Motion:
    """Remove the root joint, composing its transform into its only child, which becomes the
    new root. Exact: forward kinematics of the remaining joints are unchanged. Used for
    skeletons whose root is a static placeholder (Bandai-Namco's ``joint_Root``)."""
    sk = motion.skeleton
    kids = sk.children(0)
    if len(kids) != 1:
        raise ValueError(f"drop_root: root {sk.names[0]!r} has {len(kids)} children, needs exactly 1")
    child = kids[0]
    rot = motion.rotations[:, 1:].copy()
    pos = motion.positions[:, 1:].copy()
    rot[:, child - 1] = quat.mul(motion.rotations[:, 0], motion.rotations[:, child])
    pos[:, child - 1] = quat.mul_vec(motion.rotations[:, 0], motion.positions[:, child]) + motion.positions[:, 0]
    parents = sk.parents[1:] - 1
    parents[child - 1] = -1
    channels = list(sk.channels[1:])
    if not sk.has_positions(child):
        channels[child - 1] = ("Xposition", "Yposition", "Zposition") + channels[child - 1]
    skeleton = Skeleton(
        names=sk.names[1:],
        parents=parents,
        offsets=sk.offsets[1:],
        channels=tuple(channels),
        end_sites=tuple((j - 1, o) for j, o in sk.end_sites if j != 0),
    )
    return Motion(skeleton, rot, pos, motion.fps)
