"""Training the FMD feature extractor: a denoising autoencoder on real training windows'
joint rotations (Gaussian noise sigma 0.03 on the quaternions, quaternion-angle loss)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from styleerd.model import checkpoint as ckpt
from styleerd.model import torch_quat
from styleerd.model.fmd import MotionAutoencoder
from styleerd.models import FMD, MODELS_DIR
from styleerd.train.batches import TrainingData, WindowSet, window_rotations, windows
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import setup


def angle_loss(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    d = (a * b).sum(-1).abs().clamp(max=1.0 - 1e-7)
    return (2 * torch.acos(d)).mean()


@torch.no_grad()
def reconstruction_degrees(model: MotionAutoencoder, data: TrainingData, ws: WindowSet, batch: int = 512) -> float:
    model.eval()
    total = 0.0
    for i in range(0, len(ws.starts), batch):
        q = window_rotations(data, ws.starts[i : i + batch])
        total += float(angle_loss(model(q), q)) * len(q)
    return float(np.degrees(total / max(1, len(ws.starts))))


def train_autoencoder(
    data: TrainingData,
    train: WindowSet,
    val: WindowSet,
    epochs: int = 8,
    batch: int = 128,
    lr: float = 1e-3,
    noise: float = 0.03,
    seed: int = 0,
    progress: bool = True,
) -> tuple[MotionAutoencoder, float]:
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = MotionAutoencoder(len(data.stats.reference))
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    best, best_err = copy.deepcopy(model), float("inf")
    for epoch in range(epochs):
        model.train()
        order = rng.permutation(len(train.starts))
        bar = tqdm(
            range(0, len(order) - batch + 1, batch),
            desc=f"fmd autoencoder {epoch + 1}/{epochs}",
            disable=not progress,
            leave=False,
        )
        for i in bar:
            clean = window_rotations(data, train.starts[order[i : i + batch]])
            loss = angle_loss(model(torch_quat.normalize(clean + noise * torch.randn_like(clean))), clean)
            opt.zero_grad()
            loss.backward()
            opt.step()
            bar.set_postfix(deg=f"{np.degrees(loss.item()):.2f}")
        err = reconstruction_degrees(model, data, val)
        if err < best_err:
            best, best_err = copy.deepcopy(model), err
    return best.eval(), best_err


def train_and_save(
    config: TrainConfig, data_dir: str | None = None, out: Path | None = None, progress: bool = True
) -> dict:
    """``styleerd train-fmd``: train on real training windows, keep the best validation epoch,
    save next to the shipped models (or at ``out``)."""
    torch.set_num_threads(config.threads)
    s = setup(config, data_dir, progress)
    train = windows(s.fs, s.data, "train", config.classifier_stride, config.max_train_clips)
    model, val_deg = train_autoencoder(s.data, train, s.val, seed=config.seed, progress=progress)
    test = windows(s.fs, s.data, "test", config.window)
    report = {
        "val_reconstruction_deg": round(val_deg, 3),
        "test_reconstruction_deg": round(reconstruction_degrees(model, s.data, test), 3),
    }
    meta = {
        "kind": "styleerd-fmd",
        "config": model.config(),
        "reference": s.data.stats.reference.tolist(),
        "dataset": config.dataset,
        "window": config.window,
        **report,
    }
    ckpt.save_tensors(out or MODELS_DIR / FMD, ckpt.prefixed("autoencoder", model), meta)
    return report
