"""The labeller's familiarity at other percentiles, side by side: the shipped labeller's weights
given ``fit_familiarity`` at each pair of percentiles (``labeller_familiar``; none: no measure),
then measured on other performers' clips (``styleerd eval labels``: frames told a confident wrong
style, read as their own style or neutral, a styled clip's frames told its own style with
confidence) and on Bandai-Namco-2's test streams (the style as the stylizer uses it after 1 / 10 /
30 frames, the labeller's record).

    python benchmarks/familiar_sweep.py [--pairs 99.5,99.99 99,99.9 97,99.5 95,99] [--json docs/familiar-sweep.json]

About 45 s a pair on 2 cores; prints one Markdown table.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from styleerd.atomic import atomic_write_text
from styleerd.eval.labels import evaluate_labels
from styleerd.model.stored import load_generator_weights, load_labeller_weights
from styleerd.models import LABELLER, MODELS_DIR
from styleerd.train.config import TrainConfig
from styleerd.train.labeller import train_and_save

GROUPS = ("xia-sample", "cmu-sample iclone", "cmu-sample asf-names", "bandai-namco-1 kept back")


def measured(pair: tuple[float, ...], folder: Path, data: str | None) -> dict:
    """The shipped labeller refitted at ``pair`` (no epoch), and its figures."""
    config = TrainConfig(labeller_init_from=str(MODELS_DIR / LABELLER), labeller_epochs=0, labeller_familiar=pair)
    stem = folder / ("labeller-" + "-".join(map(str, pair)) if pair else "labeller-none")
    record = train_and_save(config, data, stem, progress=False)
    labels = evaluate_labels(load_generator_weights(), data, load_labeller_weights(stem))
    return {"groups": labels["groups"], "test_leaning_neutral": record["test_leaning_neutral"]}


def table(rows: dict[str, dict]) -> str:
    lines = [
        "| percentiles | confident wrong: " + " / ".join(GROUPS) + " | own or neutral, Bandai-Namco-1 "
        "| styled clips told their own with confidence, Bandai-Namco-1 "
        "| Bandai-Namco-2 test: style after 1 / 10 / 30 |",
        "|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        g, t = r["groups"], r["test_leaning_neutral"]
        lines.append(
            f"| {name} | "
            + " / ".join(f"{100 * g[k]['confident_wrong']:.1f}" for k in GROUPS)
            + f" % | {100 * g[GROUPS[-1]]['right_or_neutral']:.1f} % | {100 * g[GROUPS[-1]]['own_confident']:.1f} % | "
            + " / ".join(f"{100 * t[n]['style']:.1f}" for n in (1, 10, 30))
            + " % |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", nargs="+", default=["99.5,99.99", "99,99.9", "97,99.5", "95,99"])
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--data", help="data folder")
    args = ap.parse_args()
    pairs = [()] + [tuple(float(v) for v in p.split(",")) for p in args.pairs]
    with tempfile.TemporaryDirectory() as tmp:
        rows = {("none" if not p else f"{p[0]:g} / {p[1]:g}"): measured(p, Path(tmp), args.data) for p in pairs}
    print(table(rows))
    if args.json:
        atomic_write_text(args.json, json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
