"""A second judge of style, of another design than the evaluation recognisers: those read 24-frame
windows of every feature channel with a convolution; this one reads whole clips, joint positions
and the root's velocity only (no rotation), with a recurrent network (a GRU whose states are
averaged over the clip). A transfer that fools the window recognisers with a few short-lived
cues, or one whose pace still says "elderly", is read here as it plays out.

``styleerd eval clip-styles``: trains it on Bandai-Namco-2's training takes (once; kept in
``models/clip-recogniser-bandai2``), reads the test takes themselves (its ceiling), then every
styled test take streamed back to neutral and every neutral one into each style, as ``transfer``
runs them (labels inferred online, with and without ``--root-speed``): per pair, how many takes
are read as the target and how many still as the source."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from styleerd.atomic import atomic_write_text
from styleerd.data.cache import FeatureSet, prepare
from styleerd.data.features import FeatureLayout, motion_features
from styleerd.model.checkpoint import load_tensors, save_tensors
from styleerd.model.stored import GeneratorWeights
from styleerd.runtime.offline import TransferOptions, transfer_motion

STEM = Path("models/clip-recogniser-bandai2")
CROP, STEPS, BATCH = 120, 1500, 64  # frames a training crop (4 s), Adam steps, crops a step


class ClipRecogniser(nn.Module):
    def __init__(self, in_dim: int, n_styles: int, hidden: int = 96):
        super().__init__()
        self.gru = nn.GRU(in_dim, hidden, batch_first=True)
        self.head = nn.Linear(hidden, n_styles)
        self.register_buffer("mean", torch.zeros(in_dim))
        self.register_buffer("std", torch.ones(in_dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x [B, T, in_dim]`` (raw channels) -> style logits ``[B, n_styles]``."""
        h, _ = self.gru((x - self.mean) / self.std)
        return self.head(h.mean(1))


def clip_channels(features: np.ndarray, n_joints: int) -> np.ndarray:
    """Joint positions (root-relative, heading frame) and the root's velocity ``[T, 3J + 3]``."""
    layout = FeatureLayout(n_joints)
    return np.concatenate([features[:, layout.positions], features[:, layout.velocities][:, :3]], -1)


def train_recogniser(fs: FeatureSet, styles: list[str], seed: int = 0) -> ClipRecogniser:
    """Random ``CROP``-frame crops of every training take, each labelled with its take's style."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    J = fs.skeleton.n_joints
    takes = [(clip_channels(fs.features[fs.frames(c)], J), styles.index(str(fs.styles[c]))) for c in fs.clips("train")]
    takes = [(x, s) for x, s in takes if len(x) >= CROP]
    every = np.concatenate([x for x, _ in takes])
    model = ClipRecogniser(every.shape[1], len(styles))
    model.mean[:] = torch.tensor(every.mean(0))
    model.std[:] = torch.tensor(every.std(0) + 1e-6)
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
    for _ in tqdm(range(STEPS), desc="clip recogniser", leave=False):
        picks = rng.integers(0, len(takes), BATCH)
        crops = []
        for k in picks:
            x = takes[k][0]
            start = rng.integers(0, len(x) - CROP + 1)
            crops.append(x[start : start + CROP])
        logits = model(torch.tensor(np.stack(crops), dtype=torch.float32))
        loss = nn.functional.cross_entropy(logits, torch.tensor([takes[k][1] for k in picks]))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return model.eval()


def loaded_or_trained(fs: FeatureSet, styles: list[str], retrain: bool = False) -> ClipRecogniser:
    """The kept recogniser (``STEM``), or one trained now and kept."""
    if not retrain and STEM.with_suffix(".safetensors").exists():
        tensors, meta = load_tensors(STEM)
        model = ClipRecogniser(meta["in_dim"], len(meta["styles"]), meta["hidden"])
        model.load_state_dict(tensors)
        if meta["styles"] == styles:
            return model.eval()
    model = train_recogniser(fs, styles)
    meta = {
        "kind": "styleerd-clip-recogniser",
        "styles": styles,
        "in_dim": model.gru.input_size,
        "hidden": model.gru.hidden_size,
        "training": {"crop": CROP, "steps": STEPS, "batch": BATCH, "dataset": "bandai-namco-2", "split": "train"},
    }
    save_tensors(STEM, model.state_dict(), meta)
    return model


@torch.no_grad()
def read_style(recogniser: ClipRecogniser, features: np.ndarray, n_joints: int, styles: list[str]) -> str:
    x = torch.tensor(clip_channels(features, n_joints), dtype=torch.float32)[None]
    return styles[int(recogniser(x).argmax(-1))]


def evaluate_clip_styles(model: GeneratorWeights, data_dir: str | None = None, retrain: bool = False) -> dict:
    """The module docstring's figures, per (source, target) style pair and ``root_speed``."""
    fs = prepare("bandai-namco-2", data_dir, progress=False)
    styles = list(model.config.input_styles)
    neutral = model.config.neutral_style
    recogniser = loaded_or_trained(fs, styles, retrain)
    J = fs.skeleton.n_joints
    out: dict = {"ceiling": {}, "transfers": {}}
    reads: dict[str, list[str]] = {}
    jobs = []
    for clip in fs.clips("test"):
        sl = fs.frames(clip)
        style = str(fs.styles[clip])
        reads.setdefault(style, []).append(read_style(recogniser, fs.features[sl], J, styles))
        motion = fs.motion(clip)
        for target in [t for t in styles if t != neutral] if style == neutral else [neutral]:
            jobs.append((style, target, motion))
    out["ceiling"] = {s: {"takes": len(r), "read_as_own": sum(x == s for x in r)} for s, r in reads.items()}
    for root_speed in (False, True):
        key = "root speed" if root_speed else "input path"
        counts: dict[str, dict] = {}
        for source, target, motion in tqdm(jobs, desc=f"transfers ({key})", leave=False):
            options = TransferOptions({target: 1.0}, None, None, root_speed=root_speed)
            styled = transfer_motion(motion, model, fs.params.fps, options, where=f"{source} take")
            read = read_style(recogniser, motion_features(styled)[0], J, styles)
            c = counts.setdefault(f"{source} -> {target}", {"takes": 0, "read_as_target": 0, "still_source": 0})
            c["takes"] += 1
            c["read_as_target"] += read == target
            c["still_source"] += read == source
        out["transfers"][key] = counts
    return out


def markdown(report: dict) -> str:
    ceiling = " ".join(f"{s} {c['read_as_own']}/{c['takes']};" for s, c in report["ceiling"].items())
    lines = [
        f"The recogniser on the test takes themselves (read as their own style): {ceiling.rstrip(';')}.",
        "",
        (
            "| transfer (labels inferred) | takes | read as the target | still read as the source | with "
            "--root-speed: target | with --root-speed: still source |"
        ),
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    plain, fast = report["transfers"]["input path"], report["transfers"]["root speed"]
    for pair, c in plain.items():
        f = fast[pair]
        lines.append(
            f"| {pair} | {c['takes']} | {c['read_as_target']} | {c['still_source']} | {f['read_as_target']} | "
            f"{f['still_source']} |"
        )
    return "\n".join(lines)


def write(report: dict, out: Path) -> None:
    atomic_write_text(out.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    atomic_write_text(out.with_suffix(".md"), markdown(report) + "\n")
