"""Which frame a style's posture should turn a joint in: measured side by side on the held-out actions.

Issue 35, item 2: on actions the network never learnt, the default pose path gives the input's own
pose turned by the style's posture, and the style's change there points as on walks with a cosine
of 0.57-0.78 (mean over the held-out clips; docs/actions.md). On the Bandai-Namco-2 test walks,
the posture alone gives the network's change back with a cosine of 0.82-0.98
(``posture_alone_on_walks``), so what is lost on actions is how the same rotations move a body in
another pose. The shipped posture turns each joint in its own frame (local: given * change). This
script measures two other frames, each with its posture measured again on the same walks in its
own frame:

- ``joint``: given * C per joint, C the mean of inv(identity) * styled (the shipped rule);
- ``parent``: C * given, in the parent's frame (the root's in the body's heading frame);
- ``body``: each joint's orientation in the body's heading frame turned by C (children keep
  their own turn: local change inv(G) inv(C_parent) C G);
- ``reach`` (shipped): ``joint``, then each joint turned by the shortest arc that takes its children
  where the input's joints are moved by the style's mean joint offsets (``runtime.stylizer._reach``),
  the offsets measured on the same walks.

The three frames run without offsets. Every variant runs the whole ``styleerd eval actions`` table
(pose input) through ``transfer``.
Run: ``python benchmarks/posture_frames.py --walks 16 --out docs/posture-frames.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from functools import partial
from itertools import islice
from pathlib import Path

import numpy as np

import styleerd.runtime.stylizer as stylizer_module
from styleerd.eval import actions
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.motion import quat
from styleerd.motion.kinematics import facing_directions, forward_kinematics, heading_rotations
from styleerd.runtime.posture import measure_posture, training_walks

FRAMES = ("joint", "parent", "body")
VARIANTS = (*FRAMES, "reach")


def body_frames(model: GeneratorWeights, local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading rotations ``[N, 4]`` of poses ``[N, J, 4]`` (local, the root's in the world) and their
    global rotations in the body's heading frame ``[N, J, 4]``."""
    sk = model.skeleton
    g_rot, g_pos = forward_kinematics(local, np.broadcast_to(sk.offsets, local.shape[:-1] + (3,)), sk.parents)
    left, right = (sk.index("UpperLeg_L"), sk.index("UpperArm_L")), (sk.index("UpperLeg_R"), sk.index("UpperArm_R"))
    heading = heading_rotations(facing_directions(g_pos, left, right))
    return heading, quat.mul(quat.inv(heading)[:, None], g_rot)


def change_in(frame: str, model: GeneratorWeights, same: np.ndarray, styled: np.ndarray) -> np.ndarray:
    """The rotation ``[N, J, 4]`` that takes the identity output ``same`` to ``styled`` in ``frame``."""
    if frame == "joint":
        return quat.mul(quat.inv(same), styled)
    heading, g_same = body_frames(model, same)
    if frame == "body":
        return quat.mul(body_frames(model, styled)[1], quat.inv(g_same))
    out = quat.mul(styled, quat.inv(same))
    h = heading[:, None]
    out[:, :1] = quat.mul(quat.mul(quat.inv(h), out[:, :1]), h)
    return out


def as_local(frame: str, model: GeneratorWeights, given: np.ndarray, change: np.ndarray) -> np.ndarray:
    """A change in ``frame`` as the local one the stylizer's blend applies (given * local)."""
    if frame == "joint":
        return change
    heading, g = body_frames(model, given)
    if frame == "body":
        parents = model.skeleton.parents
        above = np.concatenate([quat.identity((len(given), 1)), change[:, parents[1:]]], axis=1)
        return quat.mul(quat.mul(quat.inv(g), quat.mul(quat.inv(above), change)), g)
    turned = change.copy()
    h = heading[:, None]
    turned[:, :1] = quat.mul(quat.mul(h, change[:, :1]), quat.inv(h))
    return quat.mul(quat.mul(quat.inv(given), turned), given)


def postures(model: GeneratorWeights, walks: int) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """Each variant's posture (rotation vectors, offsets or None) ``[styles, J, 3]`` over the first
    ``walks`` neutral training walks."""
    chosen = list(islice(training_walks(model), walks))
    out = {f: measure_posture(model, chosen, partial(change_in, f, model)) for f in FRAMES}
    return {**{f: (v, None) for f, (v, _) in out.items()}, "reach": out["joint"]}


def with_frame(frame: str, model: GeneratorWeights, serial):
    """The stylizer's blend towards the input (``serial``, one stream) with the posture applied in ``frame``."""

    def blend(given, same, styled, change, *rest):
        serial(given, same, styled, np.ascontiguousarray(as_local(frame, model, given, change)), *rest)

    return blend


def posture_alone_on_walks(model: GeneratorWeights, walks: int) -> dict[str, float]:
    """Per style, the cosine of the change the shipped posture alone makes on Bandai-Namco-2 test walks
    (every frame treated as unfamiliar) against the network's own change on them (the default path
    there): how much of a style's change on walks a posture holds."""
    styles = [s for s in model.config.styles if s != model.config.neutral_style]
    clips = actions.bandai2_test_walks(None, walks)
    familiar = stylizer_module.FAMILIAR, stylizer_module.UNFAMILIAR

    def changes(clip, alone: bool) -> dict:
        stylizer_module.FAMILIAR, stylizer_module.UNFAMILIAR = (-2.0, -1.0) if alone else familiar
        try:
            jm = actions._map(clip, model)
            scale = actions._body_scale(clip.motion.skeleton, jm)
            identity, styled = actions._transfers(clip, model, styles, "input")
        finally:
            stylizer_module.FAMILIAR, stylizer_module.UNFAMILIAR = familiar
        return {s: actions.style_change(clip.motion, m, identity, jm, scale) for s, m in styled.items()}

    network, alone = [changes(c, False) for c in clips], [changes(c, True) for c in clips]
    mean = lambda cs, s: {k: np.mean([c[s][k] for c in cs], 0) for k in cs[0][s]}
    return {s: round(actions._compare(mean(alone, s), mean(network, s))[0], 3) for s in styles}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--walks", type=int, default=16, help="neutral training walks the postures are measured on")
    p.add_argument(
        "--reference-walks", type=int, default=8, help="Bandai-Namco-2 test walks the changes are set against"
    )
    p.add_argument("--out", default=None, help="write the figures as JSON")
    a = p.parse_args()
    model = load_generator_weights(None)
    measured = postures(model, a.walks)
    serial, shards = stylizer_module._towards_the_input, stylizer_module._towards_the_input_on_shards
    report = {"walks": a.walks, "posture_alone_on_walks": posture_alone_on_walks(model, 4), "frames": {}}
    print("the shipped posture alone on 4 Bandai-Namco-2 test walks, cosine against the network's change:")
    print(json.dumps(report["posture_alone_on_walks"]), flush=True)
    for frame in VARIANTS:
        # transfer steps one stream, on the serial kernel: the sharded one must not run (it would use the joint frame)
        stylizer_module._towards_the_input, stylizer_module._towards_the_input_on_shards = (
            with_frame(frame, model, serial) if frame in FRAMES else serial,
            None,
        )
        vectors, offsets = measured[frame]
        try:
            table = actions.evaluate_actions(
                dataclasses.replace(model, posture=vectors, posture_offsets=offsets),
                poses=("input",),
                walks=a.reference_walks,
            )["poses"]["input"]
        finally:
            stylizer_module._towards_the_input, stylizer_module._towards_the_input_on_shards = serial, shards
        rows = [r for r in table["clips"].values() if r["group"] == "actions"]
        dry = [r for r in rows if r["action"] != "swim"]
        styles = list(rows[0]["styles"])
        mean = lambda rs, s, k: round(float(np.mean([r["styles"][s][k] for r in rs])), 3)
        report["frames"][frame] = {
            s: {
                "cosine": mean(rows, s, "cosine"),
                "cosine_without_swims": mean(dry, s, "cosine"),
                "clips_at_0.7": sum(r["styles"][s]["cosine"] >= 0.7 for r in rows),
                "size_ratio": mean(rows, s, "size_ratio"),
                "correlation": mean(rows, s, "correlation"),
            }
            for s in styles
        }
        report["clips"] = len(rows)
        print(frame, json.dumps(report["frames"][frame]), flush=True)
    print(
        f"\nheld-out actions ({report['clips']} clips): cosine / without the swims / clips at 0.7 / size / correlation"
    )
    print("| style | " + " | ".join(VARIANTS) + " |\n|---|" + "---|" * len(VARIANTS))
    for s in report["frames"]["joint"]:
        cells = [report["frames"][f][s] for f in VARIANTS]
        print(
            f"| {s} | "
            + " | ".join(
                f"{c['cosine']:.2f} / {c['cosine_without_swims']:.2f} / {c['clips_at_0.7']} / {c['size_ratio']:.2f} / "
                f"{c['correlation']:.2f}"
                for c in cells
            )
            + " |"
        )
    if a.out:
        Path(a.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
