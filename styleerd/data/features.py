"""Motion <-> per-frame feature vectors, strictly causal, and their normalisation.

One frame's feature vector, for J joints and 4 foot contacts (left foot, left toe, right foot,
right toe):

    [ rotations 4J | positions 3J | velocities 3J | contacts 4 ]

- rotations: local joint rotations (w, x, y, z), positive w; the root's is expressed in the
  heading frame (facing +Z), so the features do not depend on where the character faces;
- positions: joint positions relative to the root, in the heading frame;
- velocities: joint displacement since the previous frame (backward difference, units per
  second) in the heading frame; zero on a stream's first frame;
- contacts: 1 while a foot moves slower than ``contact_speed`` leg lengths per second.

Frame t depends on frames t and t-1 only. The root trajectory (world root position and the
heading rotation) is kept aside for reconstruction: the network changes the pose, never the
path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from styleerd.motion import quat
from styleerd.motion.kinematics import facing_directions, foot_contacts, forward_positions, heading_rotations
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import BodyRoles, Skeleton

N_CONTACTS = 4


@dataclass(frozen=True)
class FeatureLayout:
    n_joints: int

    @property
    def rotations(self) -> slice:
        return slice(0, 4 * self.n_joints)

    @property
    def positions(self) -> slice:
        return slice(4 * self.n_joints, 7 * self.n_joints)

    @property
    def velocities(self) -> slice:
        return slice(7 * self.n_joints, 10 * self.n_joints)

    @property
    def contacts(self) -> slice:
        return slice(10 * self.n_joints, 10 * self.n_joints + N_CONTACTS)

    @property
    def dim(self) -> int:
        return 10 * self.n_joints + N_CONTACTS


def pose_features(
    rotations: np.ndarray,
    positions: np.ndarray,
    previous_global: np.ndarray,
    skeleton: Skeleton,
    roles: BodyRoles,
    fps: float,
    contact_speed: float = 0.25,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features of frames ``[T, J, *]`` given the global joint positions of each frame's
    previous frame (``previous_global [T, J, 3]``; pass the frame itself for a first frame).

    Returns (features ``[T, D]``, trajectory ``[T, 7]`` = root position + heading quaternion,
    global joint positions ``[T, J, 3]``, to pass as ``previous_global`` of the next frame)."""
    g_pos = forward_positions(rotations, positions, skeleton.parents)
    heading = heading_rotations(facing_directions(g_pos, roles.left, roles.right))
    inv_h = quat.inv(heading)[:, None]
    local = rotations.copy()
    local[:, 0] = quat.mul(inv_h[:, 0], rotations[:, 0])
    rel = quat.mul_vec(inv_h, g_pos - g_pos[:, :1])
    vel = quat.mul_vec(inv_h, g_pos - previous_global) * fps
    contacts = foot_contacts(g_pos, previous_global, roles.feet, fps, contact_speed * roles.leg_length)
    T = len(rotations)
    features = np.concatenate(
        [quat.positive_w(local).reshape(T, -1), rel.reshape(T, -1), vel.reshape(T, -1), contacts], axis=-1
    )
    trajectory = np.concatenate([g_pos[:, 0], heading], axis=-1)
    return features, trajectory, g_pos


def motion_features(motion: Motion, roles: BodyRoles | None = None, contact_speed: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Features ``[T, D]`` and trajectory ``[T, 7]`` of a whole motion (the same values a
    stream of its frames gives, frame by frame)."""
    roles = roles or BodyRoles.of(motion.skeleton)
    g_pos = forward_positions(motion.rotations, motion.positions, motion.skeleton.parents)
    previous = np.concatenate([g_pos[:1], g_pos[:-1]], axis=0)
    feats, traj, _ = pose_features(motion.rotations, motion.positions, previous, motion.skeleton, roles, motion.fps, contact_speed)
    return feats, traj


def features_to_motion(features: np.ndarray, trajectory: np.ndarray, skeleton: Skeleton, fps: float) -> Motion:
    """The motion whose joint rotations are the features' (root put back on the trajectory's
    heading) and whose root follows the trajectory; other joints sit at their rest offsets."""
    T, J = len(features), skeleton.n_joints
    layout = FeatureLayout(J)
    rot = quat.normalize(features[:, layout.rotations].reshape(T, J, 4))
    rot[:, 0] = quat.mul(trajectory[:, 3:7], rot[:, 0])
    pos = np.broadcast_to(skeleton.offsets, (T, J, 3)).copy()
    pos[:, 0] = trajectory[:, :3]
    return Motion(skeleton, rot, pos, fps)


def average_rotation(q: np.ndarray) -> np.ndarray:
    """Average of unit quaternions ``[N, 4]`` regardless of their signs (Markley et al.: the
    principal eigenvector of sum q q^T)."""
    _, vecs = np.linalg.eigh(q.T @ q)
    return quat.positive_w(vecs[:, -1])


@dataclass(frozen=True)
class FeatureStats:
    """Normalisation: quaternions are first put in the hemisphere of a per-joint reference
    rotation (the joint's average; a per-frame, stateless sign choice that keeps a joint's
    features continuous unless it turns about 180 degrees away from its usual pose); then
    each dimension has its mean removed and is divided by the spread of its block (rotations,
    positions, velocities: one pooled std each; contacts are left as 0/1). A pooled scale
    keeps errors in a common unit: per-dimension scaling would magnify near-rigid joints
    (a spine's height varies by a millimetre) into the loudest dimensions."""

    mean: np.ndarray
    std: np.ndarray
    reference: np.ndarray  # [J, 4]

    @classmethod
    def fit(cls, features: np.ndarray, n_joints: int) -> "FeatureStats":
        layout = FeatureLayout(n_joints)
        q = features[:, layout.rotations].reshape(len(features), n_joints, 4).astype(np.float64)
        reference = np.stack([average_rotation(q[:, j]) for j in range(n_joints)])
        aligned = align_hemisphere(features, reference).astype(np.float64)
        mean = aligned.mean(0)
        std = np.ones(layout.dim)
        for block in (layout.rotations, layout.positions, layout.velocities):
            std[block] = np.sqrt(aligned[:, block].var(0).mean())
        mean[layout.contacts] = 0.0
        return cls(mean, std, reference)

    def normalize(self, features: np.ndarray) -> np.ndarray:
        return (align_hemisphere(features, self.reference) - self.mean) / self.std

    def denormalize(self, x: np.ndarray) -> np.ndarray:
        return x * self.std + self.mean

    def to_dict(self) -> dict:
        return {"mean": self.mean.tolist(), "std": self.std.tolist(), "reference": self.reference.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "FeatureStats":
        return cls(np.array(d["mean"]), np.array(d["std"]), np.array(d["reference"]))


def align_hemisphere(features: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Flip each joint's quaternion to the hemisphere of ``reference [J, 4]``."""
    J = len(reference)
    out = np.array(features, copy=True)
    q = out[..., : 4 * J].reshape(out.shape[:-1] + (J, 4))
    sign = np.where(np.sum(q * reference, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    out[..., : 4 * J] = (q * sign).reshape(out.shape[:-1] + (4 * J,))
    return out
