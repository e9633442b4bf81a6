"""Training the window classifiers: the perceptual-loss content classifier and the
evaluation recognisers (style, content). Plain loops, best validation accuracy kept."""

from __future__ import annotations

import copy

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from styleerd.model.classifiers import WindowClassifier
from styleerd.train.batches import TrainingData, WindowSet


@torch.no_grad()
def accuracy(model: WindowClassifier, data: TrainingData, ws: WindowSet, label: str, batch: int = 1024) -> float:
    model.eval()
    target = getattr(ws, label)
    device = next(model.parameters()).device
    correct = 0
    for i in range(0, len(ws.starts), batch):
        x = data.gather(ws.starts[i : i + batch]).to(device)
        correct += int((model(x).argmax(-1).cpu().numpy() == target[i : i + batch]).sum())
    return correct / max(1, len(ws.starts))


def train_classifier(
    data: TrainingData,
    train: WindowSet,
    val: WindowSet,
    label: str,
    instance_norm: bool,
    channels: slice,
    epochs: int,
    lr: float,
    seed: int,
    batch: int = 128,
    progress: bool = True,
    device: str = "cpu",
) -> tuple[WindowClassifier, float]:
    """Train on ``train`` windows to predict ``label`` ("style" or "content") from the feature
    ``channels``; return the model of the best validation epoch and that accuracy."""
    torch.manual_seed(seed)
    n_classes = len(data.styles if label == "style" else data.contents)
    model = WindowClassifier(
        channels.stop - channels.start, n_classes, instance_norm=instance_norm, first_channel=channels.start
    ).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    target = torch.as_tensor(getattr(train, label)).to(device)
    rng = np.random.default_rng(seed)
    best, best_acc = copy.deepcopy(model), -1.0
    for epoch in range(epochs):
        model.train()
        order = rng.permutation(len(train.starts))
        bar = tqdm(
            range(0, len(order) - batch + 1, batch),
            desc=f"{label} classifier {epoch + 1}/{epochs}",
            disable=not progress,
            leave=False,
        )
        for i in bar:
            idx = order[i : i + batch]
            x = data.gather(train.starts[idx]).to(device)
            loss = F.cross_entropy(model(x), target[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            bar.set_postfix(loss=f"{loss.item():.3f}")
        acc = accuracy(model, data, val, label)
        if acc > best_acc:
            best, best_acc = copy.deepcopy(model), acc
    return best.eval(), best_acc
