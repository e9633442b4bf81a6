"""Forward kinematics, the causal heading (facing) frame, and foot contacts.

Axes follow the source data; the up axis is +Y. The heading frame of a frame is the rotation
about +Y that turns +Z into the character's facing direction on the ground plane.
"""

from __future__ import annotations

import numpy as np

from styleerd.motion import quat

UP = np.array([0.0, 1.0, 0.0])
FORWARD = np.array([0.0, 0.0, 1.0])


def forward_kinematics(rotations: np.ndarray, positions: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations ``[..., J, 4]`` and positions ``[..., J, 3]`` from local ones.
    ``parents`` must list parents before children (``parents[0] == -1``). Joints of one depth
    are done together, so the Python loop runs once per level, not once per joint."""
    parents = np.asarray(parents)
    g_rot = np.empty(rotations.shape, dtype=np.result_type(rotations, float))
    g_pos = np.empty(positions.shape, dtype=np.result_type(positions, float))
    levels = depth_levels(parents)
    g_rot[..., levels[0], :] = rotations[..., levels[0], :]
    g_pos[..., levels[0], :] = positions[..., levels[0], :]
    for joints in levels[1:]:
        p = parents[joints]
        g_pos[..., joints, :] = quat.mul_vec(g_rot[..., p, :], positions[..., joints, :]) + g_pos[..., p, :]
        g_rot[..., joints, :] = quat.mul(g_rot[..., p, :], rotations[..., joints, :])
    return g_rot, g_pos


_LEVELS: dict[bytes, list[np.ndarray]] = {}


def depth_levels(parents: np.ndarray) -> list[np.ndarray]:
    """Joint indices grouped by depth below the root (root first): each group's parents are
    all in earlier groups, so a group can be processed at once. Cached per hierarchy."""
    parents = np.asarray(parents, dtype=np.int64)
    key = parents.tobytes()
    if key not in _LEVELS:
        depth = np.zeros(len(parents), dtype=np.int64)
        for j in range(1, len(parents)):
            depth[j] = depth[parents[j]] + 1
        _LEVELS[key] = [np.nonzero(depth == d)[0] for d in range(depth.max() + 1)]
    return _LEVELS[key]


def forward_positions(rotations: np.ndarray, positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """Global joint positions ``[..., J, 3]`` only (the common need of per-frame work): the
    same values as ``forward_kinematics``, with rotation matrices, one depth level at a time."""
    parents = np.asarray(parents)
    local = quat.to_xform(rotations)
    g_rot = np.empty_like(local)
    g_pos = np.empty(positions.shape, dtype=np.result_type(positions, local))
    levels = depth_levels(parents)
    g_rot[..., levels[0], :, :] = local[..., levels[0], :, :]
    g_pos[..., levels[0], :] = positions[..., levels[0], :]
    for joints in levels[1:]:
        p = parents[joints]
        g_pos[..., joints, :] = (g_rot[..., p, :, :] @ positions[..., joints, :, None])[..., 0] + g_pos[..., p, :]
        g_rot[..., joints, :, :] = g_rot[..., p, :, :] @ local[..., joints, :, :]
    return g_pos


def facing_directions(
    global_positions: np.ndarray, left: tuple[int, ...], right: tuple[int, ...], previous: np.ndarray | None = None
) -> np.ndarray:
    """Unit facing directions ``[T, 3]`` on the ground plane, from the across vector of
    left/right joint pairs (hips and shoulders): forward = across x up.

    Per frame, so causal. A frame whose across vector is (nearly) vertical keeps the frame
    before's direction (``previous`` for the first frame, else +Z), which is still causal."""
    across = (global_positions[..., left, :] - global_positions[..., right, :]).sum(axis=-2)
    forward = np.cross(across, UP)
    forward[..., 1] = 0.0
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


def foot_contacts(global_positions: np.ndarray, previous_positions: np.ndarray, feet: tuple[int, ...], fps: float, max_speed: float) -> np.ndarray:
    """Contact flags ``[..., len(feet)]``: a foot is planted while its speed since the previous
    frame (backward difference, units per second) is below ``max_speed``."""
    step = global_positions[..., feet, :] - previous_positions[..., feet, :]
    return (np.linalg.norm(step, axis=-1) * fps < max_speed).astype(np.float64)
