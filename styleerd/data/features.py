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

import numba as nb
import numpy as np

from styleerd.data.parallel import on_kernel_threads
from styleerd.motion import quat
from styleerd.motion.kinematics import (
    facing_directions,
    foot_contacts,
    forward_pose,
    forward_positions,
    heading_rotations,
)
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import BodyRoles, Skeleton

N_CONTACTS = 4
CONTACT_SPEED = 0.25  # a foot slower than this many leg lengths per second is planted


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
    contact_speed: float = CONTACT_SPEED,
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


def stream_features(
    rotations: np.ndarray,
    positions: np.ndarray,
    previous_global: np.ndarray,
    previous_facing: np.ndarray,
    started: np.ndarray,
    skeleton: Skeleton,
    roles: BodyRoles,
    fps: float,
    stats: FeatureStats,
    limit: float,
    contact_speed: float = CONTACT_SPEED,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One frame of N streams, the streaming hot path: ``pose_features`` of quaternions
    normalised first, then ``stats.normalize``, in one compiled loop. A stream not ``started``
    is at its first frame (zero velocity); ``previous_facing [N, 3]`` is each stream's facing
    direction the frame before (kept when the across vector is degenerate, as
    ``kinematics.facing_directions`` does over time).

    Returns (normalised features ``[N, D]`` float32, trajectory ``[N, 7]``, global joint
    positions ``[N, J, 3]``, facing directions ``[N, 3]``, ``ok [N]``: every normalised value
    finite and below ``limit``). Nothing passed in is modified. Many streams run on up to
    ``threads`` threads (``parallel.kernel_threads``)."""
    rot = np.ascontiguousarray(rotations, dtype=np.float64)
    pos = np.ascontiguousarray(positions, dtype=np.float64)
    N, J = rot.shape[:2]
    x, traj = np.empty((N, FeatureLayout(J).dim), np.float32), np.empty((N, 7))
    g, facing, ok = np.empty((N, J, 3)), np.empty((N, 3)), np.empty(N, np.bool_)
    args = (
        rot,
        pos,
        np.ascontiguousarray(previous_global, dtype=np.float64),
        np.ascontiguousarray(previous_facing, dtype=np.float64),
        np.ascontiguousarray(started, dtype=np.bool_),
        skeleton.parents,
        roles.joint_arrays,
        float(fps),
        contact_speed * roles.leg_length,
        stats.mean,
        stats.std,
        stats.reference,
        float(limit),
        x,
        traj,
        g,
        facing,
        ok,
    )
    on_kernel_threads(threads, N, _stream_features_kernel, _stream_features_on_shards, *args)
    return x, traj, g, facing, ok


@nb.njit(cache=True, nogil=True, parallel=True)
def _stream_features_on_shards(
    shards,
    rot,
    pos,
    previous,
    previous_facing,
    started,
    parents,
    roles,
    fps,
    max_speed,
    mean,
    std,
    reference,
    limit,
    x,
    traj,
    g,
    facing,
    ok,
):
    """``_stream_features_kernel`` on ``shards`` slices of the streams, one per thread."""
    N = rot.shape[0]
    for k in nb.prange(shards):
        s, e = N * k // shards, N * (k + 1) // shards
        _stream_features_kernel(
            rot[s:e],
            pos[s:e],
            previous[s:e],
            previous_facing[s:e],
            started[s:e],
            parents,
            roles,
            fps,
            max_speed,
            mean,
            std,
            reference,
            limit,
            x[s:e],
            traj[s:e],
            g[s:e],
            facing[s:e],
            ok[s:e],
        )


@nb.njit(cache=True, nogil=True)
def _stream_features_kernel(
    rot,
    pos,
    previous,
    previous_facing,
    started,
    parents,
    roles,
    fps,
    max_speed,
    mean,
    std,
    reference,
    limit,
    x,
    traj,
    g,
    facing,
    ok,
):
    J = rot.shape[1]
    left, right, feet = roles
    inv_std = 1.0 / std  # a product per value, not a division (the divisions were a tenth of the kernel)
    g_rot, unit = np.empty(rot.shape), np.empty(rot.shape)
    raw = np.empty(x.shape[1])  # a stream's features before normalisation: one vectorisable pass normalises them
    for n in range(rot.shape[0]):
        for j in range(J):
            scale = 1.0 / max(
                np.sqrt(rot[n, j, 0] ** 2 + rot[n, j, 1] ** 2 + rot[n, j, 2] ** 2 + rot[n, j, 3] ** 2), 1e-12
            )
            for k in range(4):
                unit[n, j, k] = rot[n, j, k] * scale
        forward_pose(unit[n], pos[n], parents, g_rot[n], g[n])
        # facing (kinematics.facing_directions) and heading
        ax, ay, az = 0.0, 0.0, 0.0
        for k in range(len(left)):
            ax += g[n, left[k], 0] - g[n, right[k], 0]
            ay += g[n, left[k], 1] - g[n, right[k], 1]
            az += g[n, left[k], 2] - g[n, right[k], 2]
        fx, fz = -az, ax
        fnorm = np.sqrt(fx * fx + fz * fz)
        if fnorm > 1e-6 * max(1.0, np.sqrt(ax * ax + ay * ay + az * az)):
            fx, fz = fx / fnorm, fz / fnorm
        elif started[n]:
            fx, fz = previous_facing[n, 0], previous_facing[n, 2]
        else:
            fx, fz = 0.0, 1.0
        facing[n, 0], facing[n, 1], facing[n, 2] = fx, 0.0, fz
        # the rotation about +Y taking +Z to (fx, 0, fz), w >= 0, from the half-angle identities
        # (no trigonometry)
        if fz > -0.5:
            hw = np.sqrt(0.5 * (1.0 + fz))
            hy = fx / (2.0 * hw)
        else:
            hy = np.sqrt(0.5 * (1.0 - fz)) * (-1.0 if np.signbit(fx) else 1.0)
            hw = fx / (2.0 * hy)
        traj[n, 0], traj[n, 1], traj[n, 2] = g[n, 0, 0], g[n, 0, 1], g[n, 0, 2]
        traj[n, 3], traj[n, 4], traj[n, 5], traj[n, 6] = hw, 0.0, hy, 0.0
        for j in range(J):  # rotations: root in the heading frame, w >= 0, then the reference's hemisphere
            qw, qx, qy, qz = unit[n, j, 0], unit[n, j, 1], unit[n, j, 2], unit[n, j, 3]
            if j == 0:
                qw, qx, qy, qz = quat.mul_scalars(hw, 0.0, -hy, 0.0, qw, qx, qy, qz)  # inv(heading) q
            sign = -1.0 if qw < 0.0 else 1.0
            if sign * (qw * reference[j, 0] + qx * reference[j, 1] + qy * reference[j, 2] + qz * reference[j, 3]) < 0.0:
                sign = -sign
            raw[4 * j], raw[4 * j + 1], raw[4 * j + 2], raw[4 * j + 3] = sign * qw, sign * qx, sign * qy, sign * qz
        moved = started[n]
        for j in range(J):  # positions (relative to the root) and velocities, in the heading frame
            raw[4 * J + 3 * j], raw[4 * J + 3 * j + 1], raw[4 * J + 3 * j + 2] = quat.mul_vec_scalars(
                hw, 0.0, -hy, 0.0, g[n, j, 0] - g[n, 0, 0], g[n, j, 1] - g[n, 0, 1], g[n, j, 2] - g[n, 0, 2]
            )  # by inv(heading)
            if moved:
                raw[7 * J + 3 * j], raw[7 * J + 3 * j + 1], raw[7 * J + 3 * j + 2] = quat.mul_vec_scalars(
                    hw,
                    0.0,
                    -hy,
                    0.0,
                    (g[n, j, 0] - previous[n, j, 0]) * fps,
                    (g[n, j, 1] - previous[n, j, 1]) * fps,
                    (g[n, j, 2] - previous[n, j, 2]) * fps,
                )
            else:
                raw[7 * J + 3 * j], raw[7 * J + 3 * j + 1], raw[7 * J + 3 * j + 2] = 0.0, 0.0, 0.0
        for k in range(len(feet)):  # contacts: foot speed since the previous frame below max_speed
            f = feet[k]
            if moved:
                dx, dy, dz = (
                    g[n, f, 0] - previous[n, f, 0],
                    g[n, f, 1] - previous[n, f, 1],
                    g[n, f, 2] - previous[n, f, 2],
                )
                planted = np.sqrt(dx * dx + dy * dy + dz * dz) * fps < max_speed
            else:
                planted = 0.0 < max_speed
            raw[10 * J + k] = 1.0 if planted else 0.0
        good = True
        xn = x[n]
        for d in range(len(raw)):
            y = (raw[d] - mean[d]) * inv_std[d]
            xn[d] = y
            good &= abs(y) < limit
        ok[n] = good


def motion_features(
    motion: Motion, roles: BodyRoles | None = None, contact_speed: float = CONTACT_SPEED
) -> tuple[np.ndarray, np.ndarray]:
    """Features ``[T, D]`` and trajectory ``[T, 7]`` of a whole motion (the same values a
    stream of its frames gives, frame by frame)."""
    roles = roles or BodyRoles.of(motion.skeleton)
    g_pos = forward_positions(motion.rotations, motion.positions, motion.skeleton.parents)
    previous = np.concatenate([g_pos[:1], g_pos[:-1]], axis=0)
    feats, traj, _ = pose_features(
        motion.rotations, motion.positions, previous, motion.skeleton, roles, motion.fps, contact_speed
    )
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
    def fit(cls, features: np.ndarray, n_joints: int) -> FeatureStats:
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
    def from_dict(cls, d: dict) -> FeatureStats:
        return cls(np.array(d["mean"]), np.array(d["std"]), np.array(d["reference"]))


def align_hemisphere(features: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Flip each joint's quaternion to the hemisphere of ``reference [J, 4]``."""
    J = len(reference)
    out = np.array(features, copy=True)
    q = out[..., : 4 * J].reshape(out.shape[:-1] + (J, 4))
    sign = np.where(np.sum(q * reference, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    out[..., : 4 * J] = (q * sign).reshape(out.shape[:-1] + (4 * J,))
    return out
