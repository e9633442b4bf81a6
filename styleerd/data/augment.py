"""Motions as other performers and rigs would give them, for training what must hold outside
the training set (the online labeller): other proportions, other speeds, the small constant
per-joint rotation offsets that retargeting from another rig's conventions leaves, mirroring,
walks in place.

All work on motions of the model's skeleton; mirroring goes through the skeleton's canonical
T-pose frames (``motion.retarget.tpose_rotations``), which are symmetric whatever the rig's
own joint frames are.
"""

from __future__ import annotations

import numpy as np

from styleerd.motion import quat
from styleerd.motion.kinematics import forward_kinematics, local_rotations
from styleerd.motion.motion import Motion
from styleerd.motion.resample import resample
from styleerd.motion.retarget import body_parts, tpose_rotations
from styleerd.motion.skeleton import Skeleton

# contents that a mirror turns into each other
MIRRORED_CONTENT = {
    "wave-left-hand": "wave-right-hand",
    "raise-up-left-hand": "raise-up-right-hand",
    "walk-turn-left": "walk-turn-right",
}
MIRRORED_CONTENT.update({v: k for k, v in MIRRORED_CONTENT.items()})
# contents whose root travels, which game and three.js animation libraries also ship in place
TRAVELLING = ("walk", "run", "walk-turn-left", "walk-turn-right")
STRAIGHT = ("walk", "run")  # the travelling contents that do not turn


def with_proportions(motion: Motion, legs: float, arms: float, trunk: float) -> Motion:
    """Bones scaled by part (legs, arms with collars, spine with neck and head); the root's
    height follows the legs."""
    sk = motion.skeleton
    parts = body_parts(sk)
    part_of = {j: p for p, j in parts.items()}
    scale = np.ones(sk.n_joints)
    for j in range(1, sk.n_joints):
        p = part_of.get(j, "")
        scale[j] = (
            legs
            if p.endswith(("knee", "foot", "toe"))
            else arms
            if p.endswith(("shoulder", "elbow", "hand"))
            else trunk
            if p in ("spine", "chest", "neck", "head")
            else 1.0
        )
    offsets = sk.offsets * scale[:, None]
    skeleton = Skeleton(sk.names, sk.parents, offsets, sk.channels, sk.end_sites)
    pos = np.broadcast_to(offsets, motion.positions.shape).copy()
    pos[:, 0] = motion.positions[:, 0] * np.array([1.0, legs, 1.0])
    return Motion(skeleton, motion.rotations, pos, motion.fps)


def with_speed(motion: Motion, factor: float) -> Motion:
    """The motion played ``factor`` times as fast, at the same frame rate."""
    faster = resample(motion, motion.fps / factor)
    return Motion(motion.skeleton, faster.rotations, faster.positions, motion.fps)


def with_joint_offsets(motion: Motion, offsets: np.ndarray) -> Motion:
    """Every joint's global rotation turned by a constant ``offsets [J, 4]`` in its own frame
    (what another rig's conventions leave after retargeting)."""
    parents = motion.skeleton.parents
    g, _ = forward_kinematics(motion.rotations, motion.positions, parents)
    return Motion(
        motion.skeleton, quat.normalize(local_rotations(quat.mul(g, offsets), parents)), motion.positions, motion.fps
    )


def random_joint_offsets(n_joints: int, degrees: float, rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=(n_joints, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    return quat.from_angle_axis(np.radians(rng.uniform(0, degrees, n_joints)), axis)


def mirror(motion: Motion, reference_pose: np.ndarray) -> Motion:
    """The motion mirrored left to right (across the character's X = 0 plane): each joint
    takes the mirrored physical orientation of its counterpart, measured from the canonical
    T-pose frames (found from ``reference_pose``, a natural pose of the skeleton)."""
    sk = motion.skeleton
    parts = body_parts(sk)
    C = tpose_rotations(sk, parts, set(parts), reference_pose)
    counterpart = np.arange(sk.n_joints)
    for p, j in parts.items():
        if p.startswith("left_") and (q := "right_" + p[5:]) in parts:
            counterpart[j], counterpart[parts[q]] = parts[q], j
    g, _ = forward_kinematics(motion.rotations, motion.positions, sk.parents)
    body = quat.mul(g, quat.inv(C))  # world rotation from the canonical T-pose
    reflected = body * np.array([1.0, 1.0, -1.0, -1.0])  # M R M with M = diag(-1, 1, 1)
    g_new = quat.mul(reflected[:, counterpart], C)
    pos = motion.positions.copy()
    pos[:, 0, 0] *= -1
    return Motion(sk, quat.normalize(local_rotations(g_new, sk.parents)), pos, motion.fps)


def in_place(m: Motion) -> Motion:
    """The motion with its root's ground path removed (height kept), as game libraries ship walks."""
    positions = m.positions.copy()
    positions[:, 0, [0, 2]] = positions[:1, 0, [0, 2]]
    return Motion(m.skeleton, m.rotations, positions, m.fps)


def other_performer(
    motion: Motion, content: str, reference_pose: np.ndarray, rng: np.random.Generator
) -> tuple[Motion, str]:
    """A random mix of the above: proportions within 15 %, speed 0.8-1.25 x, joint offsets up
    to 12 degrees, mirrored half of the time (the content label mirrored with it), and a walk or a
    run in place a quarter of the time."""
    m = with_proportions(motion, *rng.uniform(0.85, 1.15, 3))
    m = with_speed(m, float(np.exp(rng.uniform(np.log(0.8), np.log(1.25)))))
    m = with_joint_offsets(m, random_joint_offsets(m.skeleton.n_joints, 12.0, rng))
    if rng.random() < 0.5:
        m, content = mirror(m, reference_pose), MIRRORED_CONTENT.get(content, content)
    if content in TRAVELLING and rng.random() < 0.25:
        m = in_place(m)
    return m, content
