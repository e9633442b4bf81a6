"""Styles the shipped model never saw, added from Bandai-Namco-1 clips (``styleerd add-style``)
and judged on Bandai-Namco-2 test walks and runs (issue 17, item 2).

Per unseen style: six of its eleven Bandai-1 clips adapt the model (walk 001, run, walk-left,
walk-right, bow, bye); the other five (walk 002, dash, walk-back, byebye, guide) are kept
back. A style recogniser over Bandai-1's 15 styles is trained on the kept-back clips only,
so it never sees an adaptation clip; its accuracy on the adaptation clips is its ceiling on
real motion. Neutral Bandai-2 test windows of walk and run are transferred into the style
(labels given, as ``validate`` does) and reported as:
- SRA: the Bandai-1 recogniser reads the transfer as the target style;
- CRA: the shipped Bandai-2 content recogniser reads it as the input's content;
- FMD against the kept-back real locomotion windows of the style (walk 002, walk-back, dash;
  the shipped FMD extractor), next to the FMD of the style's adaptation locomotion clips
  against the same windows (real against real);
- the same for doing nothing (the neutral input itself).

Resumable: each style's result is written to the JSON as soon as it is measured and a
style already there is skipped; the added models are kept under runs/unseen-styles/.

    python benchmarks/unseen_styles.py --data ../shared/data
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from styleerd.atomic import atomic_write_text
from styleerd.data.cache import prepare
from styleerd.data.datasets import data_root, find_clips
from styleerd.data.features import FeatureLayout
from styleerd.data.windows import window_starts
from styleerd.eval.metrics import played_channels
from styleerd.model import checkpoint as ckpt
from styleerd.model.fmd import fmd_features
from styleerd.motion import quat
from styleerd.train.add_style import AddStyleConfig, add_style
from styleerd.train.batches import TrainingData, WindowSet, window_rotations, windows
from styleerd.train.classifiers import accuracy, train_classifier
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import setup
from styleerd.train.validation import frechet_distance

UNSEEN = ("happy", "sad", "angry", "proud", "not-confident", "childish", "musical", "giant", "chimpira")
KEPT_BACK = ("walk-back", "dash", "byebye", "guide")  # and the second walk take
TRAINED_IN_BOTH = {
    "active": "active",
    "elderly": "old",
    "exhausted": "tired",
    "feminine": "feminine",
    "masculine": "masculinity",
}
LOCOMOTION = ("walk", "walk-back", "dash", "run", "walk-left", "walk-right")  # FMD compares like with like


def kept_back(name: str, content: str) -> bool:
    return content in KEPT_BACK or (content == "walk" and name.endswith("_002"))


def bandai1(model, data_dir: str | None, window: int):
    """Bandai-1 normalised as the model's inputs, and per clip whether it is kept back."""
    fs = prepare("bandai-namco-1", data_dir)
    stats = model.stats()
    data = TrainingData(
        torch.from_numpy(stats.normalize(fs.features).astype(np.float32)),
        sorted(set(fs.styles.tolist())),
        sorted(set(fs.contents.tolist())),
        window,
        stats,
    )
    held = np.array([kept_back(n, c) for n, c in zip(fs.names, fs.contents)])
    return fs, data, held


def windows_of(fs, data: TrainingData, clips: np.ndarray, stride: int) -> WindowSet:
    starts = window_starts(fs.clip_start, clips, data.window, stride)
    clip = np.searchsorted(fs.clip_start, starts, side="right") - 1
    return WindowSet(
        starts,
        np.array([data.styles.index(s) for s in fs.styles[clip]]),
        np.array([data.contents.index(c) for c in fs.contents[clip]]),
        clip,
    )


def played(model, rot: torch.Tensor, trajectory: np.ndarray, fps: float) -> torch.Tensor:
    """Normalised motion channels of windows as they play: the output poses on the input's
    root path (the runtime's rule), velocities by differences of the played joint positions,
    not the network's velocity output."""
    out = []
    for q, traj in zip(rot.double().numpy(), trajectory):
        q = q.copy()
        q[:, 0] = quat.mul(traj[:, 3:7], q[:, 0])
        pos = np.broadcast_to(model.skeleton.offsets, (len(q), model.config.n_joints, 3)).copy()
        pos[:, 0] = traj[:, :3]
        out.append(played_channels(model, q, pos, fps))
    return torch.from_numpy(np.stack(out))


@torch.no_grad()
def judged(
    model,
    x,
    style_in,
    content,
    target,
    trajectory,
    recogniser,
    content_rec,
    fmd,
    reference,
    real_feats,
    style_index,
    content_labels,
):
    """SRA, CRA and FMD of ``model``'s transfers of windows ``x`` (target None: the input as is),
    read from the network's channels (as training validates) and from the motion as played."""
    if target is None:
        rot, ch = model.raw_rotations(x), x[..., : 10 * model.config.n_joints]
    else:
        rot, vel, _ = model(x, style_in, content, target)
        ch = model.motion_channels(rot, vel)
    channels = {"": ch, "_played": played(model, rot, trajectory, 30.0)}
    return scores(
        rot,
        channels,
        model.config.contents,
        recogniser,
        content_rec,
        fmd,
        reference,
        real_feats,
        style_index,
        content_labels,
    )


def scores(
    rot, channels: dict, contents, recogniser, content_rec, fmd, reference, real_feats, style_index, content_labels
) -> dict:
    out = {"fmd": round(frechet_distance(fmd_features(fmd, rot, reference), real_feats), 3)}
    for suffix, ch in channels.items():
        read = content_rec(ch).argmax(-1).numpy()
        out[f"sra{suffix}"] = round(float((recogniser(ch).argmax(-1).numpy() == style_index).mean()), 4)
        out[f"cra{suffix}"] = round(float((read == content_labels).mean()), 4)
        out[f"content_read_as{suffix}"] = {contents[k]: int(n) for k, n in zip(*np.unique(read, return_counts=True))}
    return out


@torch.no_grad()
def judged_from_start(
    model, base, style, x, content_labels, trajectory, recogniser, content_rec, fmd, reference, real_feats, style_index
) -> dict:
    """The same figures for a model trained with ``style`` from the start (its own labels and
    normalisation; read as played, in the judges' normalisation)."""
    c, n = model.config, len(x)
    x2 = torch.from_numpy(model.stats().normalize(base.stats().denormalize(x.double().numpy())).astype(np.float32))
    style_in = torch.zeros(n, len(c.input_styles))
    style_in[:, c.input_styles.index(c.neutral_style)] = 1.0
    content = torch.zeros(n, len(c.contents))
    content[torch.arange(n), torch.as_tensor([c.contents.index(base.config.contents[k]) for k in content_labels])] = 1.0
    target = torch.zeros(n, len(c.styles))
    target[:, c.styles.index(style)] = 1.0
    rot, _, _ = model(x2, style_in, content, target)
    return scores(
        rot,
        {"_played": played(base, rot, trajectory, 30.0)},
        base.config.contents,
        recogniser,
        content_rec,
        fmd,
        reference,
        real_feats,
        style_index,
        content_labels,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data")
    ap.add_argument("--styles", nargs="+", default=list(UNSEEN))
    ap.add_argument("--steps", type=int, default=AddStyleConfig.steps)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--critic-positions-only",
        action="store_true",
        help="the added styles' critic reads positions and velocities only (default: as the model's own critic)",
    )
    ap.add_argument("--runs", default="runs/unseen-styles")
    ap.add_argument("--out", default="docs/unseen-styles.json")
    ap.add_argument(
        "--from-start",
        default="styleerd/models/styleerd-bandai12",
        help="a model trained with the styles from the start (configs/bandai12-outside.yaml), judged beside",
    )
    ap.add_argument(
        "--filmstrip", default="docs/added-styles.png", help="picture of one walk in added styles ('' for none)"
    )
    ap.add_argument("--filmstrip-styles", nargs=3, default=["happy", "sad", "angry"])
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    base, meta = ckpt.load_generator()
    config = TrainConfig.from_dict(meta["training"]["config"])
    fs, data, held = bandai1(base, args.data, config.window)
    L = FeatureLayout(base.config.n_joints)
    out_path = Path(args.out)
    report = json.loads(out_path.read_text()) if out_path.is_file() else {}
    report.setdefault("styles", {})

    # the judge: a Bandai-1 style recogniser trained on the kept-back clips only
    held_ws = windows_of(fs, data, np.nonzero(held)[0], 4)
    adapt_ws = windows_of(fs, data, np.nonzero(~held)[0], config.window)
    visible = slice(L.positions.start, L.velocities.stop)
    torch.manual_seed(0)
    recogniser, _ = train_classifier(data, held_ws, held_ws, "style", False, visible, 12, 1e-3, 0)
    ceiling = {
        s: round(
            accuracy(
                recogniser,
                data,
                WindowSet(
                    *(
                        a[adapt_ws.style == data.styles.index(s)]
                        for a in (adapt_ws.starts, adapt_ws.style, adapt_ws.content, adapt_ws.clip)
                    )
                ),
                "style",
            ),
            4,
        )
        for s in args.styles
    }
    report["recogniser"] = {
        "trained_on": "the kept-back Bandai-1 clips of all 15 styles",
        "windows": len(held_ws.starts),
        "accuracy_on_adaptation_clips_overall": round(accuracy(recogniser, data, adapt_ws, "style"), 4),
    }
    _, content_rec, _ = ckpt.load_recognisers()
    fmd, _ = ckpt.load_fmd()
    reference = torch.as_tensor(base.stats().reference, dtype=torch.float32)

    def moving_feats(ws: WindowSet, k: int) -> np.ndarray:
        """FMD features of the locomotion windows of Bandai-1 style ``k`` in ``ws``."""
        rows = (ws.style == k) & np.isin(ws.content, [data.contents.index(c) for c in LOCOMOTION])
        return fmd_features(fmd, window_rotations(data, ws.starts[rows]), reference)

    # the content: neutral Bandai-2 test windows of walk and run
    s = setup(replace(config, stride=config.window), args.data, progress=False)
    test = windows(s.fs, s.data, "test", 4)
    pick = (test.style == s.data.styles.index(base.config.neutral_style)) & np.isin(
        test.content, [s.data.contents.index("walk"), s.data.contents.index("run")]
    )
    x = s.data.gather(test.starts[pick])
    style_in = s.data.onehot_style(test.style[pick])
    content = s.data.onehot_content(test.content[pick])
    content_labels = test.content[pick]
    trajectory = s.fs.trajectory[test.starts[pick][:, None] + np.arange(config.window)]
    content_ceiling = round(float((content_rec(x).argmax(-1).numpy() == content_labels).mean()), 4)
    report["content"] = {
        "windows": int(pick.sum()),
        "contents": ["walk", "run"],
        "content_recogniser_ceiling": content_ceiling,
    }
    # what fully trained styles reach with the same judge: the shipped model's styles that
    # Bandai-1 has too, under Bandai-1's names
    report["trained_styles"] = {}
    for ours, theirs in TRAINED_IN_BOTH.items():
        target = torch.zeros(len(x), len(base.config.styles))
        target[:, base.config.styles.index(ours)] = 1.0
        k = data.styles.index(theirs)
        real_feats = moving_feats(held_ws, k)
        report["trained_styles"][f"{ours} (Bandai-1: {theirs})"] = judged(
            base,
            x,
            style_in,
            content,
            target,
            trajectory,
            recogniser,
            content_rec,
            fmd,
            reference,
            real_feats,
            k,
            content_labels,
        )

    paths = {c.name: c.path for c in find_clips(data_root(args.data), "bandai-namco-1")}
    runs = Path(args.runs)
    runs.mkdir(parents=True, exist_ok=True)
    for style in args.styles:
        if style in report["styles"]:
            print(f"{style}: done before, skipped")
            continue
        clips = [paths[n] for n in fs.names[(fs.styles == style) & ~held]]
        if not (runs / f"{style}.safetensors").is_file():  # trained before, not yet judged: judge it
            add_style(
                None,
                style,
                clips,
                runs / style,
                config=AddStyleConfig(
                    steps=args.steps,
                    threads=args.threads,
                    critic_rotations=False if args.critic_positions_only else None,
                ),
                data_dir=args.data,
                progress=True,
            )
        G2, meta2 = ckpt.load_generator(runs / style)
        added = meta2["added_styles"][-1]
        target = torch.zeros(len(x), len(G2.config.styles))
        target[:, -1] = 1.0
        k = data.styles.index(style)
        real_feats, adapt_feats = moving_feats(held_ws, k), moving_feats(adapt_ws, k)
        judge = (recogniser, content_rec, fmd, reference, real_feats, k, content_labels)
        report["styles"][style] = {
            "adaptation_clips": [Path(c).stem for c in clips],
            "kept_back_clips": [str(n) for n in fs.names[(fs.styles == style) & held]],
            "minutes": added["minutes"],
            "steps": added["steps"],
            "started_like": added["started_like"],
            "critic_reads": added.get("critic_reads"),
            "added": judged(G2, x, style_in, content, target, trajectory, *judge),
            "none": judged(G2, x, style_in, content, None, trajectory, *judge),
            "recogniser_ceiling": ceiling[style],
            "fmd_real_adaptation_vs_kept_back": round(frechet_distance(adapt_feats, real_feats), 3),
        }
        print(style, json.dumps(report["styles"][style]), flush=True)
        atomic_write_text(out_path, json.dumps(report, indent=1) + "\n")
    if Path(args.from_start).with_suffix(".safetensors").is_file():
        model, _ = ckpt.load_generator(args.from_start)
        for style, row in report["styles"].items():
            k = data.styles.index(style)
            row["from_start"] = judged_from_start(
                model,
                base,
                style,
                x,
                content_labels,
                trajectory,
                recogniser,
                content_rec,
                fmd,
                reference,
                moving_feats(held_ws, k),
                k,
            )
            print(style, "from the start:", json.dumps(row["from_start"]), flush=True)
        report["from_start_model"] = {
            "model": args.from_start,
            "training_minutes": ckpt.load_generator(args.from_start)[1]["training"].get("wall_minutes"),
        }
        atomic_write_text(out_path, json.dumps(report, indent=1) + "\n")
    if args.filmstrip:
        picture(args.data, runs, args.filmstrip_styles, args.filmstrip)


def picture(data_dir: str | None, runs: Path, styles: list[str], path: str) -> None:
    """The README's neutral test walk and its transfers into added styles (each from its model)."""
    from styleerd.data.datasets import load_motion
    from styleerd.eval.plots import filmstrip
    from styleerd.eval.report import neutral_test_walk
    from styleerd.model.stored import load_generator_weights
    from styleerd.motion.resample import resample
    from styleerd.runtime.offline import stylise_motion

    clip = neutral_test_walk(data_dir, "normal")
    motion = resample(load_motion(clip), 30.0)
    rows = [(f"input: {clip.name} (normal, walk; Bandai-Namco-2 test split)", motion)]
    for style in styles:
        model = load_generator_weights(runs / style)
        rows.append(
            (
                f"-> {style} (added from 6 Bandai-Namco-1 clips; {model.meta['added_styles'][-1]['minutes']:.1f} min)",
                stylise_motion(model, motion, "normal", "walk", {style: 1.0}),
            )
        )
    filmstrip(rows, path, title="styles the shipped model never saw, added with styleerd add-style")
    print(f"wrote {path}")


if __name__ == "__main__":
    sys.exit(main())
