"""Two-bone inverse kinematics (hip - knee - ankle), over frames with ``...`` broadcasting."""

from __future__ import annotations

import numpy as np

from styleerd.motion import quat


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(np.sum(_unit(u) * _unit(v), axis=-1), -1.0, 1.0))


def two_bone_ik(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    target: np.ndarray,
    a_global: np.ndarray,
    b_global: np.ndarray,
    bend_axis: np.ndarray,
    eps: float = 1e-4,
) -> tuple[np.ndarray, np.ndarray]:
    """New global rotations of the upper joint ``a`` and middle joint ``b`` (e.g. hip and knee)
    that put the end joint ``c`` at ``target`` (or as near as the bone lengths allow).

    ``a, b, c, target [..., 3]`` are global positions; ``a_global, b_global [..., 4]`` the
    joints' global rotations; ``bend_axis [..., 3]`` the axis the middle joint bends about when
    the limb is straight (for legs: the body's left-right axis). First the middle joint opens
    or closes so the a-c distance equals the a-target distance (law of cosines), then the upper
    joint swings the limb onto the target by the shortest rotation, so the knee keeps pointing
    the way it pointed."""
    upper, lower = np.linalg.norm(b - a, axis=-1), np.linalg.norm(c - b, axis=-1)
    reach = np.clip(np.linalg.norm(target - a, axis=-1), np.abs(upper - lower) + eps, upper + lower - eps)
    inner_now = _angle(a - b, c - b)
    inner_new = np.arccos(np.clip((upper**2 + lower**2 - reach**2) / np.maximum(2 * upper * lower, 1e-300), -1.0, 1.0))
    axis = np.cross(b - a, c - b)
    straight = np.linalg.norm(axis, axis=-1, keepdims=True) < 1e-6 * (upper * lower)[..., None]
    axis = _unit(np.where(straight, bend_axis, axis))
    # opening the inner angle by d turns the lower bone by -d about the bend axis
    bend = quat.from_angle_axis(inner_now - inner_new, axis)
    b_new = quat.mul(bend, b_global)
    c_new = b + quat.mul_vec(bend, c - b)
    swing = quat.between(c_new - a, target - a)
    # a limb with a bone of no length (garbage input: every joint at one point) has no IK: kept
    degenerate = (np.minimum(upper, lower) < eps)[..., None]
    return np.where(degenerate, a_global, quat.mul(swing, a_global)), np.where(degenerate, b_global, quat.mul(swing, b_new))
