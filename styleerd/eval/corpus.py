"""Every take users might bring, whole, through ``transfer`` as they run it: does each one come back?

``styleerd eval corpus`` streams every take of cmu-sample (two real rigs, 60 and 120 fps, some
starting with a frame of rest pose elsewhere), Bandai-Namco-1 (every style and action) and
xia-sample, held out of training or not, uncut, and measures per take (``actions.action_kept``,
``actions.feet_figures``):

- identity, where the take's style is one of the model's (target = that style, given): the
  root-relative joint error (cm of a 170 cm body) and the correlation of the hands' and feet's
  root-relative velocities between input and output;
- into each style (the input's style given where known, else inferred online): that correlation,
  how far the feet go below the input's floor, and how fast planted feet slide against the input's.

Per corpus the worst take of each figure is named, so one odd file among hundreds shows. The held-out
action table (``eval actions``) says whether the style shows; this says whether anything breaks.
"""

from __future__ import annotations

from collections.abc import Callable

from tqdm import tqdm

from styleerd.data.datasets import BANDAI1_AS_BANDAI2, data_root, find_clips, load_motion, unpack
from styleerd.eval.actions import ActionClip, _body_scale, _map, action_kept, feet_figures
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import bvh
from styleerd.motion.motion import Motion
from styleerd.runtime.offline import TransferOptions, transfer_motion

CORPORA = ("cmu-sample", "bandai-namco-1", "xia-sample")
XIA_STYLES = {"neutral": "normal", "old": "elderly"}  # xia-sample's styles the model has
KEPT, SLID = 0.8, 1.0  # a take counted as losing its action under this correlation, as sliding over this (cm/s)


def every_take(model: GeneratorWeights, data_dir: str | None = None, corpora=CORPORA) -> list[ActionClip]:
    """Every take of ``corpora``, whole, with its style where it is one of the model's (else None)."""
    root, out = data_root(data_dir), []
    styles = set(model.config.styles)
    if "cmu-sample" in corpora:
        cmu = unpack(root / "cmu-sample.tar.xz") / "cmu-sample"
        for path in sorted(cmu.glob("*/*.bvh")):
            out.append(ActionClip(f"{path.parent.name}/{path.stem}", "", "cmu-sample", bvh.read(path), "normal"))
    for corpus in [c for c in corpora if c != "cmu-sample"]:
        for c in find_clips(root, corpus):
            style = XIA_STYLES.get(c.style) if corpus == "xia-sample" else BANDAI1_AS_BANDAI2.get(c.style, c.style)
            out.append(ActionClip(c.name, c.content, corpus, load_motion(c), style if style in styles else None))
    return out


def take_figures(clip: ActionClip, outputs: dict[str, Motion], model: GeneratorWeights) -> dict[str, dict]:
    """A take's outputs (by target) against the take: error, correlation, feet below the floor,
    planted feet's slide; the take's skeleton mapped once for all of them."""
    jm = _map(clip, model)
    scale = _body_scale(clip.motion.skeleton, jm)
    figures = {}
    for target, output in outputs.items():
        error, correlation = action_kept(clip.motion, output, jm, scale)
        feet = feet_figures(clip.motion, output, jm, scale)
        figures[target] = {
            "error_cm": round(error, 2),
            "correlation": round(correlation, 3),
            "below_floor_cm": feet["below_floor_cm"],
            "slide_cm_s": feet["slide_cm_s"],
        }
    return figures


def evaluate_corpus(
    model: GeneratorWeights,
    data_dir: str | None = None,
    corpora=CORPORA,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Per take, the identity's figures (where its style is known) and each style's (``take_figures``)."""
    styles = list(model.config.styles)
    takes: dict[str, dict] = {}
    for clip in tqdm(every_take(model, data_dir, corpora), desc="takes", leave=False):
        outputs = {
            s: transfer_motion(clip.motion, model, 30.0, TransferOptions({s: 1.0}, clip.input_style), where=clip.name)
            for s in styles
        }
        figures = take_figures(clip, outputs, model)
        row: dict = {"corpus": clip.source, "style": clip.input_style, "frames": clip.motion.n_frames}
        row["fps"] = round(clip.motion.fps, 3)
        if clip.input_style is not None:
            row["identity"] = figures[clip.input_style]
        row["styles"] = figures
        takes[f"{clip.source} {clip.name}"] = row
        if progress and len(takes) % 50 == 0:
            progress(f"{len(takes)} takes")
    return {"styles": styles, "takes": takes, "summary": summary(takes, styles)}


def _worst(rows: dict[str, dict], figure: Callable[[dict], float | None], highest: bool) -> dict | None:
    """The take whose figure is worst (highest or lowest), and the figure."""
    found = [(v, name) for name, row in rows.items() if (v := figure(row)) is not None]
    if not found:
        return None
    value, name = max(found) if highest else min(found)
    return {"take": name, "value": value}


def _slide_over_input(figures: dict) -> float | None:
    slide = figures["slide_cm_s"]
    return None if slide["output"] is None or slide["input"] is None else slide["output"] - slide["input"]


def _worst_figures(figures: Callable[[dict], dict], rows: dict[str, dict]) -> dict:
    """The worst take of each figure of ``figures(row)`` (a transfer's ``take_figures``) over ``rows``, and
    how many takes lose the action (a correlation under ``KEPT``) or slide (planted feet over ``SLID``
    cm/s faster than the input's)."""
    slides = [_slide_over_input(figures(r)) for r in rows.values()]
    return {
        "correlation": _worst(rows, lambda r: figures(r)["correlation"], False),
        "error_cm": _worst(rows, lambda r: figures(r)["error_cm"], True),
        "below_floor_cm": _worst(rows, lambda r: figures(r)["below_floor_cm"], True),
        "slide_over_input_cm_s": _worst(rows, lambda r: _slide_over_input(figures(r)), True),
        "correlation_under_kept": sum(figures(r)["correlation"] < KEPT for r in rows.values()),
        "sliding": sum(v is not None and v > SLID for v in slides),
    }


def summary(takes: dict[str, dict], styles: list[str]) -> dict:
    """Per corpus: takes, and the worst take of each figure, for the identity and each style."""
    out = {}
    for corpus in dict.fromkeys(row["corpus"] for row in takes.values()):
        rows = {k: r for k, r in takes.items() if r["corpus"] == corpus}
        known = {k: r for k, r in rows.items() if "identity" in r}
        out[corpus] = {
            "takes": len(rows),
            "with_a_known_style": len(known),
            "identity": _worst_figures(lambda r: r["identity"], known) if known else None,
            "styles": {s: _worst_figures(lambda r, s=s: r["styles"][s], rows) for s in styles},
        }
    return out


def markdown(report: dict) -> str:
    """One table per corpus: the worst take of each figure, identity and each style."""
    lines = [
        (
            "Every take, whole, as `styleerd transfer` runs it: per corpus the worst take of each figure (the take in "
            "brackets). Correlation: of the hands' and feet's root-relative velocities, input against output; error: "
            "root-relative joint error, cm of a 170 cm body; below floor: the output's feet under the input's lowest, "
            "cm; slide: planted feet's median speed over the input's own, cm/s. Counted: takes whose correlation is "
            f"under {KEPT}, and whose planted feet slide more than {SLID} cm/s faster than the input's."
        ),
    ]
    cell = lambda w, f: "-" if w is None else f"{w['value']:{f}} ({w['take']})"
    for corpus, s in report["summary"].items():
        lines += [
            "",
            f"### {corpus}: {s['takes']} takes, {s['with_a_known_style']} in a style of the model's",
            "",
            (
                f"| target | worst correlation | under {KEPT} | worst error (cm) | worst below floor (cm) | "
                f"worst slide (cm/s) | sliding over {SLID} cm/s |"
            ),
            "|---|---|---:|---|---|---|---:|",
        ]
        rows = ([("identity", s["identity"])] if s["identity"] else []) + list(s["styles"].items())
        for name, w in rows:
            lines.append(
                f"| {name} | {cell(w['correlation'], '.3f')} | {w['correlation_under_kept']} | "
                f"{cell(w['error_cm'], '.1f')} | {cell(w['below_floor_cm'], '.2f')} | "
                f"{cell(w['slide_over_input_cm_s'], '.1f')} | {w['sliding']} |"
            )
    return "\n".join(lines) + "\n"
