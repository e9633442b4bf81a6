"""Models fine-tuned from the shipped one for other performers' actions (``outside_batch``, and
``pose_change``: a network that predicts a change to the input's pose) beside it, as one Markdown
table, from what ``styleerd eval actions`` and ``styleerd eval quality --pose input`` wrote for
each. Measure first, e.g. for ``models/recipes/bandai2-outside``
(M), keeping the actions JSON:

    styleerd eval actions --model M --out /tmp/o/actions.md
    styleerd eval quality --model M --pose input --json docs/outside/NAME-quality.json --as-name input
    python benchmarks/outside_training.py NAME=ACTIONS_JSON,QUALITY_JSON ...

A quality JSON holds entries by name (``--as-name``); the pose ``input`` entry is read."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from styleerd.train.validation import CRA_BAR, FMD_BAR, style_ratios


def row(name: str, actions: dict, quality: dict) -> list[str]:
    net = actions["poses"]["network"]["summary"]["actions"]
    given = actions["poses"]["input"]["summary"]["actions"]
    cosines = ", ".join(f"{s} {v['cosine']:.2f}" for s, v in given["styles"].items())
    feet = actions.get("feet", {})
    strides = [
        f"{min(r['stride_cm']['output'] for r in feet[c]['pose network'].values()):.0f} "
        f"({next(iter(feet[c]['pose network'].values()))['stride_cm']['input']:.0f})"
        for c in ("generated walk in place", "xia neutral walk in place")
        if c in feet
    ]
    fmd, cra = style_ratios(quality)
    worst_fmd, worst_cra = max(fmd, key=fmd.get), min(cra, key=cra.get)
    meets = fmd[worst_fmd] <= FMD_BAR and cra[worst_cra] >= CRA_BAR
    return [
        name,
        f"{net['identity_error_cm']['mean']:.1f} / {net['identity_correlation']['mean']:.2f}",
        cosines,
        " / ".join(strides) or "-",
        f"{100 * quality['sra']:.1f} / {100 * quality['cra']:.1f}",
        f"{fmd[worst_fmd]:.2f} ({worst_fmd})",
        f"{100 * cra[worst_cra]:.1f} ({worst_cra})" + ("" if meets else " **below the bar**"),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", help="NAME=ACTIONS_JSON,QUALITY_JSON")
    args = ap.parse_args()
    head = [
        "model",
        "held-out actions, pose network: identity cm / correlation",
        "held-out actions, pose input: cosine of each style's change against the walks'",
        "walks in place, pose network: stride cm, generated / xia (input's)",
        "Bandai-Namco-2 test: SRA / CRA %",
        "worst FMD / floor",
        "worst CRA / ceiling %",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for spec in args.models:
        name, paths = spec.split("=", 1)
        actions_path, quality_path = paths.split(",")
        quality = json.loads(Path(quality_path).read_text())
        lines.append("| " + " | ".join(row(name, json.loads(Path(actions_path).read_text()), quality["input"])) + " |")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
