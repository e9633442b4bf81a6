"""Joint rotations, twist included, on the user's own skeleton: the round trip at intensity 0
and the change a style makes, per joint, split into swing (where the bone points) and twist
(the roll about the bone, which moves no joint and shows only on a skinned body).

``styleerd eval rotations`` runs it on the model's own skeleton (Bandai-Namco-2 test clips),
the xia-sample clips (CMU names, 120 fps) and the demo walk on generated rigs (T-pose, A-pose,
centimetres, metres, Blender names and proportions, joint frames rolled about their bones).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from styleerd.data.datasets import data_root, find_clips
from styleerd.data.windows import split_takes
from styleerd.errors import StyleERDError
from styleerd.model.generator import StyleERD
from styleerd.motion import bvh, quat
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.procedural import rig_variants
from styleerd.motion.retarget import body_parts
from styleerd.runtime.offline import TransferOptions, transfer_motion

BODY_PARTS = ("hips", "spine", "chest", "neck", "head") + tuple(
    f"{side}_{p}"
    for side in ("left", "right")
    for p in ("collar", "shoulder", "elbow", "hand", "hip", "knee", "foot", "toe")
)


def bone_axes(skeleton) -> np.ndarray:
    """Per joint, the unit direction of its bone in its own frame: towards its first child
    (or its End Site; a joint with neither, along the bone that leads to it)."""
    ends = {j: o for j, o in skeleton.end_sites if np.linalg.norm(o) > 1e-9}
    out = np.empty((skeleton.n_joints, 3))
    for j in range(skeleton.n_joints):
        kids = [k for k in skeleton.children(j) if np.linalg.norm(skeleton.offsets[k]) > 1e-9]
        v = skeleton.offsets[kids[0]] if kids else ends.get(j, skeleton.offsets[j])
        out[j] = v / np.linalg.norm(v) if np.linalg.norm(v) > 1e-9 else (0.0, 1.0, 0.0)
    return out


def _degrees(q: np.ndarray) -> np.ndarray:
    return np.degrees(quat.angle_between(quat.identity(), q))


def rotation_errors(
    reference: Motion, motion: Motion, joints: list[int] | None = None
) -> dict[str, tuple[float, float, float]]:
    """Per joint (default every joint), the median over frames of the angle between the two
    motions' global rotations, and of its swing and twist about the joint's bone (degrees)."""
    g_ref = forward_kinematics(reference.rotations, reference.positions, reference.skeleton.parents)[0]
    g = forward_kinematics(motion.rotations, motion.positions, motion.skeleton.parents)[0]
    d = quat.mul(quat.inv(g_ref), g)  # in the joint's own frame, where its bone axis is fixed
    swing, twist = quat.swing_twist(d, bone_axes(reference.skeleton))
    out = {}
    for j in range(reference.skeleton.n_joints) if joints is None else joints:
        out[reference.skeleton.names[j]] = tuple(float(np.median(_degrees(x[:, j]))) for x in (d, swing, twist))
    return out


def worst(errors: dict[str, tuple[float, float, float]]) -> tuple[str, tuple[float, float, float]]:
    """The joint with the largest median angle, and its (angle, swing, twist)."""
    return max(errors.items(), key=lambda kv: kv[1][0])


def mapped_joints(skeleton) -> list[int]:
    """The joints that play a body part the model has (the ones retargeting carries over)."""
    return sorted(set(body_parts(skeleton).values()))


def _inputs(model: StyleERD, data_dir: str | None, clips_per_set: int) -> list[tuple[str, str, Motion, str]]:
    """(group, name, motion, its style in the model's labels) to measure on."""
    neutral = model.config.neutral_style
    out = [("generated rigs", name, m, neutral) for name, m in rig_variants().items()]
    try:
        root = data_root(data_dir)
    except StyleERDError:
        return out
    clips = find_clips(root, "bandai-namco-2")
    split = split_takes({k.name: (k.dataset, k.style, k.content) for k in clips})
    test = [k for k in clips if split[k.name] == "test" and k.content in ("walk", "run")]
    picked = {(k.style, k.content): k for k in test}  # one clip per style x content
    for k in sorted(picked.values(), key=lambda k: k.name)[:clips_per_set]:
        out.append(("model skeleton (Bandai-Namco-2 test)", k.name, bvh.read(k.path), k.style))
    xia_styles = {"neutral": neutral, "old": "elderly"}
    for path in sorted((root / "xia-sample").glob("*.bvh")):
        out.append(
            (
                "xia-sample (CMU names, 120 fps)",
                path.stem,
                bvh.read(path),
                xia_styles.get(path.stem.split("_")[0], neutral),
            )
        )
    return out


def rotation_report(
    model: StyleERD,
    fps: float,
    data_dir: str | None = None,
    clips_per_set: int = 14,
    stylised: str = "elderly",
    progress: Callable = tqdm,
) -> dict:
    """Per input: the worst mapped joint's median angle (swing, twist) between input and output
    with target style = input style at intensity 0 (the round trip: ideally nothing changes),
    and the same between input and the ``stylised`` transfer (the change a style makes)."""
    rows = []
    for group, name, motion, style in progress(_inputs(model, data_dir, clips_per_set), desc="rotations", unit="clip"):
        joints = mapped_joints(motion.skeleton)
        same = transfer_motion(motion, model, fps, TransferOptions({style: 1.0}, input_style=style, cleanup=False))
        styled = transfer_motion(motion, model, fps, TransferOptions({stylised: 1.0}, input_style=style, cleanup=False))
        round_trip, change = rotation_errors(motion, same, joints), rotation_errors(motion, styled, joints)
        parts = {p: motion.skeleton.names[j] for p, j in body_parts(motion.skeleton).items()}
        rows.append(
            {
                "group": group,
                "input": name,
                "input_style": style,
                "frames": motion.n_frames,
                "fps": motion.fps,
                "parts": parts,
                "round_trip": round_trip,
                "stylised": change,
                "round_trip_worst": worst(round_trip),
                "stylised_worst": worst(change),
            }
        )
    return {"stylised_target": stylised, "rows": rows}


def markdown(report: dict) -> str:
    lines = [
        (
            f"| input | group | round trip: worst joint, median angle (swing / twist) | "
            f"into {report['stylised_target']}: worst joint (swing / twist) |"
        ),
        "| --- | --- | --- | --- |",
    ]
    for r in report["rows"]:
        (a, (t, s, w)), (b, (t2, s2, w2)) = r["round_trip_worst"], r["stylised_worst"]
        lines.append(
            f"| {r['input']} | {r['group']} | {a} {t:.1f} ({s:.1f} / {w:.1f}) | {b} {t2:.1f} ({s2:.1f} / {w2:.1f}) |"
        )
    groups: dict[str, list] = {}
    for r in report["rows"]:
        groups.setdefault(r["group"], []).append(r)
    lines += [
        "",
        (
            "| group | joints | median over clips of the per-joint median angle, round trip: swing / twist | into the "
            "style: swing / twist |"
        ),
        "| --- | --- | --- | --- |",
    ]
    for group, rows in groups.items():
        per = lambda key, k, rows=rows: np.median([np.median([v[k] for v in r[key].values()]) for r in rows])
        lines.append(
            f"| {group} | all mapped | {per('round_trip', 1):.1f} / {per('round_trip', 2):.1f} | "
            f"{per('stylised', 1):.1f} / {per('stylised', 2):.1f} |"
        )
    names = list(groups)
    lines += [
        "",
        (
            "Per body part, the median over a group's clips of the joint's median angle, swing / twist (round trip "
            "| into the style):"
        ),
        "",
        "| body part | " + " | ".join(names) + " |",
        "| --- |" + " --- |" * len(names),
    ]
    for part in BODY_PARTS:
        cells = []
        for group in names:
            found = [
                (r["round_trip"][r["parts"][part]], r["stylised"][r["parts"][part]])
                for r in groups[group]
                if part in r.get("parts", {})
            ]
            if not found:
                cells.append("-")
                continue
            rt, st = np.median([f[0] for f in found], axis=0), np.median([f[1] for f in found], axis=0)
            cells.append(f"{rt[1]:.1f} / {rt[2]:.1f} \\| {st[1]:.1f} / {st[2]:.1f}")
        lines.append(f"| {part.replace('_', ' ')} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write(report: dict, path: Path) -> None:
    import json

    from styleerd.atomic import atomic_write_text

    atomic_write_text(path.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    atomic_write_text(path.with_suffix(".md"), markdown(report))
