"""Torch twins of the quaternion and kinematics functions the network needs (differentiable).
Same convention as ``styleerd.motion.quat``: (w, x, y, z), ``mul(a, b)`` applies b first."""

from __future__ import annotations

import functools
import itertools

import torch

from styleerd.model.config import LIMB_ROUNDS


def mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def inv(q: torch.Tensor) -> torch.Tensor:
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def add_change(given: torch.Tensor, same: torch.Tensor, styled: torch.Tensor) -> torch.Tensor:
    """``given * inv(same) * styled`` per joint: the input turned by the style's change (``runtime.stylizer``)."""
    return normalize(mul(normalize(given), mul(inv(same), styled)))


def from_scaled_angle_axis(v: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """Rotation by ``|v|`` radians about ``v``'s direction (a rotation vector ``[..., 3]``; 0: identity)."""
    angle = v.norm(dim=-1, keepdim=True)
    return torch.cat([torch.cos(angle / 2), torch.sin(angle / 2) * v / angle.clamp_min(eps)], dim=-1)


def slerp(a: torch.Tensor, b: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Spherical interpolation from ``a`` (t=0) to ``b`` (t=1) along the shorter arc; ``t [...]``."""
    d = (a * b).sum(-1, keepdim=True)
    b = torch.where(d < 0, -b, b)
    theta = torch.arccos(d.abs().clamp(max=1.0))
    s, t = torch.sin(theta), t[..., None]
    near = s < 1e-6
    wa = torch.where(near, 1 - t, torch.sin((1 - t) * theta) / torch.where(near, 1.0, s))
    wb = torch.where(near, t, torch.sin(t * theta) / torch.where(near, 1.0, s))
    return normalize(wa * a + wb * b)


def angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Rotation angle (radians) of ``inv(a) * b``, exact for small angles."""
    d = mul(inv(a), b)
    return 2.0 * torch.atan2(d[..., 1:].norm(dim=-1), d[..., 0].abs())


def mul_vec(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * torch.linalg.cross(u, v, dim=-1)
    return v + w * t + torch.linalg.cross(u, t, dim=-1)


def normalize(q: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    return q / q.norm(dim=-1, keepdim=True).clamp_min(eps)


def between(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """The shortest-arc rotation taking ``a``'s direction to ``b``'s ``[..., 3]`` (a zero vector:
    the identity; opposite vectors, left to the half turn's axis ``quat.between`` picks, are not
    handled here)."""
    w = a.norm(dim=-1, keepdim=True) * b.norm(dim=-1, keepdim=True)
    q = torch.cat([w + (a * b).sum(-1, keepdim=True), torch.linalg.cross(a, b, dim=-1)], -1)
    return torch.where(w > eps, normalize(q, eps), q.new_tensor([1.0, 0.0, 0.0, 0.0]))


def ends_below_the_eyes(
    moved: torch.Tensor,
    positions: torch.Tensor,
    up: torch.Tensor,
    head: int,
    eyes: float,
    limb_ends: list[int],
    parents: list[int],
) -> torch.Tensor:
    """``moved [..., J, 3]`` (where a posture moves each joint of the input's pose ``positions [..., J,
    3]``) with each limb's end's (``limb_ends``) rise ``r`` along ``up [..., 3]`` cut to the smooth
    minimum ``(r^-3 + b^-3)^(-1/3)`` of itself and how far ``b`` the end is below the eyes (``eyes``
    above the ``head`` joint; none at or above them), and its middle joint's rise cut in the same
    proportion; ``runtime.stylizer._ends_below_the_eyes``' twin."""
    out = list(moved.unbind(-2))
    for m in (m for m in limb_ends if m >= 0):
        rise = (moved[..., m, :] * up).sum(-1, keepdim=True)
        below = eyes + ((positions[..., head, :] - positions[..., m, :]) * up).sum(-1, keepdim=True)
        b, r = below.clamp_min(0.0), rise.clamp_min(1e-12)
        kept = torch.where(rise > 0, r * b / (r**3 + b**3).pow(1.0 / 3.0), rise)  # what is left of the rise
        out[m] = moved[..., m, :] - (rise - kept) * up
        k = parents[m]
        middle = (moved[..., k, :] * up).sum(-1, keepdim=True)
        cut = torch.where((rise > 0) & (middle > 0), middle * (1.0 - kept / r), 0.0)
        out[k] = moved[..., k, :] - cut * up
    return torch.stack(out, -2)


def reach(
    rotations: torch.Tensor,
    offsets: torch.Tensor,
    targets: torch.Tensor,
    parents: list[int],
    limb_ends: list[int] | None = None,
) -> torch.Tensor:
    """``rotations [..., J, 4]`` (local) turned so that each joint's children go towards
    ``targets [..., J, 3]`` (relative to the root, in the root's parent frame): down the chain, each
    joint but the root by the shortest arc from its children's summed bone vectors (``offsets
    [J, 3]``) to the summed vectors to their targets; the first joint of a two-bone limb (``limb_ends``,
    ``motion.humanoid.limb_ends``) so that its bone goes where ``limb_elbow`` puts it.
    ``runtime.stylizer._reach``'s twin."""
    out = list(rotations.unbind(-2))
    G, X = list(out), [torch.zeros_like(targets[..., 0, :])] * len(parents)
    for j, p in enumerate(parents):
        if p < 0:
            continue
        G[j] = mul(G[p], out[j])
        X[j] = X[p] + mul_vec(G[p], offsets[j].expand_as(X[p]))
        kids = [k for k in range(j + 1, len(parents)) if parents[k] == j]
        if not kids:
            continue
        now = sum(mul_vec(G[j], offsets[k].expand_as(X[j])) for k in kids)
        if limb_ends is not None and limb_ends[j] >= 0:
            end = limb_ends[j]
            wanted = limb_elbow(
                targets[..., parents[end], :] - X[j],
                targets[..., end, :] - X[j],
                offsets[parents[end]].norm(),
                offsets[end].norm(),
            )
        else:
            wanted = sum(targets[..., k, :] - X[j] for k in kids)
        G[j] = mul(between(now, wanted), G[j])
        out[j] = mul(inv(G[p]), G[j])
    return torch.stack(out, -2)


def limb_elbow(elbow: torch.Tensor, end: torch.Tensor, upper: torch.Tensor, lower: torch.Tensor) -> torch.Tensor:
    """Where a two-bone limb's middle joint goes (``[..., 3]``, from the limb's first joint), given its
    target ``elbow`` and the end's target ``end``: the point at ``upper`` from the first joint nearest,
    in the least squares, to the middle joint's target and to the sphere of radius ``lower`` about the
    end's target (from which the lower bone reaches it), by ``LIMB_ROUNDS`` rounds of projections;
    ``runtime.stylizer._limb_elbow``'s twin."""
    e = elbow
    for _ in range(LIMB_ROUNDS):
        e = upper * e / e.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        reach = e - end
        e = 0.5 * (elbow + end + lower * reach / reach.norm(dim=-1, keepdim=True).clamp_min(1e-12))
    return upper * e / e.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def body_axes(
    positions: torch.Tensor, hips: int, head: int, left: tuple[int, ...], right: tuple[int, ...]
) -> torch.Tensor:
    """The body's own axes as rows ``[..., 3, 3]`` (left, up, forward) of joint positions ``[..., J,
    3]``; ``motion.kinematics.body_axes``' twin."""
    up = positions[..., head, :] - positions[..., hips, :]
    across = (positions[..., list(left), :] - positions[..., list(right), :]).sum(-2)
    forward = torch.linalg.cross(across, up, dim=-1)
    across = torch.linalg.cross(up, forward, dim=-1)
    axes = torch.stack([across, up, forward], -2)
    return axes / axes.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def root_relative_positions(rotations: torch.Tensor, offsets: torch.Tensor, parents: list[int]) -> torch.Tensor:
    """Joint positions ``[..., J, 3]`` relative to the root, in the root's parent frame, from
    local rotations ``[..., J, 4]`` and rest offsets ``[J, 3]`` (forward kinematics with the
    root at the origin). The joints of one depth run together, taken from the rotations by one
    gather and a split (a gather per joint would cost a full-size zero fill each in training's
    backward pass)."""
    sizes, slots, by_depth, order = _depth_levels(tuple(int(p) for p in parents))
    levels = rotations[..., by_depth, :].split(sizes, -2)
    level_offsets = offsets[by_depth].split(sizes, -2)
    g_rot = levels[0]
    g_pos = torch.zeros_like(g_rot[..., :3])
    out = [g_pos]
    for rot, offset, slot in zip(levels[1:], level_offsets[1:], slots):
        p_rot, p_pos = g_rot[..., slot, :], g_pos[..., slot, :]
        g_pos = mul_vec(p_rot, offset.expand_as(p_pos)) + p_pos
        g_rot = mul(p_rot, rot)
        out.append(g_pos)
    return torch.cat(out, -2)[..., order, :]


@functools.lru_cache(maxsize=64)
def _depth_levels(parents: tuple[int, ...]) -> tuple[list[int], list[torch.Tensor], torch.Tensor, torch.Tensor]:
    """Joints by depth: how many at each depth (the root alone at depth 0), each joint's
    parent's slot in the depth above, the joints in depth order, and the permutation from
    depth order back to the skeleton's."""
    levels = [[0]]
    while joints := [j for j, p in enumerate(parents) if p in levels[-1] and j != 0]:
        levels.append(joints)
    by_depth = [j for level in levels for j in level]
    if sorted(by_depth) != list(range(len(parents))):
        raise ValueError(f"parents {list(parents)} do not form one tree rooted at joint 0")
    slots = [torch.tensor([above.index(parents[j]) for j in level]) for above, level in itertools.pairwise(levels)]
    return (
        [len(level) for level in levels],
        slots,
        torch.tensor(by_depth),
        torch.tensor([by_depth.index(j) for j in range(len(parents))]),
    )


def angle_loss(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """The paper's L_quat: mean of acos(|a.b|)^2 (half the rotation angle, squared); the clamp keeps the
    gradient of acos finite at identical rotations."""
    d = (a * b).sum(-1).abs().clamp(0.0, 1.0 - eps)
    return torch.acos(d).pow(2).mean()
