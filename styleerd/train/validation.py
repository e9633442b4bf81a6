"""Quick quality signal of a generator on held-out windows: reconstruction error (degrees, cm),
style recognition accuracy (SRA) and content recognition accuracy (CRA) of its transfers."""

from __future__ import annotations

import numpy as np
import torch

from styleerd.model import torch_quat
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.generator import StyleERD
from styleerd.train.batches import TrainingData, WindowSet


def transfer_targets(style: np.ndarray, neutral: int, n_styles: int) -> tuple[np.ndarray, np.ndarray]:
    """The paper's transfer tasks for windows of the given styles: a neutral window goes to
    every other style, a styled window goes to neutral. Returns (window index, target)."""
    rows, targets = [], []
    for i, s in enumerate(style):
        for t in ([t for t in range(n_styles) if t != neutral] if s == neutral else [neutral]):
            rows.append(i)
            targets.append(t)
    return np.array(rows, dtype=np.int64), np.array(targets, dtype=np.int64)


@torch.no_grad()
def validate(
    model: StyleERD,
    data: TrainingData,
    ws: WindowSet,
    style_recogniser: WindowClassifier | None = None,
    content_recogniser: WindowClassifier | None = None,
    batch: int = 512,
) -> dict[str, float]:
    model.eval()
    L = model.layout
    deg, cm, n = 0.0, 0.0, 0
    for i in range(0, len(ws.starts), batch):
        sl = slice(i, i + batch)
        x = data.gather(ws.starts[sl])
        s, c = data.onehot_style(ws.style[sl]), data.onehot_content(ws.content[sl])
        rot, vel, _ = model(x, s, c, s)
        target = model.raw_rotations(x)
        d = (rot * target).sum(-1).abs().clamp(max=1.0)
        deg += float(torch.rad2deg(2 * torch.acos(d)).mean(dim=(1, 2)).sum())
        pos = torch_quat.root_relative_positions(rot, model.offsets, model.parents)
        pos_in = (x[..., L.positions] * model.std[L.positions] + model.mean[L.positions]).reshape(pos.shape)
        cm += float((pos - pos_in).norm(dim=-1).mean(dim=(1, 2)).sum())
        n += len(x)
    out = {"rec_deg": deg / n, "rec_cm": cm / n}
    if style_recogniser is None or content_recogniser is None:
        return out
    hit_s = hit_c = n = 0
    for r, t, _, _, ch in transfers(model, data, ws, batch):
        hit_s += int((style_recogniser(ch).argmax(-1).numpy() == t).sum())
        hit_c += int((content_recogniser(ch).argmax(-1).numpy() == ws.content[r]).sum())
        n += len(r)
    out.update(sra=hit_s / n, cra=hit_c / n)
    return out


@torch.no_grad()
def transfers(model: StyleERD, data: TrainingData, ws: WindowSet, batch: int = 512):
    """The transfer tasks of ``ws`` in batches: (window rows, targets, rotations, velocities,
    normalised motion channels)."""
    rows, targets = transfer_targets(ws.style, model.config.neutral_index, len(data.styles))
    for i in range(0, len(rows), batch):
        r, t = rows[i : i + batch], targets[i : i + batch]
        x = data.gather(ws.starts[r])
        rot, vel, _ = model(x, data.onehot_style(ws.style[r]), data.onehot_content(ws.content[r]), data.onehot_style(t))
        yield r, t, rot, vel, model.motion_channels(rot, vel)
