"""A fine-tune and the model it started from, their weights mixed (WiSE-FT, Wortsman et al. 2022:
a fine-tune's robustness with its start's accuracy, sometimes), side by side: each mix given its
own posture (`styleerd posture`) and measured on Bandai-Namco-2 (`evaluate_model`, the default
pose path): SRA, CRA, each style's CRA over its ceiling (issue 35's bar: 95 %) and the worst FMD
over its floor. The fine-tunes with other performers' motion (`configs/bandai2-outside*.yaml`) lost
the elderly style's CRA; this asks whether a mix keeps it. Choose on ``--split val``.

    python benchmarks/wise_sweep.py [--fine-tune models/recipes/bandai2-outside] [--mix 0 0.25 0.5 0.75 1]
        [--split val] [--json docs/outside/wise-sweep.json] [--keep FOLDER]

``--keep`` keeps each mix (``FOLDER/mix-SHARE``, with its posture) to measure further or ship.

About 25 s a mix on 2 cores; prints one Markdown table.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import torch

from styleerd import cli
from styleerd.atomic import atomic_write_text
from styleerd.eval.metrics import evaluate_model
from styleerd.model import checkpoint as ckpt
from styleerd.train.soup import averaged

ROOT = Path(__file__).resolve().parents[1]


def mixed(start: str, tuned: str, share: float) -> tuple[dict[str, torch.Tensor], dict]:
    """The generator ``(1 - share) * start + share * tuned`` (float64 sums) and the fine-tune's
    metadata, its posture left out (each mix measures its own)."""
    (a, _), (b, meta) = ckpt.load_generator(start), ckpt.load_generator(tuned)
    if meta["training"].get("started_from", {}).get("model") != start:
        raise SystemExit(f"{tuned} was not fine-tuned from {start}")
    tensors = averaged([a.state_dict(), b.state_dict()], [1 - share, share])
    name = f"{1 - share:g} {Path(start).name} + {share:g} {Path(tuned).name}"
    meta = {k: v for k, v in meta.items() if k != "posture"}
    return tensors, {**meta, "training": {**meta["training"], "config": {**meta["training"]["config"], "name": name}}}


def measured(stem: Path, data: str | None, split: str) -> dict:
    if cli.main(["posture", str(stem)] + (["--data", data] if data else [])):
        raise SystemExit(f"styleerd posture {stem} failed")
    q = evaluate_model(ckpt.load_generator(stem)[0], data, split, "input")
    of_ceiling = {s: q["cra_per_style"][s] / q["content_ceiling_per_style"][s] for s in q["cra_per_style"]}
    keep = ("sra", "cra", "worst_fmd_over_floor", "worst_cra_of_ceiling")
    return {**{k: q[k] for k in keep}, "cra_of_ceiling_per_style": of_ceiling}


def table(rows: dict[str, dict]) -> str:
    styles = list(next(iter(rows.values()))["cra_of_ceiling_per_style"])
    lines = [
        "| share of the fine-tune | SRA % | CRA % | CRA of its ceiling %: "
        + " / ".join(styles)
        + " | worst FMD / floor |",
        "|---|---|---|---|---|",
    ]
    for share, r in rows.items():
        per = " / ".join(f"{100 * r['cra_of_ceiling_per_style'][s]:.1f}" for s in styles)
        lines.append(
            f"| {share} | {100 * r['sra']:.1f} | {100 * r['cra']:.1f} | {per} | {r['worst_fmd_over_floor']:.2f} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--start", default="styleerd-bandai2")
    ap.add_argument("--fine-tune", default=str(ROOT / "models" / "recipes" / "bandai2-outside"))
    ap.add_argument("--mix", nargs="+", type=float, default=[0.0, 0.25, 0.5, 0.75, 1.0])
    ap.add_argument("--split", choices=("val", "test"), default="val")
    ap.add_argument("--data")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--keep", type=Path, help="keep each mix here (FOLDER/mix-SHARE)")
    args = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for share in args.mix:
            stem = (args.keep or Path(tmp)) / f"mix-{share:g}"
            ckpt.save_tensors(stem, *mixed(args.start, args.fine_tune, share))
            rows[f"{share:g}"] = measured(stem, args.data, args.split)
    print(table(rows))
    if args.json:
        record = {"start": args.start, "fine_tune": Path(args.fine_tune).name, "split": args.split, "mixes": rows}
        atomic_write_text(args.json, json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
