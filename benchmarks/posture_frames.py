"""Where a style's posture takes the joints: its rotations alone against its rotations then its
joint offsets reached, side by side on the held-out actions.

Issue 35, item 2: on actions the network never learnt, the default pose path gives the input's own
pose turned by the style's posture. With the posture's rotations alone (given * C per joint, C the
mean of inv(identity) * styled over neutral training walks) the style's change there pointed as on
walks with a cosine of 0.57-0.78 (mean over the held-out clips), while on the Bandai-Namco-2 test
walks the posture alone gives the network's change back (``posture_alone_on_walks``): the same
rotations move a body in another pose another way. (Turning each joint in its parent's frame or in
the body's heading frame instead did no better: docs/model.md, measured by this script at commit
fa1eb34.) ``reach`` then turns each joint by the shortest arc that takes its children where the
input's joints are moved by the style's mean joint offsets (``runtime.stylizer._reach``), the
offsets measured and reached in the body's heading frame (up the world's) or along its own axes (up
from the hips to the head; shipped). The postures are measured on the same walks; each runs the
whole ``styleerd eval actions`` table (pose input) through ``transfer``.

Run: ``python benchmarks/posture_frames.py --walks 16 --out docs/posture-frames.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from itertools import islice
from pathlib import Path

import numpy as np

from styleerd.eval import actions
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.runtime.posture import measure_posture, training_walks

VARIANTS = ("rotations", "reach, heading frame", "reach, body frame")  # the last is shipped


def posture_alone_on_walks(model: GeneratorWeights, walks: int) -> dict[str, float]:
    """Per style, the cosine of the change the shipped posture alone makes on Bandai-Namco-2 test walks
    (every frame treated as unfamiliar) against the network's own change on them (the default path
    there): how much of a style's change on walks a posture holds."""
    styles = [s for s in model.config.styles if s != model.config.neutral_style]
    clips = actions.bandai2_test_walks(None, walks)
    unfamiliar = dataclasses.replace(model, familiar=(-2.0, -1.0))  # every frame

    def changes(clip, alone: bool) -> dict:
        jm = actions._map(clip, model)
        identity, styled = actions._transfers(clip, unfamiliar if alone else model, styles, "input")
        return {s: actions.style_change(clip.motion, m, identity, jm)["heading"] for s, m in styled.items()}

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
    walks = list(islice(training_walks(model), a.walks))
    postures = {frame: measure_posture(model, walks, frame) for frame in ("heading", "body")}
    report = {"walks": a.walks, "posture_alone_on_walks": posture_alone_on_walks(model, 4), "variants": {}}
    print("the shipped posture alone on 4 Bandai-Namco-2 test walks, cosine against the network's change:")
    print(json.dumps(report["posture_alone_on_walks"]), flush=True)
    for variant in VARIANTS:
        frame = "body" if "body" in variant else "heading"
        vectors, offsets = postures[frame]
        posed = dataclasses.replace(
            model, posture=vectors, posture_offsets=offsets if "reach" in variant else None, posture_frame=frame
        )
        table = actions.evaluate_actions(posed, poses=("input",), walks=a.reference_walks)["poses"]["input"]
        rows = [r for r in table["clips"].values() if r["group"] == "actions"]
        dry = [r for r in rows if r["action"] != "swim"]
        styles = list(rows[0]["styles"])
        mean = lambda rs, s, k: round(float(np.mean([r["styles"][s][k] for r in rs])), 3)
        report["variants"][variant] = {
            s: {
                "cosine": mean(rows, s, "cosine"),
                "cosine_body": mean(rows, s, "cosine_body"),
                "cosine_body_worst": round(float(min(r["styles"][s]["cosine_body"] for r in rows)), 3),
                "cosine_without_swims": mean(dry, s, "cosine"),
                "clips_at_0.7": sum(r["styles"][s]["cosine"] >= 0.7 for r in rows),
                "size_ratio": mean(rows, s, "size_ratio"),
                "correlation": mean(rows, s, "correlation"),
            }
            for s in styles
        }
        report["clips"] = len(rows)
        print(variant, json.dumps(report["variants"][variant]), flush=True)
    print(
        f"\nheld-out actions ({report['clips']} clips): cosine / without the swims / clips at 0.7 / size / correlation"
        " / in the body's own frame: cosine, worst"
    )
    print("| style | " + " | ".join(VARIANTS) + " |\n|---|" + "---|" * len(VARIANTS))
    for s in report["variants"][VARIANTS[0]]:
        cells = [report["variants"][v][s] for v in VARIANTS]
        print(
            f"| {s} | "
            + " | ".join(
                f"{c['cosine']:.2f} / {c['cosine_without_swims']:.2f} / {c['clips_at_0.7']} / {c['size_ratio']:.2f} / "
                f"{c['correlation']:.2f} / {c['cosine_body']:.2f}, {c['cosine_body_worst']:.2f}"
                for c in cells
            )
            + " |"
        )
    if a.out:
        Path(a.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
