"""Quaternion and Euler-angle math over numpy arrays.

Convention, used everywhere inside styleerd:
- a quaternion is ``[..., 4]`` in (w, x, y, z) order (scalar first); convert only at the
  boundaries (glTF, three.js and VMC use x, y, z, w);
- rotations act on column vectors: ``mul_vec(q, v) = R(q) @ v``, and ``mul(a, b)`` applies
  ``b`` first, then ``a`` (as matrices: ``R(a) @ R(b)``);
- an Euler ``order`` is a string such as ``"zxy"`` naming the axes in the order the BVH
  channels list them; the rotation is intrinsic, ``R = Rz(e[0]) @ Rx(e[1]) @ Ry(e[2])``
  (scipy's uppercase ``"ZXY"``). Angles are radians.

Every function broadcasts over leading ``...`` dimensions.
"""

from __future__ import annotations

import numba as nb
import numpy as np

ORDERS = ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx")
_AXIS = {"x": 0, "y": 1, "z": 2}


def identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity rotations of the given leading ``shape``: ``[*shape, 4]``."""
    q = np.zeros(shape + (4,))
    q[..., 0] = 1.0
    return q


def _hamilton_table() -> np.ndarray:
    """``[16, 4]``: mul(a, b)[k] = sum over i, j of a[i] b[j] table[4 i + j, k]."""
    t = np.zeros((4, 4, 4))
    for k, terms in enumerate(
        (
            ((1, 0, 0), (-1, 1, 1), (-1, 2, 2), (-1, 3, 3)),
            ((1, 0, 1), (1, 1, 0), (1, 2, 3), (-1, 3, 2)),
            ((1, 0, 2), (-1, 1, 3), (1, 2, 0), (1, 3, 1)),
            ((1, 0, 3), (1, 1, 2), (-1, 2, 1), (1, 3, 0)),
        )
    ):
        for sign, i, j in terms:
            t[i, j, k] = sign
    return t.reshape(16, 4)


HAMILTON = _hamilton_table()
SMALL = 256  # quaternions: below this, per-call overhead dominates and one matmul beats 28 ufunc calls


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamilton product ``a * b`` (rotate by ``b``, then by ``a``), broadcast over leading axes."""
    if a.size + b.size <= 8 * SMALL:  # per-frame work: outer product and one matmul (3 numpy calls)
        ab = a[..., :, None] * b[..., None, :]
        return ab.reshape(ab.shape[:-2] + (16,)) @ HAMILTON
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def inv(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion (its conjugate)."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """``q`` scaled to unit length (a zero quaternion stays zero rather than dividing by zero)."""
    return q / np.maximum(
        np.sqrt(np.einsum("...i,...i->...", q, q))[..., None], eps
    )  # einsum: twice linalg.norm's speed


def positive_w(q: np.ndarray) -> np.ndarray:
    """The same rotation with a non-negative scalar part (a per-frame, stateless sign choice)."""
    return np.where(q[..., :1] < 0.0, -q, q)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` for ``[..., 3]`` arrays, written out: several times faster on the small
    arrays of per-frame work (np.cross moves axes around on every call)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def mul_vec(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v [..., 3]`` by unit quaternions ``q [..., 4]``."""
    if q.size <= 4 * SMALL and v.size <= 3 * SMALL:  # per-frame work: the rotation matrix, then one matmul
        return (to_xform(q) @ v[..., None])[..., 0]
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def from_angle_axis(angle: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Rotation by ``angle [...]`` about unit ``axis [..., 3]``."""
    half = np.asarray(angle)[..., None] / 2.0
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def to_angle_axis(q: np.ndarray, eps: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """The rotation angle in ``[0, pi]`` (radians) and the unit axis of each quaternion."""
    q = positive_w(q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    axis = q[..., 1:] / np.maximum(s, eps)[..., None]
    return angle, axis


def from_scaled_angle_axis(v: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Rotation by ``|v|`` radians about ``v``'s direction (a rotation vector ``[..., 3]``; 0: identity)."""
    angle = np.linalg.norm(v, axis=-1)
    return from_angle_axis(angle, v / np.maximum(angle, eps)[..., None])


def to_scaled_angle_axis(q: np.ndarray) -> np.ndarray:
    """The rotation vector of each quaternion (the inverse of ``from_scaled_angle_axis``)."""
    angle, axis = to_angle_axis(q)
    return angle[..., None] * axis


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle (radians, in [0, pi]) of ``inv(a) * b``; from the half angle's sine and
    cosine, which keeps small angles exact (arccos of the cosine alone loses them below 1e-7)."""
    d = mul(inv(a), b)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def swing_twist(q: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split rotations ``q [..., 4]`` into ``swing * twist``: ``twist`` turns about the unit
    ``axis [..., 3]``, ``swing`` about an axis perpendicular to it."""
    q = positive_w(q)
    along = np.sum(q[..., 1:] * axis, axis=-1, keepdims=True) * axis
    twist = np.concatenate([q[..., :1], along], axis=-1)
    small = np.linalg.norm(twist, axis=-1, keepdims=True) < 1e-12  # a half turn about a perpendicular axis
    twist = np.where(small, identity(q.shape[:-1]), twist)
    twist = normalize(twist)
    return mul(q, inv(twist)), twist


def from_euler(e: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles ``e [..., 3]`` (radians) about the axes of ``order``."""
    e = np.asarray(e, dtype=np.float64)
    out = np.empty(e.shape[:-1] + (4,))
    _from_euler_kernel(np.ascontiguousarray(e).reshape(-1, 3), np.array([_AXIS[a] for a in order]), out.reshape(-1, 4))
    return out


@nb.njit(cache=True)
def mul_scalars(aw, ax, ay, az, bw, bx, by, bz):
    """``mul`` of two quaternions given as scalars, for compiled loops (no arrays allocated)."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@nb.njit(cache=True)
def mul_vec_scalars(w, x, y, z, vx, vy, vz):
    """``mul_vec`` on scalars: v + w t + u x t with t = 2 u x v (u = (x, y, z))."""
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    return vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx)


@nb.njit(cache=True)
def euler_scalars_to_quat(e0, e1, e2, a0, a1, a2):
    """q = q(a0, e0) q(a1, e1) q(a2, e2) for axes a (0, 1, 2: x, y, z), each factor
    cos(e/2) + sin(e/2) axis: ``from_euler`` of one triple, for compiled loops."""
    w, x, y, z = 1.0, 0.0, 0.0, 0.0
    for e, a in ((e0, a0), (e1, a1), (e2, a2)):
        c, s = np.cos(0.5 * e), np.sin(0.5 * e)
        w, x, y, z = mul_scalars(w, x, y, z, c, s if a == 0 else 0.0, s if a == 1 else 0.0, s if a == 2 else 0.0)
    return w, x, y, z


@nb.njit(cache=True)
def _from_euler_kernel(e, axes, out):
    for n in range(e.shape[0]):
        out[n, 0], out[n, 1], out[n, 2], out[n, 3] = euler_scalars_to_quat(
            e[n, 0], e[n, 1], e[n, 2], axes[0], axes[1], axes[2]
        )


def _xform_table() -> np.ndarray:
    """``[16, 9]``: to_xform(q) = I + (q q^T, flattened) @ table, the terms below."""
    t = np.zeros((4, 4, 3, 3))
    w, x, y, z = range(4)
    for (r, c), terms in {
        (0, 0): ((-2, y, y), (-2, z, z)),
        (0, 1): ((2, x, y), (-2, w, z)),
        (0, 2): ((2, x, z), (2, w, y)),
        (1, 0): ((2, x, y), (2, w, z)),
        (1, 1): ((-2, x, x), (-2, z, z)),
        (1, 2): ((2, y, z), (-2, w, x)),
        (2, 0): ((2, x, z), (-2, w, y)),
        (2, 1): ((2, y, z), (2, w, x)),
        (2, 2): ((-2, x, x), (-2, y, y)),
    }.items():
        for sign, i, j in terms:
            t[i, j, r, c] = sign
    return t.reshape(16, 9)


_XFORM = _xform_table()
_EYE3 = np.eye(3)


def to_xform(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` of unit quaternions."""
    if q.size <= 4 * SMALL:  # per-frame work: 4 numpy calls instead of 40
        qq = q[..., :, None] * q[..., None, :]
        return _EYE3 + (qq.reshape(qq.shape[:-2] + (16,)) @ _XFORM).reshape(qq.shape[:-2] + (3, 3))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def from_xform(m: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation matrices ``[..., 3, 3]`` (branch on the largest term,
    so the result is accurate for every rotation)."""
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    cand = np.stack(
        [
            np.stack(
                [
                    1 + m00 + m11 + m22,
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + m00 - m11 - m22,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m00 + m11 - m22,
                    m[..., 1, 2] + m[..., 2, 1],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        axis=-2,
    )
    best = np.argmax(
        np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1), axis=-1
    )
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    return positive_w(normalize(q))


def to_euler(q: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles ``[..., 3]`` (radians) of unit quaternions for any of the six
    Tait-Bryan orders; the middle angle lies in [-pi/2, pi/2], the others in (-pi, pi].
    At gimbal lock the last angle is set to zero."""
    i, j, k = (_AXIS[a] for a in order)
    q = np.asarray(q, dtype=np.float64)
    out = np.empty(q.shape[:-1] + (3,))
    _to_euler_kernel(np.ascontiguousarray(q).reshape(-1, 4), i, j, k, out.reshape(-1, 3))
    return out


@nb.njit(cache=True)
def quat_scalars_to_euler(w, x, y, z, i, j, k):
    """``to_euler`` of one quaternion about axes (i, j, k), for compiled loops."""
    s = 1.0 if (j - i) % 3 == 1 else -1.0  # +1 when (i, j, k) is a cyclic permutation of (x, y, z)
    m = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    sin_b = min(1.0, max(-1.0, s * m[i][k]))
    if abs(sin_b) > 1.0 - 1e-10:  # gimbal lock: the last angle is zero
        return np.arctan2(s * m[k][j], m[j][j]), np.arcsin(sin_b), 0.0
    return np.arctan2(-s * m[j][k], m[k][k]), np.arcsin(sin_b), np.arctan2(-s * m[i][j], m[i][i])


@nb.njit(cache=True)
def _to_euler_kernel(q, i, j, k, out):
    for n in range(q.shape[0]):
        out[n, 0], out[n, 1], out[n, 2] = quat_scalars_to_euler(q[n, 0], q[n, 1], q[n, 2], q[n, 3], i, j, k)


def alternate_euler(e: np.ndarray) -> np.ndarray:
    """The other Tait-Bryan triple giving the same rotation: (a + pi, pi - b, c + pi)."""
    return np.stack([e[..., 0] + np.pi, np.pi - e[..., 1], e[..., 2] + np.pi], axis=-1)


def nearest_euler(e: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Of the Euler triples equivalent to ``e`` (the two Tait-Bryan solutions and their 2*pi
    shifts), the one nearest ``reference``. Reproduces a source file's angle branches."""
    e, reference = np.broadcast_arrays(np.asarray(e, dtype=np.float64), np.asarray(reference, dtype=np.float64))
    out = np.empty(e.shape)
    _nearest_euler_kernel(
        np.ascontiguousarray(e).reshape(-1, 3), np.ascontiguousarray(reference).reshape(-1, 3), out.reshape(-1, 3)
    )
    return out


@nb.njit(cache=True)
def nearest_euler_scalars(e0, e1, e2, r0, r1, r2):
    """``nearest_euler`` of one triple, for compiled loops."""
    two_pi = 2.0 * np.pi
    best, out = 0.0, (e0, e1, e2)
    for alt in range(2):  # (a, b, c) and its twin (a + pi, pi - b, c + pi)
        c0, c1, c2 = (e0, e1, e2) if alt == 0 else (e0 + np.pi, np.pi - e1, e2 + np.pi)
        c0 += two_pi * np.rint((r0 - c0) / two_pi)
        c1 += two_pi * np.rint((r1 - c1) / two_pi)
        c2 += two_pi * np.rint((r2 - c2) / two_pi)
        d = (c0 - r0) ** 2 + (c1 - r1) ** 2 + (c2 - r2) ** 2
        if alt == 0 or d < best:  # ties (and NaN) keep the principal triple, as before
            best, out = d, (c0, c1, c2)
    return out


@nb.njit(cache=True)
def _nearest_euler_kernel(e, ref, out):
    for n in range(e.shape[0]):
        out[n, 0], out[n, 1], out[n, 2] = nearest_euler_scalars(
            e[n, 0], e[n, 1], e[n, 2], ref[n, 0], ref[n, 1], ref[n, 2]
        )


def unroll_euler(e: np.ndarray) -> np.ndarray:
    """Make Euler triples ``[T, ..., 3]`` continuous over time (no +-180 degree flips in the
    curves): frame 0 keeps its principal triple, each later frame takes the equivalent triple
    nearest the frame before."""
    out = np.array(e, dtype=np.float64, copy=True)
    for t in range(1, len(out)):
        out[t] = nearest_euler(out[t], out[t - 1])
    return out


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation from ``a`` (t=0) to ``b`` (t=1) along the shorter arc."""
    t = np.asarray(t, dtype=np.float64)[..., None]
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0.0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-6
    wa = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(near, 1.0, sin_theta))
    wb = np.where(near, t, np.sin(t * theta) / np.where(near, 1.0, sin_theta))
    return normalize(wa * a + wb * b)


@nb.njit(cache=True)
def between_scalars(x0, y0, z0, x1, y1, z1):
    """``between`` of two vectors given as scalars, for compiled loops."""
    n0, n1 = np.sqrt(x0 * x0 + y0 * y0 + z0 * z0), np.sqrt(x1 * x1 + y1 * y1 + z1 * z1)
    if n0 < 1e-12 or n1 < 1e-12:
        return 1.0, 0.0, 0.0, 0.0
    x0, y0, z0, x1, y1, z1 = x0 / n0, y0 / n0, z0 / n0, x1 / n1, y1 / n1, z1 / n1
    w = 1.0 + x0 * x1 + y0 * y1 + z0 * z1
    if w < 1e-9:  # opposite: a half turn about an axis orthogonal to v0
        ox, oy, oz = (1.0, 0.0, 0.0) if abs(x0) < 0.9 else (0.0, 1.0, 0.0)
        w, x, y, z = 0.0, y0 * oz - z0 * oy, z0 * ox - x0 * oz, x0 * oy - y0 * ox
    else:
        x, y, z = y0 * z1 - z0 * y1, z0 * x1 - x0 * z1, x0 * y1 - y0 * x1
    n = max(np.sqrt(w * w + x * x + y * y + z * z), 1e-12)
    return w / n, x / n, y / n, z / n


def between(v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Shortest rotation taking direction ``v0`` to direction ``v1`` (both ``[..., 3]``); the
    identity where either has no length (no direction to turn from or to)."""
    n0, n1 = np.linalg.norm(v0, axis=-1, keepdims=True), np.linalg.norm(v1, axis=-1, keepdims=True)
    none = (n0 < 1e-12) | (n1 < 1e-12)
    v0 = np.where(none, [1.0, 0.0, 0.0], v0 / np.where(none, 1.0, n0))
    v1 = np.where(none, [1.0, 0.0, 0.0], v1 / np.where(none, 1.0, n1))
    c = np.cross(v0, v1)
    w = 1.0 + np.sum(v0 * v1, axis=-1, keepdims=True)
    # Opposite vectors: rotate by pi about any axis orthogonal to v0.
    ortho = np.cross(v0, np.where(np.abs(v0[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    opposite = w < 1e-9
    q = np.where(opposite, np.concatenate([np.zeros_like(w), ortho], -1), np.concatenate([w, c], -1))
    return normalize(q)
