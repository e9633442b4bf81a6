"""Style-ERD: Encoder -> recurrent branches (neutral + one residual branch per style) -> Decoder.

Per frame: the encoder maps the input features and the input's (style, content) labels to a
latent z_t. The neutral branch r_0 (an LSTM stack whose initial state is learned per content)
and the branch of each target style r_s (an LSTM stack with its own learned initial state)
read z_t; z'_t = r_0(z_t) + sum_s w_s r_s(z_t), with w the target weights (one-hot for one
style; a mixture or intensity otherwise). The decoder, conditioned on w, outputs joint
rotations (unit quaternions per joint; with ``pose_change``, each joint's change to the input's
own rotation) and joint velocities; joint positions follow by differentiable forward
kinematics. Only branches with a non-zero weight run.

All tensors are batch-first. ``forward`` takes T frames; ``step`` takes one frame and an
explicit recurrent state, and the two agree exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from styleerd.data.features import FeatureLayout, FeatureStats
from styleerd.model import torch_quat
from styleerd.model.config import FAMILIAR, UNFAMILIAR, GeneratorConfig
from styleerd.motion.skeleton import Skeleton


def mlp(sizes: list[int], last_activation: bool = False) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2 or last_activation:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


State = tuple[torch.Tensor, torch.Tensor]  # (h, c), each [layers, B, hidden]


@dataclass
class RecurrentState:
    """Recurrent state of a batch of streams: the neutral branch's, and each style branch's
    that has run (a branch that has not yet run starts from its learned initial state)."""

    neutral: State
    branches: dict[int, State] = field(default_factory=dict)


class StyleERD(nn.Module):
    def __init__(self, config: GeneratorConfig, skeleton: Skeleton, stats: FeatureStats):
        super().__init__()
        self.config = c = config
        J, D, nS, nC, H = c.n_joints, c.feature_dim, len(c.input_styles), len(c.contents), c.hidden
        if c.encoder[-1] != H:
            raise ValueError(f"encoder must end in the hidden size {H}, got {c.encoder}")
        self.layout = FeatureLayout(J)
        self.encoder = mlp([D + nS + nC, *c.encoder])
        self.neutral = nn.LSTM(H, H, c.neutral_layers, batch_first=True)
        self.branch_styles = c.branch_styles
        self.branches = nn.ModuleList(nn.LSTM(H, H, c.style_layers, batch_first=True) for _ in self.branch_styles)
        init = nn.Parameter if c.learned_init else (lambda t: nn.Parameter(t, requires_grad=False))
        self.neutral_h0 = init(torch.zeros(nC, c.neutral_layers, H))
        self.neutral_c0 = init(torch.zeros(nC, c.neutral_layers, H))
        self.branch_h0 = init(torch.zeros(len(self.branch_styles), c.style_layers, H))
        self.branch_c0 = init(torch.zeros(len(self.branch_styles), c.style_layers, H))
        self.decoder = mlp([H + nS, *c.decoder, 7 * J])
        if c.added_styles:  # the added styles' target weights enter the decoder's first layer apart,
            # so the trained styles' outputs stay bit-identical (a wider product sums in another order)
            self.decoder_added = nn.Parameter(torch.zeros(len(c.added_styles), self.decoder[0].out_features))
        self.skeleton = skeleton
        self.parents = [int(p) for p in skeleton.parents]
        self.register_buffer("offsets", torch.tensor(skeleton.offsets, dtype=torch.float32))
        self.register_buffer("mean", torch.tensor(stats.mean, dtype=torch.float32))
        self.register_buffer("std", torch.tensor(stats.std, dtype=torch.float32))
        self.register_buffer("reference", torch.tensor(stats.reference, dtype=torch.float32))
        # the styles' postures (``runtime.posture``): rotation vectors and joint offsets ``[styles, J, 3]``,
        # measured after training and kept in the model file's configuration, not among the weights;
        # None: not measured
        self.posture: torch.Tensor | None = None
        self.posture_offsets: torch.Tensor | None = None
        self.posture_frame = "heading"  # the frame the offsets are in (``model.stored.posture_frame``)
        self.familiar = (FAMILIAR, UNFAMILIAR)  # degrees (``model.stored.familiar_range``)

    def stats(self) -> FeatureStats:
        """The feature normalisation the model was trained with."""
        return FeatureStats(self.mean.double().numpy(), self.std.double().numpy(), self.reference.double().numpy())

    # ---------------------------------------------------------------- recurrent state
    def initial_state(self, content: torch.Tensor) -> RecurrentState:
        """Neutral state selected by the content label (one-hot or probabilities ``[B, nC]``)."""
        h = torch.einsum("bc,clh->lbh", content, self.neutral_h0).contiguous()
        c = torch.einsum("bc,clh->lbh", content, self.neutral_c0).contiguous()
        return RecurrentState((h, c))

    def branch_initial_state(self, k: int, batch: int) -> State:
        """Style branch k's learned initial state for ``batch`` streams."""
        return (
            self.branch_h0[k].unsqueeze(1).expand(-1, batch, -1).contiguous(),
            self.branch_c0[k].unsqueeze(1).expand(-1, batch, -1).contiguous(),
        )

    # ---------------------------------------------------------------- network
    def forward(
        self,
        x: torch.Tensor,
        style: torch.Tensor,
        content: torch.Tensor,
        target: torch.Tensor,
        state: RecurrentState | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, RecurrentState]:
        """``x [B, T, D]`` normalised features; ``style [B, nI]`` (over ``input_styles``),
        ``content [B, nC]`` the input's labels; ``target [B, nS]`` the target weights (over
        ``styles``). Returns unit quaternions ``[B, T, J, 4]``, normalised velocities
        ``[B, T, 3J]`` and the new state."""
        if state is None:
            state = self.initial_state(content)
        z = self.encode(x, style, content)
        out, neutral_state = self.neutral(z, state.neutral)
        out, branches = self._add_branches(z, out, target, dict(state.branches))
        rotations, velocities = self.decode(out, target)
        return self.posed(rotations, x), velocities, RecurrentState(neutral_state, branches)

    def forward_targets(
        self, x: torch.Tensor, style: torch.Tensor, content: torch.Tensor, targets: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``forward`` from fresh states of ``x [B, T, D]`` under K target weightings at once,
        ``targets [K*B, nS]`` (rows k*B .. k*B + B - 1: the k-th): the encoder and the neutral
        branch, which do not depend on the target, run once (training's reconstruction and
        transfer of one batch). Returns rotations and velocities of the K*B rows."""
        k = targets.shape[0] // x.shape[0]
        z = self.encode(x, style, content)
        out, _ = self.neutral(z, self.initial_state(content).neutral)
        out, _ = self._add_branches(z.repeat(k, 1, 1), out.repeat(k, 1, 1), targets, {})
        rotations, velocities = self.decode(out, targets)
        return self.posed(rotations, x.repeat(k, 1, 1)), velocities

    def _add_branches(
        self, z: torch.Tensor, out: torch.Tensor, target: torch.Tensor, branches: dict[int, State]
    ) -> tuple[torch.Tensor, dict[int, State]]:
        """``out`` plus each style branch's output on ``z`` weighted by ``target``; a branch
        runs only on the rows that weight it."""
        B = z.shape[0]
        for k, s in enumerate(self.branch_styles):
            w = target[:, s]
            rows = torch.nonzero(w != 0).squeeze(1)
            if len(rows) == 0:
                continue
            h, c = branches.get(k) or self.branch_initial_state(k, B)
            if len(rows) == B:
                y, (h, c) = self.branches[k](z, (h, c))
                out = out + w[:, None, None] * y
            else:
                y, (hr, cr) = self.branches[k](z[rows], (h[:, rows], c[:, rows]))
                out = out.index_add(0, rows, w[rows, None, None] * y)
                h, c = h.index_copy(1, rows, hr), c.index_copy(1, rows, cr)
            branches[k] = (h, c)
        return out, branches

    def encode(self, x: torch.Tensor, style: torch.Tensor, content: torch.Tensor) -> torch.Tensor:
        """The latent ``z [B, T, H]`` of features ``x [B, T, D]`` with the input's labels."""
        labels = torch.cat([style, content], -1).unsqueeze(1).expand(*x.shape[:2], -1)
        return self.encoder(torch.cat([x, labels], -1))

    def decode(self, out: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Unit quaternions ``[B, T, J, 4]`` and normalised velocities ``[B, T, 3J]`` of the
        branches' sum ``out [B, T, H]`` under target weights ``[B, nS]``."""
        B, T, _ = out.shape
        nI = len(self.config.input_styles)
        target = target.unsqueeze(1).expand(B, T, -1)
        y = self.decoder[0](torch.cat([out, target[..., :nI]], -1))
        if self.config.added_styles:
            y = y + target[..., nI:] @ self.decoder_added
        y = self.decoder[1:](y)
        J = self.config.n_joints
        return torch_quat.normalize(y[..., : 4 * J].reshape(B, T, J, 4)), y[..., 4 * J :]

    def posed(self, decoded: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The output's rotations ``[B, T, J, 4]`` from the decoder's: themselves, or with
        ``pose_change`` each applied to the input's own rotation of features ``x``."""
        return torch_quat.mul(self.raw_rotations(x), decoded) if self.config.pose_change else decoded

    def start_at_no_change(self) -> None:
        """``pose_change``: the decoder's rotation outputs say "no change" for every joint (their
        weights zero, their bias the identity), whatever the layers before them hold."""
        last, J = self.decoder[-1], self.config.n_joints
        with torch.no_grad():
            last.weight[: 4 * J] = 0.0
            last.bias[: 4 * J] = torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(J)

    def step(
        self,
        x: torch.Tensor,
        style: torch.Tensor,
        content: torch.Tensor,
        target: torch.Tensor,
        state: RecurrentState | None,
    ) -> tuple[torch.Tensor, torch.Tensor, RecurrentState]:
        """One frame ``x [B, D]`` -> rotations ``[B, J, 4]``, velocities ``[B, 3J]``, state."""
        rot, vel, state = self.forward(x.unsqueeze(1), style, content, target, state)
        return rot[:, 0], vel[:, 0], state

    # ---------------------------------------------------------------- outputs as features
    def motion_channels(self, rotations: torch.Tensor, velocities: torch.Tensor) -> torch.Tensor:
        """Normalised [rotations | positions | velocities] (the first 10J feature dims) of a
        generated motion; positions by forward kinematics of the rotations."""
        J = self.config.n_joints
        lead = rotations.shape[:-2]
        sign = torch.where((rotations * self.reference).sum(-1, keepdim=True) < 0, -1.0, 1.0)
        rot = (rotations * sign).reshape(*lead, 4 * J)
        pos = torch_quat.root_relative_positions(rotations, self.offsets, self.parents).reshape(*lead, 3 * J)
        L = self.layout
        rot_n = (rot - self.mean[L.rotations]) / self.std[L.rotations]
        pos_n = (pos - self.mean[L.positions]) / self.std[L.positions]
        return torch.cat([rot_n, pos_n, velocities], -1)

    def raw_rotations(self, x: torch.Tensor) -> torch.Tensor:
        """Unit quaternions ``[..., J, 4]`` of normalised input features."""
        J = self.config.n_joints
        q = x[..., self.layout.rotations] * self.std[self.layout.rotations] + self.mean[self.layout.rotations]
        return torch_quat.normalize(q.reshape(*x.shape[:-1], J, 4))
