"""Training the OnlineLabeller on real training clips, and how well it labels streams.

Training sequences are ``length``-frame stretches of training clips, each starting from a
fresh state (a stream can begin anywhere in a motion); the loss is the labels' cross-entropy
at every frame, so early frames learn to guess and later ones to be sure. Accuracy is measured
on streams that start at the first frame of each clip of a split, after 1, 10 and 30 frames.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from styleerd.data.cache import FeatureSet
from styleerd.model import checkpoint as ckpt
from styleerd.model.labeller import OnlineLabeller
from styleerd.train.batches import TrainingData, windows
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import setup

AFTER_FRAMES = (1, 10, 30)


@torch.no_grad()
def stream_accuracy(model: OnlineLabeller, fs: FeatureSet, data: TrainingData, split: str, after: tuple[int, ...] = AFTER_FRAMES) -> dict[int, dict[str, float]]:
    """{n: {"style": acc, "content": acc, "streams": k}}: labels right after n frames of a
    stream that starts at a clip's first frame (clips shorter than n frames not counted)."""
    model.eval()
    clips = fs.clips(split)
    longest = max(after)
    rows = [fs.frames(c) for c in clips]
    out = {}
    style_pred, content_pred, length = [], [], []
    for sl in rows:
        n = min(longest, sl.stop - sl.start)
        s, c, _ = model(data.frames[sl.start : sl.start + n][None])
        style_pred.append(s[0].argmax(-1).numpy())
        content_pred.append(c[0].argmax(-1).numpy())
        length.append(n)
    true_s = np.array([data.styles.index(s) for s in fs.styles[clips]])
    true_c = np.array([data.contents.index(c) for c in fs.contents[clips]])
    for n in after:
        keep = [i for i, k in enumerate(length) if k >= n]
        out[n] = {
            "style": round(float(np.mean([style_pred[i][n - 1] == true_s[i] for i in keep])), 4),
            "content": round(float(np.mean([content_pred[i][n - 1] == true_c[i] for i in keep])), 4),
            "streams": len(keep),
        }
    return out


def train_labeller(fs: FeatureSet, data: TrainingData, epochs: int = 6, length: int = 40, stride: int = 4, batch: int = 64, lr: float = 2e-3, seed: int = 0, max_clips: int = 0, progress: bool = True) -> tuple[OnlineLabeller, dict]:
    """Train; keep the epoch whose validation streams are labelled best after 30 frames."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = OnlineLabeller(data.frames.shape[1], len(data.styles), len(data.contents))
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    ws = windows(fs, data, "train", stride, max_clips)
    idx = torch.as_tensor(ws.starts[:, None] + np.arange(length))
    ok = (idx[:, -1] < torch.as_tensor(fs.clip_start[ws.clip + 1])).numpy()  # whole stretch inside its clip
    starts, style, content = ws.starts[ok], torch.as_tensor(ws.style[ok]), torch.as_tensor(ws.content[ok])
    best, best_score, history = copy.deepcopy(model), -1.0, []
    for epoch in range(epochs):
        model.train()
        order = rng.permutation(len(starts))
        bar = tqdm(range(0, len(order) - batch + 1, batch), desc=f"labeller {epoch + 1}/{epochs}", disable=not progress, leave=False)
        for i in bar:
            b = order[i : i + batch]
            x = data.frames[torch.as_tensor(starts[b][:, None] + np.arange(length))]
            s_logits, c_logits, _ = model(x)
            loss = F.cross_entropy(s_logits.reshape(-1, len(data.styles)), style[b].repeat_interleave(length)) + F.cross_entropy(
                c_logits.reshape(-1, len(data.contents)), content[b].repeat_interleave(length)
            )
            opt.zero_grad()
            loss.backward()
            opt.step()
            bar.set_postfix(loss=f"{loss.item():.3f}")
        val = stream_accuracy(model, fs, data, "val")
        score = val[30]["style"] + val[30]["content"]
        history.append({"epoch": epoch + 1, "val": val})
        if score > best_score:
            best, best_score = copy.deepcopy(model), score
    return best.eval(), {"history": history}


def train_and_save(config: TrainConfig, data_dir: str | None = None, out: Path | None = None, progress: bool = True) -> dict:
    """``styleerd train-labeller``: train on the config's dataset, report stream accuracy on
    the test split, save next to the shipped models (or at ``out``)."""
    torch.set_num_threads(config.threads)
    s = setup(config, data_dir, progress)
    model, report = train_labeller(s.fs, s.data, seed=config.seed, max_clips=config.max_train_clips, progress=progress)
    report["test"] = stream_accuracy(model, s.fs, s.data, "test")
    meta = {"kind": "styleerd-labeller", "config": model.config(), "styles": s.data.styles, "contents": s.data.contents, "dataset": config.dataset, **report}
    ckpt.save_tensors(out or ckpt.MODELS_DIR / ckpt.LABELLER, ckpt.prefixed("labeller", model), meta)
    return report
