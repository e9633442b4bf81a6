"""Any action, any performer: does the output keep the input's action on motion the model never
trained on, does the style still show there, and do the feet stay on the floor?

``styleerd eval actions`` streams held-out clips of other performers, skeletons and actions
(``HELD_OUT``: CMU subjects 2 and 126 from cmu-sample, Bandai-Namco-1's neutral actions that
Bandai-Namco-2 lacks, the xia-sample jump and punch) through ``transfer`` as users run it, on
their own skeletons, and measures per clip:

- identity (target = the input's own style): the root-relative joint error (cm, scaled to a
  170 cm body) and the correlation of the hands' and feet's root-relative velocities between
  input and output (1 = the same action);
- into each style: that correlation, and the style's change (output minus the identity output,
  root-relative, in the body's heading frame, per joint of the model's skeleton, averaged over the
  clip) against the same change on Bandai-Namco-2 test walks: cosine of the two and the ratio of
  their sizes.

Whether a style's change should point as on walks is measured on a real performer
(``performer_changes``): Bandai-Namco-1's kept-back takes of other actions in each style, the
performer's own change against their change on the walk, and the model's against the performer's.

The feet (``feet_figures``): on walks and runs of other performers and a generated walk in place
(the root fixed, as game libraries ship them), how far the output's feet go below the input's
floor, how fast planted feet slide (cm/s at the clip's own rate, where the input's foot is
planted), and the stride (the feet's largest horizontal gap, 95th percentile), judged against the input's
and against the style's own change of it on Bandai-Namco-2 walks (``stride_against_style``).

These clips are kept out of every training run (``held_out``): the figures are on motion the
model has never seen.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from styleerd.data.augment import in_place
from styleerd.data.datasets import (
    BANDAI1_AS_BANDAI2,
    BANDAI1_KEPT_BACK,
    Clip,
    bandai1_kept_back,
    data_root,
    find_clips,
    load_motion,
    unpack,
)
from styleerd.data.outside import CMU_HELD_OUT, CMU_REPORTED_SWIMS, XIA_ACTIONS, held_out
from styleerd.data.windows import split_takes
from styleerd.errors import StyleERDError
from styleerd.model.config import FAMILIAR, UNFAMILIAR
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import bvh, quat
from styleerd.motion.kinematics import body_axes, facing_directions, forward_positions, heading_rotations
from styleerd.motion.motion import Motion
from styleerd.motion.procedural import walk
from styleerd.motion.resample import resample
from styleerd.motion.retarget import JointMap, to_target
from styleerd.runtime.cleanup import LEG_DOWN, SQUAT_DOWN, UPRIGHT
from styleerd.runtime.offline import TransferOptions, map_skeleton, transfer_motion

BODY_CM = 170.0
SECONDS = 12.0  # of each clip, from its start: long enough for several steps or moves
# CMU subject 2's takes (the database's own descriptions)
CMU_ACTIONS = {
    "002_01": "walk",
    "002_02": "walk",
    "002_03": "run",
    "002_04": "jump, balance",
    "002_05": "punch, strike",
    "002_06": "punch, strike",
    "002_07": "swordplay",
    "002_08": "swordplay",
    "002_09": "wash self",
    "002_10": "wash self",
}
HANDS_FEET = ("Hand_L", "Hand_R", "Foot_L", "Foot_R")
FRAMES = ("heading", "body")  # the frames a style's change is compared in (``style_change``)


@dataclass(frozen=True)
class ActionClip:
    name: str
    action: str
    source: str  # dataset and rig
    motion: Motion
    input_style: str | None  # None: inferred


def trimmed(m: Motion) -> Motion:
    """The first ``SECONDS`` of ``m``."""
    return m[: int(round(SECONDS * m.fps))]


def held_out_clips(data_dir: str | None = None) -> list[ActionClip]:
    """Every held-out action clip, cut to ``SECONDS``."""
    root = data_root(data_dir)
    out = []
    cmu = unpack(root / "cmu-sample.tar.xz") / "cmu-sample"
    for folder, prefixes in CMU_HELD_OUT.items():
        for path in sorted(
            p
            for p in (cmu / folder).glob("*.bvh")
            if p.stem.startswith(prefixes) and (folder != "asf-names" or p.stem in CMU_REPORTED_SWIMS)
        ):
            action = CMU_ACTIONS.get(path.stem, "swim" if folder == "asf-names" else "other")
            out.append(
                ActionClip(
                    f"cmu {path.stem}",
                    action,
                    f"cmu-sample/{folder}",
                    trimmed(bvh.read(path)),
                    "normal",
                )
            )
    for c in find_clips(root, "bandai-namco-1"):
        if held_out(c.name, c.dataset, c.content, c.style):
            out.append(
                ActionClip(
                    c.name.removeprefix("dataset-1_"), c.content, "bandai-namco-1", trimmed(load_motion(c)), "normal"
                )
            )
    for c in find_clips(root, "xia-sample"):
        cid = c.name.rsplit("_", 2)[1]
        if cid in XIA_ACTIONS:
            out.append(
                ActionClip(
                    f"xia {c.name}",
                    XIA_ACTIONS[cid],
                    "xia-sample",
                    trimmed(load_motion(c)),
                    "normal" if c.name.startswith("neutral") else None,
                )
            )
    return out


def bandai2_test_walks(data_dir: str | None = None, n: int = 8) -> list[ActionClip]:
    """The first ``n`` neutral walks (straight and turning) of Bandai-Namco-2's test split: the reference."""
    clips = find_clips(data_root(data_dir), "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    walks: list[Clip] = [
        c for c in clips if split[c.name] == "test" and c.style == "normal" and c.content.startswith("walk")
    ][:n]
    return [
        ActionClip(
            c.name.removeprefix("dataset-2_"), c.content, "bandai-namco-2 test", trimmed(load_motion(c)), "normal"
        )
        for c in walks
    ]


def _map(clip: ActionClip, model: GeneratorWeights) -> JointMap:
    return map_skeleton(clip.motion.skeleton, model, None, clip.name, clip.motion.rotations[0])


def _body_scale(skeleton, jm: JointMap) -> float:
    """cm of a 170 cm body per unit of this skeleton: the foot-to-head bone length (ankle to hip to
    hips to head, which leaves out the foot's height and the crown) is 0.9 of the body's height."""
    source = {jm.target.names[t]: s for t, s in jm.pairs}
    height = sum(skeleton.chain_length(source["Hips"], source[end]) for end in ("Foot_L", "Head"))
    return 0.9 * BODY_CM / height


def _root_relative(m: Motion, jm: JointMap) -> tuple[np.ndarray, list[str]]:
    """Global positions of the mapped joints minus the root's ``[T, K, 3]``, and their model names."""
    g = forward_positions(m.rotations, m.positions, m.skeleton.parents)
    names = [jm.target.names[t] for t, _ in jm.pairs]
    source = [s for _, s in jm.pairs]
    root = source[names.index("Hips")]
    return g[:, source] - g[:, root : root + 1], names


def _frames(m: Motion, jm: JointMap) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of ``m``, world -> the body's heading (``[T, 4]``, from hips and shoulders) and
    world -> the body's own frame (``[T, 3, 3]``, ``kinematics.body_axes``: up from the hips to the
    head). Upright the two agree; lying (a swimmer), the second turns with the body where the
    heading cannot."""
    g = forward_positions(m.rotations, m.positions, m.skeleton.parents)
    at = {jm.target.names[t]: s for t, s in jm.pairs}
    left, right = (at["UpperLeg_L"], at["UpperArm_L"]), (at["UpperLeg_R"], at["UpperArm_R"])
    heading = quat.inv(heading_rotations(facing_directions(g, left, right)))
    return heading, body_axes(g, at["Hips"], at["Head"], left, right)


def action_kept(given: Motion, output: Motion, jm: JointMap, scale: float) -> tuple[float, float]:
    """(root-relative joint error in cm of a 170 cm body, correlation of the hands' and feet's
    root-relative velocities) between an input and its output."""
    a, names = _root_relative(given, jm)
    b, _ = _root_relative(output, jm)
    error = float(np.linalg.norm(a - b, axis=-1).mean() * scale)
    ends = [names.index(n) for n in HANDS_FEET]
    va, vb = np.diff(a[:, ends], axis=0).ravel(), np.diff(b[:, ends], axis=0).ravel()
    corr = float(np.corrcoef(va, vb)[0, 1]) if va.std() > 0 and vb.std() > 0 else 0.0
    return error, corr


# ``familiar_range_for``: at most this much more error (cm) and less correlation than the input's own pose
AS_THE_INPUT = (0.5, 0.02)
FAMILIAR_STEP = 1.0  # degrees: how far ``familiar_range_for`` lowers a model's range a try


def familiar_range_for(model: GeneratorWeights, data_dir: str | None = None) -> dict:
    """A model's familiar range (``model.stored.familiar_range``): from ``model.config``'s FAMILIAR and
    UNFAMILIAR, both lowered by ``FAMILIAR_STEP`` until the identity transfer keeps each of
    Bandai-Namco-1's kept-back normal takes (``bandai1_kept_back``: actions and a take no training run
    sees, and none of the clips ``evaluate_actions`` reports) as well as the input's own pose does
    (every frame unfamiliar), within ``AS_THE_INPUT``. A model that rebuilds those actions' poses
    closely enough to pass as familiar, yet loses their hands' and feet' motion, gets a lower range; one
    that keeps them keeps the default. Returns the range, the input's own figures and, per range tried,
    each take's (error, correlation)."""
    neutral = model.config.neutral_style
    clips = [
        c
        for c in find_clips(data_root(data_dir), "bandai-namco-1")
        if c.style == neutral and bandai1_kept_back(c.name, c.content)
    ]
    if not clips:
        raise StyleERDError(f"Bandai-Namco-1 has no kept-back takes of the model's neutral style {neutral!r}")
    takes = [ActionClip(c.name, c.content, "bandai-namco-1", trimmed(load_motion(c)), c.style) for c in clips]
    maps = {clip.name: _map(clip, model) for clip in takes}  # the same for every range tried
    scales = {clip.name: _body_scale(clip.motion.skeleton, maps[clip.name]) for clip in takes}

    def identity(lo: float, hi: float) -> dict[str, tuple[float, float]]:
        ranged = dataclasses.replace(model, familiar=(lo, hi))
        kept = {}
        for clip in tqdm(takes, desc=f"familiar {lo:g}-{hi:g} deg", leave=False):
            output = _transfers(clip, ranged, [], "input")[0]
            kept[clip.name] = action_kept(clip.motion, output, maps[clip.name], scales[clip.name])
        return kept

    given = identity(-2.0, -1.0)  # every frame unfamiliar: the input's own pose
    lo, hi = FAMILIAR, UNFAMILIAR
    tried = []
    while True:
        kept = identity(lo, hi)
        tried.append({"degrees": [lo, hi], "takes": {k: [round(e, 3), round(c, 3)] for k, (e, c) in kept.items()}})
        if lo <= FAMILIAR_STEP or all(
            e <= given[k][0] + AS_THE_INPUT[0] and c >= given[k][1] - AS_THE_INPUT[1] for k, (e, c) in kept.items()
        ):
            break
        lo, hi = lo - FAMILIAR_STEP, hi - FAMILIAR_STEP
    return {
        "degrees": [lo, hi],
        "measured_on": f"the identity transfer of Bandai-Namco-1's {len(takes)} kept-back normal takes "
        "(styleerd familiar)",
        "input": {k: [round(e, 3), round(c, 3)] for k, (e, c) in given.items()},
        "tried": tried,
    }


def _model_points(jm: JointMap) -> JointMap:
    """The model's skeleton mapped onto itself, joint for joint, over the joints ``jm`` maps."""
    model = jm.target
    return JointMap(model, model, tuple((t, t) for t, _ in jm.pairs), jm.target_tpose, jm.target_tpose, 1.0)


def style_change(given: Motion, styled: Motion, identity: Motion, jm: JointMap) -> dict[str, dict[str, np.ndarray]]:
    """Per frame of reference (``heading``: the body's heading, ``body``: the body's own frame,
    both of the input) and model joint, the clip's mean of (styled - identity output)
    root-relative position (cm of a 170 cm body), on the model's skeleton (the motions retargeted
    onto it): a joint is the same point of the body on every rig, where on a CMU/ASF rig the neck
    and the shoulders start at the chest's joint."""
    own = _model_points(jm)
    scale = _body_scale(jm.target, own)
    given, styled, identity = (to_target(m, jm) for m in (given, styled, identity))
    a, names = _root_relative(styled, own)
    b, _ = _root_relative(identity, own)
    to_heading, to_body = _frames(given, own)
    heading = quat.mul_vec(to_heading[:, None], a - b).mean(0) * scale
    body = np.einsum("tij,tkj->tki", to_body, a - b).mean(0) * scale
    return {"heading": dict(zip(names, heading)), "body": dict(zip(names, body))}


def _cosine_size(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(cosine, size ratio) of vector ``a`` against ``b``."""
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    return (float(a @ b / (na * nb)) if na > 0 and nb > 0 else 0.0), float(na / nb) if nb > 0 else 0.0


def _compare(change: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> tuple[float, float]:
    """(cosine, size ratio) of a clip's style change against the walks', over their common joints."""
    common = [k for k in reference if k in change and k != "Hips"]
    return _cosine_size(np.concatenate([change[k] for k in common]), np.concatenate([reference[k] for k in common]))


def _transfers(
    clip: ActionClip, model: GeneratorWeights, targets: list[str], pose: str
) -> tuple[Motion, dict[str, Motion]]:
    """The identity output and each target's output of a clip (``transfer`` as users run it)."""
    m, identity_target = clip.motion, clip.input_style or model.config.neutral_style

    def run(target: str, input_style: str | None) -> Motion:
        return transfer_motion(
            m,
            model,
            30.0,
            TransferOptions({target: 1.0}, input_style, None, pose=pose),
            where=clip.name,
        )

    identity = run(identity_target, clip.input_style or identity_target)
    return identity, {t: run(t, clip.input_style) for t in targets}


def evaluate_actions(
    model: GeneratorWeights,
    data_dir: str | None = None,
    poses: tuple[str, ...] = ("input", "network"),
    walks: int = 8,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """The action table: per held-out clip and pose path, identity error and correlation, and per
    style its correlation and change against the walks' (cosine, size ratio); the same figures on
    Bandai-Namco-2 test walks beside them."""
    neutral = model.config.neutral_style
    styles = [s for s in model.config.styles if s != neutral]
    out: dict = {"body_cm": BODY_CM, "seconds": SECONDS, "styles": styles, "poses": {}}
    reference_clips, action_clips = bandai2_test_walks(data_dir, walks), held_out_clips(data_dir)
    for pose in poses:
        rows: dict[str, dict] = {}
        changes: dict[str, list[dict]] = {s: [] for s in styles}
        for group, clips in (("walks", reference_clips), ("actions", action_clips)):
            for clip in tqdm(clips, desc=f"{group}, pose {pose}", leave=False):
                jm = _map(clip, model)
                scale = _body_scale(clip.motion.skeleton, jm)
                identity, styled = _transfers(clip, model, styles, pose)
                err, corr = action_kept(clip.motion, identity, jm, scale)
                row = {
                    "group": group,
                    "action": clip.action,
                    "source": clip.source,
                    "frames": clip.motion.n_frames,
                    "fps": round(clip.motion.fps, 3),
                    "identity": {"error_cm": round(err, 2), "correlation": round(corr, 3)},
                    "styles": {},
                }
                for s, m in styled.items():
                    change = style_change(clip.motion, m, identity, jm)
                    if group == "walks":
                        changes[s].append(change)
                    feet = feet_figures(clip.motion, m, jm, scale)
                    row["styles"][s] = {
                        "correlation": round(action_kept(clip.motion, m, jm, scale)[1], 3),
                        "change": change,
                        "below_floor_cm": feet["below_floor_cm"],
                        "slide_cm_s": feet["slide_cm_s"],
                    }
                rows[clip.name] = row
        walk_change = {
            s: {f: {k: np.mean([c[f][k] for c in changes[s]], 0) for k in changes[s][0][f]} for f in FRAMES}
            for s in styles
        }
        for row in rows.values():
            for s, r in row["styles"].items():
                change = r.pop("change")
                cos, ratio = _compare(change["heading"], walk_change[s]["heading"])
                cos_body, ratio_body = _compare(change["body"], walk_change[s]["body"])
                r.update(
                    cosine=round(cos, 3),
                    size_ratio=round(ratio, 3),
                    cosine_body=round(cos_body, 3),
                    size_ratio_body=round(ratio_body, 3),
                )
        out["poses"][pose] = {"clips": rows, "summary": _summary(rows, styles)}
        if progress:
            progress(f"pose {pose}: {json_summary(out['poses'][pose]['summary'])}")
    return out


def _summary(rows: dict[str, dict], styles: list[str]) -> dict:
    """Walks against held-out actions: mean and worst of each figure."""
    out = {}
    for group in ("walks", "actions"):
        rs = [r for r in rows.values() if r["group"] == group]
        ids = np.array([(r["identity"]["error_cm"], r["identity"]["correlation"]) for r in rs])
        g = {
            "clips": len(rs),
            "identity_error_cm": {"mean": round(float(ids[:, 0].mean()), 2), "worst": round(float(ids[:, 0].max()), 2)},
            "identity_correlation": {
                "mean": round(float(ids[:, 1].mean()), 3),
                "worst": round(float(ids[:, 1].min()), 3),
            },
            "styles": {},
        }
        for s in styles:
            keys = ("correlation", "cosine", "size_ratio", "cosine_body")
            v = np.array([[r["styles"][s][k] for k in keys] for r in rs])
            g["styles"][s] = {
                "correlation": round(float(v[:, 0].mean()), 3),
                "correlation_worst": round(float(v[:, 0].min()), 3),
                "cosine": round(float(v[:, 1].mean()), 3),
                "cosine_worst": round(float(v[:, 1].min()), 3),
                "size_ratio": round(float(v[:, 2].mean()), 3),
                "size_ratio_worst": round(float(v[:, 2].min()), 3),
                "cosine_body": round(float(v[:, 3].mean()), 3),
                "cosine_body_worst": round(float(v[:, 3].min()), 3),
            }
        out[group] = g
    return out


def actions_feet(clips: dict[str, dict]) -> str:
    """One line on the feet over every held-out action clip and style of one pose path: the furthest
    below the input's floor and the fastest planted foot's slide, each with its clip and style (rows
    measured before the feet were: none)."""
    cells = [
        (name, s, r["below_floor_cm"], r["slide_cm_s"])
        for name, row in clips.items()
        if row["group"] == "actions"
        for s, r in row["styles"].items()
        if "below_floor_cm" in r
    ]
    if not cells:
        return ""
    below = max(cells, key=lambda c: c[2])
    slid = [c for c in cells if c[3]["output"] is not None]
    slide = max(slid, key=lambda c: c[3]["output"] - c[3]["input"]) if slid else None
    where = f"at most {below[2]:.2f} cm ({below[0]}, {below[1]})" if below[2] > 0 else "nothing"
    text = f"Feet on the {len({c[0] for c in cells})} held-out actions, every style: {where} below the input's floor"
    if slide:
        text += (
            f"; planted feet slide at most {slide[3]['output'] - slide[3]['input']:.1f} cm/s more than the input's own "
            f"({slide[0]}, {slide[1]}: {slide[3]['output']:.1f} against {slide[3]['input']:.1f})"
        )
    return text + "."


def json_summary(summary: dict) -> str:
    a, w = summary["actions"], summary["walks"]
    return (
        f"held-out actions: identity {a['identity_error_cm']['mean']} cm, correlation "
        f"{a['identity_correlation']['mean']} "
        f"(worst {a['identity_correlation']['worst']}); walks: {w['identity_error_cm']['mean']} cm, "
        f"{w['identity_correlation']['mean']}"
    )


# ---------------------------------------------------------------- the performer's own change


def _mean_pose(m: Motion, jm: JointMap) -> np.ndarray:
    """The clip's mean root-relative position of each mapped joint but the root, in the body's heading
    frame (cm of a 170 cm body), on the model's skeleton as ``style_change`` measures, as one vector
    ``[3 K]``."""
    own = _model_points(jm)
    m = to_target(m, jm)
    a, names = _root_relative(m, own)
    to_heading, _ = _frames(m, own)
    mean = quat.mul_vec(to_heading[:, None], a).mean(0) * _body_scale(jm.target, own)
    return np.concatenate([mean[k] for k, n in enumerate(names) if n != "Hips"])


def performer_changes(model: GeneratorWeights, data_dir: str | None = None) -> dict:
    """A style's change as a real performer makes it: Bandai-Namco-1's performer, on the takes every
    training run keeps back (``bandai1_kept_back``: walk-back, dash, byebye, guide and the second walk,
    in every style). Per action and each model style Bandai-1 also has (its ``old``, ``tired`` and
    ``masculinity`` are the model's elderly, exhausted and masculine), cosine and size ratio of:

    - ``performer``: the performer's change (the styled take's mean pose minus the normal take's,
      ``_mean_pose``) against the same performer's change on the walk (both takes' mean); on the walk's
      row, the first take's change against the second's: how far two takes of one walk agree;
    - ``model``: the model's change on the normal take (styled minus identity output, ``style_change``)
      against its change on the normal walk;
    - ``model_vs_performer``: the model's change against the performer's on the same action."""
    clips = find_clips(data_root(data_dir), "bandai-namco-1")
    names = {BANDAI1_AS_BANDAI2.get(c.style, c.style): c.style for c in clips}
    neutral = model.config.neutral_style
    styles = [s for s in model.config.styles if s != neutral and s in names]
    wanted = {names[s] for s in [neutral, *styles]}
    takes = {
        (c.content, c.style, c.name[-3:]): c
        for c in clips
        if c.content in ("walk", *BANDAI1_KEPT_BACK) and c.style in wanted
    }
    motions = {
        key: trimmed(load_motion(c)) for key, c in tqdm(sorted(takes.items()), desc="performer's takes", leave=False)
    }
    posed: dict[tuple, np.ndarray] = {}
    for key, m in motions.items():
        jm = map_skeleton(m.skeleton, model, None, takes[key].name, m.rotations[0])
        posed[key] = _mean_pose(m, jm)
    real = lambda action, style, take: posed[(action, names[style], take)] - posed[(action, names[neutral], take)]
    walk = {s: (real("walk", s, "001") + real("walk", s, "002")) / 2 for s in styles}
    out: dict = {"styles": styles, "actions": {}}
    model_walk: dict[str, np.ndarray] = {}  # the model's change on the walk, the first action below
    against = lambda a, b: tuple(round(v, 3) for v in _cosine_size(a, b))
    for action, take in [("walk", "002")] + [(a, "001") for a in BANDAI1_KEPT_BACK]:
        key = (action, names[neutral], take)
        clip = ActionClip(takes[key].name, action, "bandai-namco-1", motions[key], neutral)
        jm = _map(clip, model)
        identity, styled = _transfers(clip, model, styles, "input")
        row = {}
        for s in styles:
            change = style_change(clip.motion, styled[s], identity, jm)["heading"]
            mine = np.concatenate([v for k, v in change.items() if k != "Hips"])
            model_walk.setdefault(s, mine)
            theirs = real(action, s, take)
            row[s] = {
                "performer": against(real("walk", s, "001"), real("walk", s, "002"))
                if action == "walk"
                else against(theirs, walk[s]),
                "model": None if action == "walk" else against(mine, model_walk[s]),
                "model_vs_performer": against(mine, theirs),
            }
        out["actions"][action] = row
    return out


def performer_markdown(report: dict) -> str:
    """``performer_changes`` as a table."""
    styles = report["styles"]
    lines = [
        "| action | " + " | ".join(styles) + " |",
        "|---|" + "---:|" * len(styles),
    ]
    for action, row in report["actions"].items():
        label = "walk (take 1 against take 2)" if action == "walk" else action
        cells = []
        for s in styles:
            r = row[s]
            model = f"{r['model'][0]:.2f}" if r["model"] else "-"
            cells.append(f"{r['performer'][0]:.2f} / {model} / {r['model_vs_performer'][0]:.2f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ---------------------------------------------------------------- feet and pace


def walk_clips(data_dir: str | None = None) -> list[ActionClip]:
    """Two Bandai-Namco-2 test walks (the reference: the model's own data), then walks and runs of
    other performers: xia-sample's neutral walk, CMU subject 2's walks and run, and a generated walk
    in place (and the xia walk in place)."""
    root = data_root(data_dir)
    out = [c for c in bandai2_test_walks(data_dir) if c.action == "walk"][:2]
    xia = next(c for c in find_clips(root, "xia-sample") if c.name.startswith("neutral_01"))
    xia_walk = ActionClip("xia neutral walk", "walk", "xia-sample", trimmed(load_motion(xia)), "normal")
    out.append(xia_walk)
    cmu = unpack(root / "cmu-sample.tar.xz") / "cmu-sample" / "iclone"
    for stem in ("002_01", "002_02", "002_03"):
        out.append(
            ActionClip(
                f"cmu {stem}",
                CMU_ACTIONS[stem],
                "cmu-sample/iclone",
                trimmed(bvh.read(cmu / f"{stem}.bvh")),
                "normal",
            )
        )
    generated = resample(walk(SECONDS, fps=60.0, turn_degrees_per_second=0.0), 30.0)
    out.append(ActionClip("generated walk in place", "walk in place", "procedural", in_place(generated), "normal"))
    out.append(
        ActionClip("xia neutral walk in place", "walk in place", "xia-sample", in_place(xia_walk.motion), "normal")
    )
    return out


def _feet(m: Motion, jm: JointMap) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Global positions of the feet's joints ``[T, 2, k, 3]`` (side; ankle, and toe where mapped), of
    the ankles ``[T, 2, 3]``, of the body (between the hips) ``[T, 3]``, and the body's up (hips to
    head, unit; the world's up where no head is mapped) ``[T, 3]``."""
    g = forward_positions(m.rotations, m.positions, m.skeleton.parents)
    source = {jm.target.names[t]: s for t, s in jm.pairs}
    joints = [[source[f"{p}_{s}"] for p in ("Foot", "Toes") if f"{p}_{s}" in source] for s in "LR"]
    k = min(len(side) for side in joints)
    body = g[:, [source[f"UpperLeg_{s}"] for s in "LR"]].mean(1)
    up = g[:, source["Head"]] - body if "Head" in source else np.broadcast_to([0.0, 1.0, 0.0], body.shape)
    up = up / np.maximum(np.linalg.norm(up, axis=-1, keepdims=True), 1e-9)
    return g[:, [side[:k] for side in joints]], g[:, [side[0] for side in joints]], body, up


def style_recogniser(model: GeneratorWeights):
    """The shipped style recogniser whose styles are the model's (``styleerd train-recognisers``),
    or None where none is."""
    from styleerd.model.checkpoint import load_recognisers

    for stem in (None, "recognisers-bandai12"):
        style, _, meta = load_recognisers(stem)
        if tuple(meta["style"]["labels"]) == tuple(model.config.styles):
            return style
    return None


def read_as_target(output: Motion, jm: JointMap, model: GeneratorWeights, recogniser, target: str) -> float | None:
    """The share of an output's 24-frame windows (every 12 frames, on the model's skeleton at its
    rate, as the recognisers read Bandai-Namco-2's) that the style ``recogniser`` reads as
    ``target``; None for a clip shorter than a window."""
    import torch

    from styleerd.data.windows import gather_windows
    from styleerd.eval.metrics import played_channels

    fps = float(model.meta["data"]["fps"])
    on_model = to_target(output if output.fps == fps else resample(output, fps), jm)
    features = played_channels(model, on_model.rotations, on_model.positions, fps)
    starts = np.arange(0, len(features) - 24 + 1, 12)
    if not len(starts):
        return None
    with torch.no_grad():
        read = recogniser(torch.from_numpy(gather_windows(features, starts, 24))).argmax(-1).numpy()
    return round(float((read == model.config.styles.index(target)).mean()), 3)


def feet_figures(given: Motion, output: Motion, jm: JointMap, scale: float) -> dict:
    """Below the floor (cm under the input's lowest foot point over the clip), planted feet's slide,
    and the stride (95th percentile of the ankles' horizontal gap), input and output.

    A foot is planted where it can bear the body's weight and the input's ankle moves under 15 % of a
    leg length per second, or where the input's body (between the hips) stands still (as slowly) and
    its foot is flat on its floor (every joint of it within 5 % of a leg length of the lowest it goes): a
    walk in place, whose planted feet move back under a still body as on a treadmill. A foot bears
    weight where its ankle is half a leg or more under the hips, or a fifth of one under an upright body
    (hips to head within 60 degrees of the world's up: a squat), as the foot cleanup reads it; a
    swimmer's slow feet are not planted. The slide is the median horizontal speed (cm/s at the clip's
    own rate) of a planted foot against its ground: the world where the input's foot is still, the
    input's own foot where it moves along its floor (on a treadmill, or sliding in a dance)."""
    fin, ain, body, up = _feet(given, jm)
    fout, aout, _, _ = _feet(output, jm)
    floor = fin[..., 1].min()
    below = max(0.0, float(floor - fout[..., 1].min())) * scale
    leg = 0.45 * BODY_CM  # a leg is about 0.45 of the body
    velocity = lambda a: np.diff(a[..., [0, 2]], axis=0) * given.fps * scale
    v_in, v_out = velocity(ain), velocity(aout)
    under = (body[:, None, 1] - ain[..., 1]) * scale  # how far each ankle is under the hips
    bears = (under >= LEG_DOWN * leg) | ((up[:, None, 1] >= UPRIGHT) & (under >= SQUAT_DOWN * leg))
    still = np.linalg.norm(v_in, axis=-1) < 0.15 * leg
    body_still = np.linalg.norm(velocity(body), axis=-1) < 0.15 * leg
    flat = (((fin[..., 1] - fin[..., 1].min(0)) * scale < 0.05 * leg).all(-1))[1:]
    planted = (still | (body_still[:, None] & flat)) & bears[1:]
    ground = np.where(still[..., None], 0.0, v_in)  # what a planted foot stands on moves so
    off = lambda v: np.linalg.norm(v - ground, axis=-1)[planted]
    slide = lambda v: round(float(np.median(off(v))), 2) if planted.any() else None
    gap = lambda a: np.percentile(np.linalg.norm(a[:, 0, [0, 2]] - a[:, 1, [0, 2]], axis=-1), 95) * scale
    return {
        "below_floor_cm": round(below, 2),
        "slide_cm_s": {"input": slide(v_in), "output": slide(v_out)},
        "stride_cm": {"input": round(float(gap(ain)), 1), "output": round(float(gap(aout)), 1)},
    }


def evaluate_feet(
    model: GeneratorWeights,
    data_dir: str | None = None,
    poses: tuple[str, ...] = ("input", "network"),
    root_speed: tuple[bool, ...] = (False, True),
    recogniser=None,
) -> dict:
    """``feet_figures`` of every walk clip into every style (and identity), per pose path and with
    and without ``--root-speed``, with the share of each output's windows the style ``recogniser``
    reads as its target (``read_as_target``, where one is given); the labeller's read of each walk
    (with inferred labels)."""
    neutral = model.config.neutral_style
    out: dict = {}
    for clip in tqdm(walk_clips(data_dir), desc="feet", leave=False):
        jm = _map(clip, model)
        scale = _body_scale(clip.motion.skeleton, jm)
        row: dict = {"action": clip.action, "source": clip.source}
        labels: list = []
        transfer_motion(
            clip.motion,
            model,
            30.0,
            TransferOptions({neutral: 1.0}),
            labels=labels,
            where=clip.name,
        )
        row["labeller_reads"] = list(labels[0]) if labels else None
        for pose in poses:
            for rs in root_speed:
                key = f"pose {pose}" + (", root speed" if rs else "")
                row[key] = {}
                for style in model.config.styles:
                    o = TransferOptions({style: 1.0}, clip.input_style, root_speed=rs, pose=pose)
                    output = transfer_motion(clip.motion, model, 30.0, o, where=clip.name)
                    row[key][style] = feet_figures(clip.motion, output, jm, scale)
                    if recogniser is not None:
                        row[key][style]["read_as_target"] = read_as_target(output, jm, model, recogniser, style)
        out[clip.name] = row
    return out


def stride_against_style(feet: dict) -> dict[str, dict[str, tuple[str, float, float]]]:
    """Per clip of ``evaluate_feet``'s table and pose path, the target style whose stride is furthest
    from both the input's and the style's own change, with its output stride over the input's and that
    over the same ratio on the table's Bandai-Namco-2 walks (the style's own change). Issue 35's bar:
    one of the two within 20 % of 1."""
    reference = [row for row in feet.values() if row["source"].startswith("bandai-namco-2")]
    ratio = lambda f: f["stride_cm"]["output"] / f["stride_cm"]["input"]
    out: dict[str, dict[str, tuple[str, float, float]]] = {}
    for name, row in feet.items():
        out[name] = {}
        for key in (k for k in row if k.startswith("pose")):
            kept = {}
            for s, f in row[key].items():
                r = ratio(f)
                kept[s] = (r, r / np.mean([ratio(b[key][s]) for b in reference]))
            worst = max(kept, key=lambda s: min(abs(kept[s][0] - 1.0), abs(kept[s][1] - 1.0)))
            out[name][key] = (worst, round(float(kept[worst][0]), 3), round(float(kept[worst][1]), 3))
    return out


# ---------------------------------------------------------------- report


def markdown(report: dict) -> str:
    """The action table (per clip: identity error and correlation, per style correlation, cosine
    and size ratio of its change against the walks') per pose path, and the feet table."""
    styles = report["styles"]
    lines = [
        (
            f"Clips cut to {report['seconds']:g} s; errors in cm of a {report['body_cm']:g} cm body; per style: "
            "velocity correlation / "
            "cosine of the style's change against the walks' / its size over the walks'."
        ),
        "",
    ]
    for pose, r in report["poses"].items():
        lines += [
            f"### Pose `{pose}`",
            "",
            "| clip | action | identity cm | identity corr | " + " | ".join(styles) + " |",
            "|---|---|---:|---:|" + "---:|" * len(styles),
        ]
        for name, row in r["clips"].items():
            cells = [
                f"{row['styles'][s]['correlation']:.2f} / {row['styles'][s]['cosine']:.2f} / "
                f"{row['styles'][s]['size_ratio']:.2f}"
                for s in styles
            ]
            lines.append(
                f"| {name} | {row['action']} | {row['identity']['error_cm']:.1f} | "
                f"{row['identity']['correlation']:.2f} | " + " | ".join(cells) + " |"
            )
        for group, g in r["summary"].items():
            cells = [
                f"{g['styles'][s]['correlation']:.2f} / {g['styles'][s]['cosine']:.2f} / "
                f"{g['styles'][s]['size_ratio']:.2f}"
                for s in styles
            ]
            lines.append(
                f"| **{group}: mean** | {g['clips']} clips | {g['identity_error_cm']['mean']:.1f} | "
                f"{g['identity_correlation']['mean']:.2f} | " + " | ".join(cells) + " |"
            )
            cells = [
                f"{g['styles'][s]['correlation_worst']:.2f} / {g['styles'][s]['cosine_worst']:.2f} / "
                f"{g['styles'][s]['size_ratio_worst']:.2f}"
                for s in styles
            ]
            lines.append(
                f"| **{group}: worst** | | {g['identity_error_cm']['worst']:.1f} | "
                f"{g['identity_correlation']['worst']:.2f} | " + " | ".join(cells) + " |"
            )
        low = {n: row for n, row in r["clips"].items() if min(x["cosine"] for x in row["styles"].values()) < 0.7}
        if low:
            lines += [
                "",
                (
                    "The clips whose change points elsewhere than the walks' (a cosine under 0.7), the same cosine in "
                    "the body's own frame (up from the hips to the head) instead of its heading:"
                ),
                "",
                "| clip | action | " + " | ".join(styles) + " |",
                "|---|---|" + "---:|" * len(styles),
            ]
            lines += [
                f"| {n} | {row['action']} | "
                + " | ".join(
                    f"{row['styles'][s]['cosine']:.2f} -> {row['styles'][s]['cosine_body']:.2f}" for s in styles
                )
                + " |"
                for n, row in low.items()
            ]
            g = r["summary"]["actions"]["styles"]
            for label, k in (("mean", ""), ("worst", "_worst")):
                lines.append(
                    f"| **actions: {label}** | | "
                    + " | ".join(f"{g[s]['cosine' + k]:.2f} -> {g[s]['cosine_body' + k]:.2f}" for s in styles)
                    + " |"
                )
        feet = actions_feet(r["clips"])
        if feet:
            lines += ["", feet]
        lines.append("")
    if report.get("performers"):
        lines += [
            "### The style's change as a performer makes it",
            "",
            (
                "Bandai-Namco-1's performer in each style, on the takes every training run keeps back (the styles the "
                "model shares with it; pose `input`), cosines of the style's change (mean root-relative pose, heading "
                "frame): the performer's on the action against the performer's on the walk / the model's on the "
                "normal take against the model's on the normal walk / the model's against the performer's on the "
                "action. On the walk, the first: the performer's change on one take against the other's."
            ),
            "",
            performer_markdown(report["performers"]),
            "",
        ]
    if report.get("feet"):
        keys = [k for k in next(iter(report["feet"].values())) if k.startswith("pose")]
        lines += [
            "### Feet and pace",
            "",
            (
                "Worst over the target styles: cm below the input's floor; planted feet's slide (cm/s, input's in "
                "brackets); stride (cm, input's in brackets), smallest over the styles, then the style furthest from "
                "both the input's stride and its own change: output over input stride / that over the same on the "
                "Bandai-Namco-2 walks above (1 = the style changes it as on the model's data; the bar: one of the two "
                "within 0.8 to 1.2); what the labeller reads."
            ),
            "",
            "| clip | labeller reads | " + " | ".join(keys) + " |",
            "|---|---|" + "---|" * len(keys),
        ]
        against = stride_against_style(report["feet"])
        for name, row in report["feet"].items():
            cells = []
            for k in keys:
                f = row[k].values()
                below = max(x["below_floor_cm"] for x in f)
                slides = [x["slide_cm_s"]["output"] for x in f if x["slide_cm_s"]["output"] is not None]
                slide_in = next(iter(row[k].values()))["slide_cm_s"]["input"]
                stride = min(x["stride_cm"]["output"] for x in f)
                stride_in = next(iter(row[k].values()))["stride_cm"]["input"]
                style, of_input, of_own = against[name][k]
                slide = f"slide {max(slides):.1f} ({slide_in}); " if slides else ""
                kept = f"{style} {of_input:.2f} / {of_own:.2f}"
                cells.append(f"{below:.1f} cm; {slide}stride {stride:.0f} ({stride_in:.0f}), {kept}")
            reads = "/".join(row["labeller_reads"]) if row["labeller_reads"] else "(given)"
            lines.append(f"| {name} | {reads} | " + " | ".join(cells) + " |")
        lines.append("")
        read = styles_read_markdown(report["feet"], report["styles"])
        if read:
            lines.append(read)
    return "\n".join(lines)


def styles_read_markdown(feet: dict, styles: list[str]) -> str:
    """The walks' outputs as the style recogniser reads them (``read_as_target``), per pose path:
    the mean over the target ``styles``, the least-read style, the identity read as the input's
    own style; empty where they were not read."""
    keys = [k for k in next(iter(feet.values())) if k.startswith("pose")]
    first = next(iter(feet.values()))[keys[0]]
    own = next((s for s in first if s not in styles), None)
    if own is None or first[own].get("read_as_target") is None:
        return ""
    lines = [
        (
            "The style as a recogniser reads it: the share of each output's 24-frame windows (on the model's "
            "skeleton) that the project's style recogniser, trained on Bandai-Namco-2's performer, reads as the "
            "target style; the mean over the target styles, the least-read one, and in brackets the identity "
            f"transfer's windows read as the input's own style ({own}). Where the identity is seldom read as {own}, "
            "the recogniser takes the performer's own manner for a style."
        ),
        "",
        "| clip | " + " | ".join(keys) + " |",
        "|---|" + "---|" * len(keys),
    ]
    for name, row in feet.items():
        cells = []
        for k in keys:
            shares = {s: row[k][s]["read_as_target"] for s in styles if row[k][s]["read_as_target"] is not None}
            least = min(shares, key=shares.get)
            cells.append(
                f"{np.mean(list(shares.values())):.2f} (least: {least} {shares[least]:.2f}) "
                f"[{row[k][own]['read_as_target']:.2f}]"
            )
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


FILMSTRIPS = {  # held-out clip -> the two styles its filmstrip shows
    "dance-short_normal_001": ("elderly", "exhausted"),
    "kick_normal_001": ("elderly", "exhausted"),
    "punch_normal_002": ("active", "youthful"),
}


def action_filmstrips(
    model: GeneratorWeights,
    out: Path,
    data_dir: str | None = None,
    strips: dict[str, tuple[str, str]] = FILMSTRIPS,
) -> list[Path]:
    """Per clip of ``strips`` (Bandai-Namco-1's dance, kick and punch), a filmstrip: the input, the
    identity transfer and its two styles with each pose path, named after the table ``out`` and the
    action (``docs/actions-kick.png`` beside ``docs/actions.md``), so another model's do not overwrite
    them."""
    from styleerd.eval.plots import filmstrip  # matplotlib: only for the pictures

    paths = []
    for clip in [c for c in held_out_clips(data_dir) if c.name in strips]:
        styles = [s for s in strips[clip.name] if s in model.config.styles]
        rows: list[tuple[str, Motion]] = [(f"input: {clip.source} {clip.name} (held out)", clip.motion)]
        for pose in ("network", "input"):
            identity, styled = _transfers(clip, model, styles, pose)
            rows += [(f"pose {pose}: identity (-> {clip.input_style})", identity)] + [
                (f"pose {pose}: -> {s}", m) for s, m in styled.items()
            ]
        path = out.with_name(f"{out.stem}-{clip.action}.png")
        filmstrip(
            rows,
            path,
            frames=8,
            title=f"{clip.action}: the paper's output (pose network) against the input's pose plus the style's posture "
            "(pose input)",
        )
        paths.append(path)
    return paths
