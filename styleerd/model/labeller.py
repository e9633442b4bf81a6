"""OnlineLabeller: the input's style and content, inferred from the frames seen so far.

A small causal recogniser (a linear layer, a GRU, two linear heads) over the generator's
normalised input features. After every frame it gives posteriors over styles and contents,
which the stylizer passes to the generator in place of labels the user did not give (the
learned initial states and the encoder accept probabilities as well as one-hot labels).
"""

from __future__ import annotations

import torch
from torch import nn

from styleerd.model.stored import Familiarity


class OnlineLabeller(nn.Module):
    def __init__(self, in_dim: int, n_styles: int, n_contents: int, hidden: int = 64):
        super().__init__()
        self.in_dim, self.n_styles, self.n_contents, self.hidden = in_dim, n_styles, n_contents, hidden
        self.inp = nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU())
        self.gru = nn.GRU(hidden, hidden, batch_first=True)
        self.style = nn.Linear(hidden, n_styles)
        self.content = nn.Linear(hidden, n_contents)
        self.familiar: Familiarity | None = None  # where its states are like its training streams' (none: everywhere)

    def forward(
        self, x: torch.Tensor, h: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``x [B, T, D]`` -> style logits ``[B, T, nS]``, content logits ``[B, T, nC]``, state."""
        y, h = self.gru(self.inp(x), h)
        return self.style(y), self.content(y), h

    def states(self, x: torch.Tensor) -> torch.Tensor:
        """``x [B, T, D]`` -> the state after each frame ``[B, T, H]`` of streams starting at ``x``'s first."""
        return self.gru(self.inp(x))[0]

    def config(self) -> dict:
        return {"in_dim": self.in_dim, "n_styles": self.n_styles, "n_contents": self.n_contents, "hidden": self.hidden}
