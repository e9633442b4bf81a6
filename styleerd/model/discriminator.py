"""The FT-Att discriminator: a temporal conv trunk on joint positions + velocities whose
feature map m [C', T] is weighted by a feature attention w_f [C'] and a temporal attention
w_t [T], both computed from the (target style, content) labels: score = sum(m * w_f w_t^T).

With ``attention=False`` it is the ablation's standard multi-head discriminator: one output
channel per style, the target style's channel averaged over time.
"""

from __future__ import annotations

import torch
from torch import nn


def conv(in_ch: int, out_ch: int, kernel: int = 3) -> nn.Sequential:
    """Length-preserving 1D convolution (replicate padding)."""
    left = (kernel - 1) // 2
    return nn.Sequential(nn.ReplicationPad1d((left, kernel - 1 - left)), nn.Conv1d(in_ch, out_ch, kernel))


class Discriminator(nn.Module):
    def __init__(
        self,
        in_dim: int,
        n_styles: int,
        n_contents: int,
        window: int,
        layers: int = 4,
        feature_dim: int = 16,
        attention: bool = True,
    ):
        super().__init__()
        trunk: list[nn.Module] = []
        ch = in_dim
        for _ in range(layers):
            trunk += [conv(ch, ch // 3 * 2), nn.LeakyReLU(0.2)]
            ch = ch // 3 * 2
        self.trunk = nn.Sequential(*trunk)
        self.attention = attention
        self.last = conv(ch, feature_dim if attention else n_styles)
        if attention:
            self.label_mlp = nn.Sequential(
                nn.Linear(n_styles + n_contents, 64), nn.LeakyReLU(0.2), nn.Linear(64, 64), nn.LeakyReLU(0.2)
            )
            self.feature_attention = nn.Linear(64, feature_dim)
            self.temporal_attention = nn.Linear(64, window)

    def forward(self, x: torch.Tensor, style: torch.Tensor, content: torch.Tensor) -> torch.Tensor:
        """``x [B, T, C]`` (normalised positions + velocities); labels ``[B, nS]``, ``[B, nC]``.
        Returns one score per window ``[B]``."""
        m = self.last(self.trunk(x.transpose(1, 2)))  # [B, C', T]
        if not self.attention:
            return (m * style.unsqueeze(-1)).sum(1).mean(-1)
        a = self.label_mlp(torch.cat([style, content], -1))
        w = self.feature_attention(a).unsqueeze(-1) * self.temporal_attention(a).unsqueeze(1)
        return (m * w).sum(dim=(1, 2))
