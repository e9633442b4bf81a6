"""What the online labeller tells the encoder about other performers' clips.

When ``--input-style`` is not given, the style the encoder is told is the labeller's posterior
after ``toward_neutral`` (a style it is unsure of leans to neutral). A wrong style told with
confidence is subtracted from the input by the network, so the measure here is, per clip of a
performer, skeleton and often a style the labeller never saw:

- ``read``: the style told at the last frame, and the content;
- ``confident_wrong``: the share of frames whose style is told with weight >= 0.9 on a style
  that is neither the clip's own (where the model has it) nor neutral;
- ``right_or_neutral``: the share of frames whose top style is the clip's own or neutral
  (for styles the model does not have: neutral);
- ``own_confident``: for a clip of one of the model's styles but its neutral one, the share of
  frames told that style with confidence (what reading other performers' styles still gives,
  where an unsure or unfamiliar reading leans to neutral).

Clips: xia-sample (another performer; its ``old`` is the model's ``elderly``, its angry,
childlike, depressed, proud, sexy and strutting are no style of the model's), cmu-sample (all
neutral, two rig families) and Bandai-Namco-1 (other performers; its old, tired and masculinity
are the model's elderly, exhausted and masculine, and nine styles the model does not have).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from styleerd.atomic import atomic_write_text
from styleerd.data.datasets import BANDAI1_AS_BANDAI2, bandai1_kept_back, data_root, find_clips, load_motion, unpack
from styleerd.data.outside import CMU_HELD_OUT
from styleerd.eval.actions import trimmed
from styleerd.model.stored import SURE, GeneratorWeights, LabellerWeights
from styleerd.motion import bvh
from styleerd.motion.motion import Motion
from styleerd.motion.resample import resample
from styleerd.motion.retarget import to_target
from styleerd.runtime.offline import map_skeleton
from styleerd.runtime.stylizer import StreamStylizer

# other datasets' names for the model's styles
SAME_STYLE = {**BANDAI1_AS_BANDAI2, "neutral": "normal"}


@dataclass(frozen=True)
class LabelledClip:
    name: str
    group: str
    style: str  # the clip's own style, in the model's names where the model has it
    motion: Motion


def outside_clips(data_dir: str | None = None, per_bandai1_style: int = 2) -> list[LabelledClip]:
    """Clips no labeller trains on (``train.labeller`` keeps them out), cut to ``SECONDS``: every
    xia-sample clip, cmu-sample's held-out subjects (``data.outside.CMU_HELD_OUT``) and the first
    ``per_bandai1_style`` kept-back clips (``bandai1_kept_back``) of each Bandai-Namco-1 style."""
    root = data_root(data_dir)
    out = []
    for c in find_clips(root, "xia-sample"):
        out.append(LabelledClip(c.name, "xia-sample", SAME_STYLE.get(c.style, c.style), trimmed(load_motion(c))))
    cmu = unpack(root / "cmu-sample.tar.xz") / "cmu-sample"
    for folder in ("iclone", "asf-names"):
        for path in sorted(p for p in (cmu / folder).glob("*.bvh") if p.stem.startswith(CMU_HELD_OUT[folder])):
            group = f"cmu-sample {folder}"
            out.append(LabelledClip(f"cmu {path.stem}", group, "normal", trimmed(bvh.read(path))))
    taken: dict[str, int] = {}
    for c in sorted(find_clips(root, "bandai-namco-1"), key=lambda c: c.name):
        if bandai1_kept_back(c.name, c.content) and taken.get(c.style, 0) < per_bandai1_style:
            taken[c.style] = taken.get(c.style, 0) + 1
            style = SAME_STYLE.get(c.style, c.style)
            out.append(LabelledClip(c.name, "bandai-namco-1 kept back", style, trimmed(load_motion(c))))
    return out


def told_styles(
    model: GeneratorWeights, clip: LabelledClip, labeller: LabellerWeights | None = None
) -> tuple[np.ndarray, list[str]]:
    """Per frame at 30 fps, the style weights the encoder is told ``[T, styles]`` (labels
    inferred online by ``labeller``, default the model's), and the content read at each frame."""
    motion = resample(clip.motion, 30.0)
    jm = map_skeleton(motion.skeleton, model, None, clip.name, motion.rotations[0])
    on_model = to_target(motion, jm)
    target = {model.config.neutral_style: 1.0}
    stylizer = StreamStylizer(model, None, None, target, fps=30.0, pose="network", labeller=labeller)
    styles, contents = [], []
    for t in range(on_model.n_frames):
        stylizer.step(on_model.rotations[t][None], on_model.positions[t][None])
        styles.append(stylizer.labels[0][0].copy())
        contents.append(model.config.contents[int(stylizer.labels[1][0].argmax())])
    return np.array(styles), contents


def clip_figures(model: GeneratorWeights, clip: LabelledClip, labeller: LabellerWeights | None = None) -> dict:
    """``read``, ``confident_wrong``, ``right_or_neutral`` and ``own_confident`` of one clip
    (module docstring)."""
    c = model.config
    told, contents = told_styles(model, clip, labeller)
    own = c.input_styles.index(clip.style) if clip.style in c.input_styles else None
    neutral = c.input_styles.index(c.neutral_style)
    top = told.argmax(-1)
    fine = (top == neutral) | (top == own)
    sure = told.max(-1) >= SURE
    sure_wrong = sure & ~fine
    return {
        "group": clip.group,
        "style": clip.style if own is not None else f"{clip.style} (not the model's)",
        "read": [c.input_styles[top[-1]], contents[-1]],
        "confident_wrong": round(float(sure_wrong.mean()), 3),
        "right_or_neutral": round(float(fine.mean()), 3),
        "own_confident": None if own in (None, neutral) else round(float((sure & (top == own)).mean()), 3),
    }


def evaluate_labels(
    model: GeneratorWeights, data_dir: str | None = None, labeller: LabellerWeights | None = None
) -> dict:
    """``clip_figures`` of every ``outside_clips`` clip, and per group the means and the clips
    read as another style at their last frame."""
    clips = tqdm(outside_clips(data_dir), desc="labels", leave=False)
    rows = {clip.name: clip_figures(model, clip, labeller) for clip in clips}
    groups: dict = {}
    for name, r in rows.items():
        g = groups.setdefault(
            r["group"],
            {"clips": 0, "confident_wrong": [], "right_or_neutral": [], "own_confident": [], "wrong_reads": []},
        )
        g["clips"] += 1
        g["confident_wrong"].append(r["confident_wrong"])
        g["right_or_neutral"].append(r["right_or_neutral"])
        if r["own_confident"] is not None:
            g["own_confident"].append(r["own_confident"])
        known = not r["style"].endswith("(not the model's)")
        if r["read"][0] not in (model.config.neutral_style, r["style"] if known else None):
            g["wrong_reads"].append(name)
    for g in groups.values():
        for key in ("confident_wrong", "right_or_neutral", "own_confident"):
            g[key] = round(float(np.mean(g[key])), 3) if g[key] else None
    return {"clips": rows, "groups": groups}


def markdown(report: dict) -> str:
    """Per group, then per clip: the share of frames told a confident wrong style, the share read
    as the clip's own style or neutral, the share of a styled clip's frames told its own style
    with confidence, and the read at the last frame."""
    lines = [
        (
            "| group | clips | frames told a confident wrong style | frames read as its own style or neutral "
            "| frames of the model's styles (not neutral) told their own with confidence "
            "| clips read as another style at the end |"
        ),
        "|---|---|---|---|---|---|",
    ]
    for name, g in report["groups"].items():
        own = "-" if g["own_confident"] is None else f"{100 * g['own_confident']:.1f} %"
        lines.append(
            f"| {name} | {g['clips']} | {100 * g['confident_wrong']:.1f} % | {100 * g['right_or_neutral']:.1f} % "
            f"| {own} | {len(g['wrong_reads'])} |"
        )
    lines += [
        "",
        "| clip | style | read at the end (style / content) | confident wrong | own or neutral |",
        "|---|---|---|---|---|",
    ]
    for name, r in report["clips"].items():
        lines.append(
            f"| {name} | {r['style']} | {' / '.join(r['read'])} | {100 * r['confident_wrong']:.0f} % "
            f"| {100 * r['right_or_neutral']:.0f} % |"
        )
    return "\n".join(lines) + "\n"


def write(report: dict, out: Path) -> None:
    """``out`` (Markdown) and the JSON beside it."""
    atomic_write_text(out.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    atomic_write_text(out, markdown(report))
