"""Forward kinematics, the causal heading (facing) frame, and foot contacts.

Axes follow the source data; the up axis is +Y. The heading frame of a frame is the rotation
about +Y that turns +Z into the character's facing direction on the ground plane.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from styleerd.motion import quat

UP = np.array([0.0, 1.0, 0.0])
FORWARD = np.array([0.0, 0.0, 1.0])


def forward_kinematics(
    rotations: np.ndarray, positions: np.ndarray, parents: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations ``[..., J, 4]`` and positions ``[..., J, 3]`` (float64) from local
    ones (leading axes broadcast). ``parents`` must list parents before children
    (``parents[0] == -1``). One compiled loop over poses and joints: per-frame calls cost
    microseconds, whole clips run at memory speed."""
    rotations, positions = np.asarray(rotations), np.asarray(positions)
    J, lead = rotations.shape[-2], rotations.shape[:-2]
    if positions.shape[:-2] != lead:
        lead = np.broadcast_shapes(lead, positions.shape[:-2])
        rotations, positions = np.broadcast_to(rotations, lead + (J, 4)), np.broadcast_to(positions, lead + (J, 3))
    rot = np.ascontiguousarray(rotations, dtype=np.float64).reshape(-1, J, 4)
    pos = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, J, 3)
    g_rot, g_pos = np.empty_like(rot), np.empty_like(pos)
    _forward_kernel(rot, pos, np.asarray(parents, dtype=np.int64), g_rot, g_pos)
    return g_rot.reshape(lead + (J, 4)), g_pos.reshape(lead + (J, 3))


@nb.njit(cache=True)
def _forward_kernel(rot, pos, parents, g_rot, g_pos):
    for b in range(rot.shape[0]):
        forward_pose(rot[b], pos[b], parents, g_rot[b], g_pos[b])


@nb.njit(cache=True)
def forward_pose(rot, pos, parents, g_rot, g_pos):
    """Forward kinematics of one pose ``[J, 4]``, ``[J, 3]`` into ``g_rot``, ``g_pos`` (compiled loops)."""
    for j in range(rot.shape[0]):
        p = parents[j]
        if p < 0:
            g_rot[j] = rot[j]
            g_pos[j] = pos[j]
            continue
        w, x, y, z = g_rot[p, 0], g_rot[p, 1], g_rot[p, 2], g_rot[p, 3]
        ox, oy, oz = quat.mul_vec_scalars(w, x, y, z, pos[j, 0], pos[j, 1], pos[j, 2])
        g_pos[j, 0], g_pos[j, 1], g_pos[j, 2] = ox + g_pos[p, 0], oy + g_pos[p, 1], oz + g_pos[p, 2]
        g_rot[j, 0], g_rot[j, 1], g_rot[j, 2], g_rot[j, 3] = quat.mul_scalars(
            w, x, y, z, rot[j, 0], rot[j, 1], rot[j, 2], rot[j, 3]
        )


def forward_positions(rotations: np.ndarray, positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Global joint positions ``[..., J, 3]`` only (the common need of per-frame work)."""
    return forward_kinematics(rotations, positions, parents)[1]


def facing_directions(
    global_positions: np.ndarray, left: tuple[int, ...], right: tuple[int, ...], previous: np.ndarray | None = None
) -> np.ndarray:
    """Unit facing directions ``[T, 3]`` on the ground plane, from the across vector of
    left/right joint pairs (hips and shoulders): forward = across x up.

    Per frame, so causal. A frame whose across vector is (nearly) vertical keeps the frame
    before's direction (``previous`` for the first frame, else +Z), which is still causal."""
    across = (global_positions[..., left, :] - global_positions[..., right, :]).sum(axis=-2)
    forward = np.zeros_like(across)  # across x up, written out for up = +Y: (-z, 0, x)
    forward[..., 0], forward[..., 2] = -across[..., 2], across[..., 0]
    norm = np.linalg.norm(forward, axis=-1, keepdims=True)
    ok = norm[..., 0] > 1e-6 * np.maximum(1.0, np.linalg.norm(across, axis=-1))
    out = forward / np.where(ok[..., None], norm, 1.0)
    for t in np.nonzero(~ok)[0]:
        out[t] = out[t - 1] if t > 0 else (FORWARD if previous is None else previous)
    return out


def heading_rotations(directions: np.ndarray) -> np.ndarray:
    """Rotations about +Y ``[..., 4]`` taking +Z to each ground-plane direction ``[..., 3]``."""
    angle = np.arctan2(directions[..., 0], directions[..., 2])
    return quat.from_angle_axis(angle, UP)


def heading_axes(directions: np.ndarray) -> np.ndarray:
    """The heading frame's axes as rows ``[..., 3, 3]`` (left, up, forward, in world coordinates)
    for ground-plane facing directions ``[..., 3]``: ``heading_rotations``' columns."""
    fx, fz = directions[..., 0], directions[..., 2]
    zero, one = np.zeros_like(fx), np.ones_like(fx)
    return np.stack([np.stack([fz, zero, -fx], -1), np.stack([zero, one, zero], -1), np.stack([fx, zero, fz], -1)], -2)


def body_axes(
    global_positions: np.ndarray, hips: int, head: int, left: tuple[int, ...], right: tuple[int, ...]
) -> np.ndarray:
    """The body's own axes as rows ``[..., 3, 3]`` (left, up, forward, in world coordinates): up
    from the hips to the head, left from the right joints to the left ones (hips and shoulders),
    forward across them. Upright, the heading frame's axes tilted with the trunk; lying down (a
    swimmer), they turn with the body where the heading frame keeps the world's up. Degenerate
    (the head on the hips): zero axes, no NaN."""
    up = global_positions[..., head, :] - global_positions[..., hips, :]
    across = (global_positions[..., left, :] - global_positions[..., right, :]).sum(axis=-2)
    forward = np.cross(across, up)
    across = np.cross(up, forward)
    axes = np.stack([across, up, forward], -2)
    return axes / np.maximum(np.linalg.norm(axes, axis=-1, keepdims=True), 1e-9)


def foot_contacts(
    global_positions: np.ndarray, previous_positions: np.ndarray, feet: tuple[int, ...], fps: float, max_speed: float
) -> np.ndarray:
    """Contact flags ``[..., len(feet)]``: a foot is planted while its speed since the previous
    frame (backward difference, units per second) is below ``max_speed``."""
    step = global_positions[..., feet, :] - previous_positions[..., feet, :]
    return (np.linalg.norm(step, axis=-1) * fps < max_speed).astype(np.float64)


def local_rotations(global_rotations: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Local rotations ``[..., J, 4]`` of global ones: each joint's relative to its parent's."""
    local = global_rotations.copy()
    local[..., 1:, :] = quat.mul(quat.inv(global_rotations[..., parents[1:], :]), global_rotations[..., 1:, :])
    return local


def bone_fronts(skeleton) -> np.ndarray:
    """Per joint j, the rest-pose front ``[J, 3]`` of the bone from j's parent to j, in the
    parent's frame: +Z made perpendicular to the bone (+Y for a bone along Z, such as a foot);
    zero for the root and zero-length bones. Turned by the parent's global rotation it shows
    how the bone is rolled about itself."""
    fronts = np.zeros((skeleton.n_joints, 3))
    for j in range(1, skeleton.n_joints):
        length = np.linalg.norm(skeleton.offsets[j])
        if length < 1e-9:
            continue
        bone = skeleton.offsets[j] / length
        for axis in (FORWARD, UP):
            f = axis - bone * np.dot(axis, bone)
            if np.linalg.norm(f) > 0.3:
                fronts[j] = f / np.linalg.norm(f)
                break
    return fronts
