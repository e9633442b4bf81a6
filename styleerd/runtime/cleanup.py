"""Online foot cleanup: where the input's foot is planted, pin the output's foot.

Contacts come from the input (a foot is planted while the input's ankle moves slower than
``contact_speed`` leg lengths per second: the same causal rule as the features). When a
contact begins, the output ankle's position at that frame becomes the anchor; while the
contact lasts, two-bone IK (hip, knee) holds the output ankle on it; when it ends, the target
slides from the anchor back to the raw ankle over ``release_frames`` frames, so nothing pops.
Frame t uses frames <= t only. Works on any skeleton with named legs (BodyRoles).
"""

from __future__ import annotations

import numpy as np

from styleerd.motion import quat
from styleerd.motion.ik import two_bone_ik
from styleerd.motion.kinematics import foot_contacts, forward_kinematics, forward_positions
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import body_parts
from styleerd.motion.skeleton import Skeleton


class FootLock:
    def __init__(
        self,
        skeleton: Skeleton,
        n_streams: int = 1,
        fps: float = 30.0,
        contact_speed: float = 0.25,
        release_frames: int = 4,
        legs: list[list[int]] | None = None,
    ):
        """``legs``: [[hip, knee, ankle] of the left leg, the same of the right] (default: found
        by joint names and topology, as retargeting finds them)."""
        self.skeleton, self.fps = skeleton, fps
        if legs is None:
            parts = body_parts(skeleton)
            legs = [[parts[f"{side}_{p}"] for p in ("hip", "knee", "foot")] for side in ("left", "right")]
        self.legs = np.array(legs)
        self.across = (self.legs[0, 0], self.legs[1, 0])
        parents = skeleton.parents
        # IK sets hip and knee rotations directly: the leg must be one hip-knee-ankle chain
        self.enabled = all(parents[k] == h and parents[a] == k for h, k, a in self.legs)
        P = forward_positions(quat.identity((skeleton.n_joints,)), skeleton.offsets, skeleton.parents)
        leg = np.linalg.norm(P[self.legs[0, 1]] - P[self.legs[0, 0]]) + np.linalg.norm(P[self.legs[0, 2]] - P[self.legs[0, 1]])
        self.max_speed = contact_speed * leg
        self.n, self.release_frames = n_streams, max(1, release_frames)
        self.previous = np.zeros((n_streams, 2, 3))  # input ankles of the last frame (once started)
        self.anchor = np.zeros((n_streams, 2, 3))  # where a planted foot is held (while planted)
        self.since_release = np.full((n_streams, 2), self.release_frames)  # frames since a contact ended
        self.planted = np.zeros((n_streams, 2), dtype=bool)
        self.started = np.zeros(n_streams, dtype=bool)

    def reset(self, streams=None) -> None:
        """Forget the past of some (default all) streams."""
        rows = slice(None) if streams is None else np.asarray(streams, dtype=int)
        self.since_release[rows], self.planted[rows], self.started[rows] = self.release_frames, False, False

    def step(self, rotations: np.ndarray, positions: np.ndarray, input_rotations: np.ndarray, input_positions: np.ndarray, rows=None) -> np.ndarray:
        """Output frame ``rotations [N, J, 4]`` (local) with ``positions [N, J, 3]``, and the
        input frame it came from -> cleaned local rotations; of every stream, or of the
        streams ``rows`` only."""
        sel = slice(None) if rows is None else np.asarray(rows, dtype=int)
        g_in = forward_positions(input_rotations, input_positions, self.skeleton.parents)
        ankles = g_in[:, self.legs[:, 2]]
        previous = np.where(self.started[sel, None, None], self.previous[sel], ankles)
        self.previous[sel], self.started[sel] = ankles, True
        planted = foot_contacts(ankles, previous, (0, 1), self.fps, self.max_speed) > 0  # [N, 2]
        g_rot, g_pos = forward_kinematics(rotations, positions, self.skeleton.parents)
        raw = g_pos[:, self.legs[:, 2]]  # [N, 2, 3] output ankles
        was_planted = self.planted[sel]
        anchor = np.where((planted & ~was_planted)[..., None], raw, self.anchor[sel])
        since_release = np.where(planted, 0, np.where(was_planted, 1, np.minimum(self.since_release[sel] + 1, self.release_frames)))
        self.anchor[sel], self.since_release[sel], self.planted[sel] = anchor, since_release, planted
        weight = np.where(planted, 1.0, 1.0 - since_release / self.release_frames)  # [N, 2]
        if not (self.enabled and weight.any()):
            return rotations
        target = raw + weight[..., None] * (anchor - raw)
        left_axis = g_pos[:, self.across[0]] - g_pos[:, self.across[1]]
        out = rotations.copy()
        for side in range(2):
            hip, knee, ankle = self.legs[side]
            rows = np.nonzero(weight[:, side] > 0)[0]
            if len(rows) == 0:
                continue
            hip_g, knee_g = two_bone_ik(
                g_pos[rows, hip], g_pos[rows, knee], g_pos[rows, ankle], target[rows, side], g_rot[rows, hip], g_rot[rows, knee], left_axis[rows]
            )
            parent = self.skeleton.parents[hip]
            out[rows, hip] = quat.mul(quat.inv(g_rot[rows, parent]), hip_g)
            out[rows, knee] = quat.mul(quat.inv(hip_g), knee_g)
        return out


def clean_feet(output: Motion, source: Motion) -> Motion:
    """A whole output motion cleaned frame by frame (the same values as streaming it)."""
    lock = FootLock(output.skeleton, 1, output.fps)
    rot = np.empty_like(output.rotations)
    for t in range(output.n_frames):
        rot[t] = lock.step(output.rotations[t : t + 1], output.positions[t : t + 1], source.rotations[t : t + 1], source.positions[t : t + 1])[0]
    return Motion(output.skeleton, rot, output.positions, output.fps, output.euler_hint)
