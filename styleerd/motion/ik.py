"""Two-bone inverse kinematics (hip - knee - ankle): ``limb_ik`` for one limb in compiled
loops, ``two_bone_ik`` over frames with ``...`` broadcasting."""

from __future__ import annotations

import numba as nb
import numpy as np

from styleerd.motion import quat


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
    the limb is straight (for legs: the body's left-right axis). See ``limb_ik``."""
    arrays = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (a, b, c, target, bend_axis)))
    a_global, b_global = np.broadcast_arrays(
        np.asarray(a_global, dtype=np.float64), np.asarray(b_global, dtype=np.float64)
    )
    lead = np.broadcast_shapes(arrays[0].shape[:-1], a_global.shape[:-1])
    flat = [
        np.ascontiguousarray(np.broadcast_to(v, lead + v.shape[-1:])).reshape(-1, v.shape[-1])
        for v in (*arrays, a_global, b_global)
    ]
    a_new, b_new = np.empty((len(flat[0]), 4)), np.empty((len(flat[0]), 4))
    _ik_kernel(*flat, eps, a_new, b_new)
    return a_new.reshape(lead + (4,)), b_new.reshape(lead + (4,))


@nb.njit(cache=True)
def _ik_kernel(a, b, c, target, bend_axis, a_global, b_global, eps, a_new, b_new):
    for n in range(a.shape[0]):
        limb_ik(a[n], b[n], c[n], target[n], a_global[n], b_global[n], bend_axis[n], eps, a_new[n], b_new[n])


@nb.njit(cache=True)
def _unit3(x, y, z):
    n = max(np.sqrt(x * x + y * y + z * z), 1e-12)
    return x / n, y / n, z / n


@nb.njit(cache=True)
def limb_ik(a, b, c, target, a_global, b_global, bend_axis, eps, a_new, b_new):
    """One limb (positions ``[3]``, rotations ``[4]``) into ``a_new``, ``b_new``. First the
    middle joint opens or closes so the a-c distance equals the a-target distance (law of
    cosines), then the upper joint swings the limb onto the target by the shortest rotation, so
    the knee keeps pointing the way it pointed. A limb with a bone of no length (garbage input:
    every joint at one point) has no IK: its rotations are kept."""
    ab, bc = b - a, c - b
    upper, lower = np.sqrt(np.sum(ab * ab)), np.sqrt(np.sum(bc * bc))
    if min(upper, lower) < eps:
        a_new[:], b_new[:] = a_global, b_global
        return
    reach = min(max(np.sqrt(np.sum((target - a) ** 2)), abs(upper - lower) + eps), upper + lower - eps)
    u, v = _unit3(-ab[0], -ab[1], -ab[2]), _unit3(bc[0], bc[1], bc[2])
    inner_now = np.arccos(min(1.0, max(-1.0, u[0] * v[0] + u[1] * v[1] + u[2] * v[2])))
    inner_new = np.arccos(min(1.0, max(-1.0, (upper**2 + lower**2 - reach**2) / max(2 * upper * lower, 1e-300))))
    axis = np.cross(ab, bc)
    if np.sqrt(np.sum(axis * axis)) < 1e-6 * upper * lower:  # straight: bend about the given axis
        axis = bend_axis.copy()
    x, y, z = _unit3(axis[0], axis[1], axis[2])
    # opening the inner angle by d turns the lower bone by -d about the bend axis
    half = 0.5 * (inner_now - inner_new)
    bw, s = np.cos(half), np.sin(half)
    bx, by, bz = s * x, s * y, s * z
    kw, kx, ky, kz = quat.mul_scalars(bw, bx, by, bz, b_global[0], b_global[1], b_global[2], b_global[3])
    tx, ty, tz = quat.mul_vec_scalars(bw, bx, by, bz, bc[0], bc[1], bc[2])
    sw, sx, sy, sz = quat.between_scalars(
        b[0] + tx - a[0], b[1] + ty - a[1], b[2] + tz - a[2], target[0] - a[0], target[1] - a[1], target[2] - a[2]
    )
    a_new[0], a_new[1], a_new[2], a_new[3] = quat.mul_scalars(
        sw, sx, sy, sz, a_global[0], a_global[1], a_global[2], a_global[3]
    )
    b_new[0], b_new[1], b_new[2], b_new[3] = quat.mul_scalars(sw, sx, sy, sz, kw, kx, ky, kz)
