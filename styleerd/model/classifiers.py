"""Window classifiers on normalised motion channels [rotations | positions | velocities].

One architecture, two uses kept apart:
- the content classifier of the perceptual loss (InstanceNorm after each conv, so per-window
  statistics, where much of the style lives, are removed and it keys on content);
- the evaluation recognisers (style and content), trained on real training windows only,
  which judge transferred motion (SRA / CRA). They read joint positions and velocities only:
  what a viewer sees. Rotation channels also carry twist about the bone axis, which moves no
  joint and which a judge of style or content should not key on.
"""

from __future__ import annotations

import torch
from torch import nn

from styleerd.model.discriminator import conv


class WindowClassifier(nn.Module):
    """Reads channels ``first_channel : first_channel + in_dim`` of its input windows
    ``[B, T, C]``, so every caller passes whole feature windows."""

    def __init__(
        self,
        in_dim: int,
        n_classes: int,
        channels: tuple[int, ...] = (128, 64, 32),
        kernel: int = 5,
        instance_norm: bool = False,
        first_channel: int = 0,
    ):
        super().__init__()
        self.in_dim, self.channels, self.kernel, self.instance_norm = in_dim, channels, kernel, instance_norm
        self.first_channel = first_channel
        self.features = nn.ModuleList()
        ch = in_dim
        for out in channels:
            norm = nn.InstanceNorm1d(out) if instance_norm else nn.Identity()
            self.features.append(nn.Sequential(conv(ch, out, kernel), norm, nn.LeakyReLU(0.2)))
            ch = out
        self.head = nn.Linear(2 * ch, n_classes)

    def feature_maps(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Every conv layer's output ``[B, C_i, T]`` for ``x [B, T, C]``."""
        maps, h = [], x[..., self.first_channel : self.first_channel + self.in_dim].transpose(1, 2)
        for layer in self.features:
            h = layer(h)
            maps.append(h)
        return maps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Class logits ``[B, n_classes]`` of windows ``x [B, T, C]``."""
        return self.logits(self.feature_maps(x)[-1])

    def logits(self, h: torch.Tensor) -> torch.Tensor:
        """Class logits of the last feature map ``h [B, C_last, T]``, mean- and max-pooled over time."""
        return self.head(torch.cat([h.mean(-1), h.amax(-1)], -1))
