"""The feature extractor of the Fréchet Motion Distance (FMD), as in the paper: a denoising
1D-convolutional autoencoder on joint rotations. Its last encoder layer, averaged over time,
is the feature of a window."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from styleerd.model import torch_quat


class MotionAutoencoder(nn.Module):
    def __init__(self, n_joints: int, channels: tuple[int, ...] = (128, 96, 64), kernel: int = 5):
        super().__init__()
        self.n_joints, self.channels, self.kernel = n_joints, channels, kernel
        pad = kernel // 2
        enc, ch = [], 4 * n_joints
        for out in channels:
            enc += [nn.Conv1d(ch, out, kernel, padding=pad), nn.LeakyReLU(0.2)]
            ch = out
        self.encoder = nn.Sequential(*enc)
        dec = []
        for out in reversed(channels[:-1]):
            dec += [nn.Conv1d(ch, out, kernel, padding=pad), nn.LeakyReLU(0.2)]
            ch = out
        dec.append(nn.Conv1d(ch, 4 * n_joints, kernel, padding=pad))
        self.decoder = nn.Sequential(*dec)

    def encode(self, rotations: torch.Tensor) -> torch.Tensor:
        """Unit quaternions ``[B, T, J, 4]`` -> encoder output ``[B, C, T]``."""
        B, T = rotations.shape[:2]
        return self.encoder(rotations.reshape(B, T, -1).transpose(1, 2))

    def features(self, rotations: torch.Tensor) -> torch.Tensor:
        """The FMD feature of each window ``[B, C]``: the last encoder layer, mean over time."""
        return self.encode(rotations).mean(-1)

    def forward(self, rotations: torch.Tensor) -> torch.Tensor:
        B, T = rotations.shape[:2]
        y = self.decoder(self.encode(rotations)).transpose(1, 2).reshape(B, T, self.n_joints, 4)
        return torch_quat.normalize(y)

    def config(self) -> dict:
        return {"n_joints": self.n_joints, "channels": list(self.channels), "kernel": self.kernel}


def hemisphere(rotations: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Quaternions ``[..., J, 4]`` flipped into the hemisphere of ``reference [J, 4]``."""
    return rotations * torch.where((rotations * reference).sum(-1, keepdim=True) < 0, -1.0, 1.0)


@torch.no_grad()
def fmd_features(model: MotionAutoencoder, rotations: torch.Tensor, reference: torch.Tensor) -> np.ndarray:
    """FMD features ``[B, C]`` (float64) of windows of unit quaternions ``[B, T, J, 4]``."""
    return model.features(hemisphere(rotations, reference)).numpy().astype(np.float64)
