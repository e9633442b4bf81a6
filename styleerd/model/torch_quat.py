"""Torch twins of the quaternion and kinematics functions the network needs (differentiable).
Same convention as ``styleerd.motion.quat``: (w, x, y, z), ``mul(a, b)`` applies b first."""

from __future__ import annotations

import torch


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


def mul_vec(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * torch.linalg.cross(u, v, dim=-1)
    return v + w * t + torch.linalg.cross(u, t, dim=-1)


def normalize(q: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    return q / q.norm(dim=-1, keepdim=True).clamp_min(eps)


def root_relative_positions(rotations: torch.Tensor, offsets: torch.Tensor, parents: list[int]) -> torch.Tensor:
    """Joint positions ``[..., J, 3]`` relative to the root, in the root's parent frame, from
    local rotations ``[..., J, 4]`` and rest offsets ``[J, 3]`` (forward kinematics with the
    root at the origin)."""
    g_rot = [rotations[..., 0, :]]
    g_pos = [torch.zeros_like(rotations[..., 0, :3])]
    for j in range(1, len(parents)):
        p = parents[j]
        g_pos.append(mul_vec(g_rot[p], offsets[j].expand_as(g_pos[p])) + g_pos[p])
        g_rot.append(mul(g_rot[p], rotations[..., j, :]))
    return torch.stack(g_pos, dim=-2)


def angle_loss(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """The paper's L_quat: mean of acos(|a.b|)^2 (half the rotation angle, squared); the clamp keeps the
    gradient of acos finite at identical rotations."""
    d = (a * b).sum(-1).abs().clamp(0.0, 1.0 - eps)
    return torch.acos(d).pow(2).mean()
