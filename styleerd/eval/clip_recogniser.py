"""A second judge of style, of another design than the evaluation recognisers: those read 24-frame
windows of every feature channel with a convolution; this one reads whole clips, joint positions
and the root's velocity only (no rotation), with a recurrent network (a GRU whose states are
averaged over the clip). A transfer that fools the window recognisers with a few short-lived
cues, or one whose pace still says "elderly", is read here as it plays out.

``styleerd eval clip-styles``: trains it on Bandai-Namco-2's training takes (once; kept in
``models/clip-recogniser-bandai2``), reads the test takes themselves (its ceiling), then every
styled test take streamed back to neutral and every neutral one into each style, as ``transfer``
runs them (labels inferred online; plain, with ``--root-speed``, and with ``--no-cleanup``): per
pair, how many takes are read as the target and how many still as the source, and for the neutral
takes into each style, how many of each content are read as the target with and without the foot
cleanup (which holds the output's planted feet where the input's are: what it does to a style is
seen here)."""

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
PASSES = {  # how each transfer is run (labels inferred online)
    "input path": lambda target: TransferOptions({target: 1.0}),
    "root speed": lambda target: TransferOptions({target: 1.0}, root_speed=True),
    "no cleanup": lambda target: TransferOptions({target: 1.0}, cleanup=False),
}
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
            jobs.append((style, target, str(fs.contents[clip]), motion))
    out["ceiling"] = {s: {"takes": len(r), "read_as_own": sum(x == s for x in r)} for s, r in reads.items()}
    out["by_content"] = {}
    for key, options in PASSES.items():
        counts: dict[str, dict] = {}
        contents: dict[str, dict] = {}
        for source, target, content, motion in tqdm(jobs, desc=f"transfers ({key})", leave=False):
            styled = transfer_motion(motion, model, fs.params.fps, options(target), where=f"{source} take")
            read = read_style(recogniser, motion_features(styled)[0], J, styles)
            c = counts.setdefault(f"{source} -> {target}", {"takes": 0, "read_as_target": 0, "still_source": 0})
            c["takes"] += 1
            c["read_as_target"] += read == target
            c["still_source"] += read == source
            if source == neutral:
                k = contents.setdefault(target, {}).setdefault(content, {"takes": 0, "read_as_target": 0})
                k["takes"] += 1
                k["read_as_target"] += read == target
        out["transfers"][key] = counts
        out["by_content"][key] = contents
    return out


def markdown(report: dict) -> str:
    ceiling = " ".join(f"{s} {c['read_as_own']}/{c['takes']};" for s, c in report["ceiling"].items())
    lines = [
        f"The recogniser on the test takes themselves (read as their own style): {ceiling.rstrip(';')}.",
        "",
        (
            "| transfer (labels inferred) | takes | read as the target | still read as the source | with "
            "--root-speed: target | with --root-speed: still source | with --no-cleanup: target | with "
            "--no-cleanup: still source |"
        ),
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    passes = [report["transfers"][k] for k in PASSES]
    for pair, c in passes[0].items():
        cells = " | ".join(f"{p[pair]['read_as_target']} | {p[pair]['still_source']}" for p in passes)
        lines.append(f"| {pair} | {c['takes']} | {cells} |")
    with_feet, without = report["by_content"]["input path"], report["by_content"]["no cleanup"]
    targets = list(with_feet)
    lines += [
        "",
        (
            "The neutral takes into each style, per content: takes read as the target, with the foot cleanup / "
            "without it (of the takes in brackets)."
        ),
        "",
        "| content | " + " | ".join(targets) + " |",
        "| --- |" + " ---: |" * len(targets),
    ]
    for content in sorted(with_feet[targets[0]]):
        cells = [
            f"{with_feet[t][content]['read_as_target']} / {without[t][content]['read_as_target']}" for t in targets
        ]
        lines.append(f"| {content} ({with_feet[targets[0]][content]['takes']}) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write(report: dict, out: Path) -> None:
    atomic_write_text(out.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    atomic_write_text(out.with_suffix(".md"), markdown(report) + "\n")
