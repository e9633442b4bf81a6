"""OnlineLabeller: the input's style and content, inferred from the frames seen so far.

A small causal recogniser (a linear layer, a GRU, two linear heads) over the generator's
normalised input features. After every frame it gives posteriors over styles and contents,
which the stylizer passes to the generator in place of labels the user did not give (the
learned initial states and the encoder accept probabilities as well as one-hot labels).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


class OnlineLabeller(nn.Module):
    def __init__(self, in_dim: int, n_styles: int, n_contents: int, hidden: int = 64):
        super().__init__()
        self.in_dim, self.n_styles, self.n_contents, self.hidden = in_dim, n_styles, n_contents, hidden
        self.inp = nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU())
        self.gru = nn.GRU(hidden, hidden, batch_first=True)
        self.style = nn.Linear(hidden, n_styles)
        self.content = nn.Linear(hidden, n_contents)

    def forward(self, x: torch.Tensor, h: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``x [B, T, D]`` -> style logits ``[B, T, nS]``, content logits ``[B, T, nC]``, state."""
        y, h = self.gru(self.inp(x), h)
        return self.style(y), self.content(y), h

    def config(self) -> dict:
        return {"in_dim": self.in_dim, "n_styles": self.n_styles, "n_contents": self.n_contents, "hidden": self.hidden}


def toward_neutral(p_style: np.ndarray, neutral: int, unsure: float = 0.5, sure: float = 0.9) -> np.ndarray:
    """Style posteriors ``[N, nS]`` the labeller is unsure of, leaning to the neutral style:
    a top probability at ``unsure`` or below becomes the neutral label, one at ``sure`` or above
    is kept, linearly between. Telling the encoder "neutral" when in doubt costs little (the
    target branch still adds the style); a wrong confident style gets it subtracted."""
    keep = np.clip((p_style.max(-1, keepdims=True) - unsure) / (sure - unsure), 0.0, 1.0)
    out = keep * p_style
    out[..., neutral] += 1.0 - keep[..., 0]
    return out.astype(p_style.dtype)
