"""Training's epoch time on this machine's cores: one process against data-parallel processes,
side by side in one run.

    python benchmarks/bench_train_parallel.py [--config configs/bandai2-critic-rot.yaml]
        [--clips 400] [--rounds 2] [--json docs/train-parallel.json]

Trains the config (from scratch, 3 epochs on its first ``--clips`` training clips) with the
real trainer (``styleerd train``) in three forms, taking turns round by round so all see the
same machine:

- one process, 1 thread, batch B (how the shipped recipe trains);
- one process, 2 threads, batch B;
- ``torchrun``: 2 processes of 1 thread, batch B / 2 each: the same global batch, the same
  steps per epoch and the same gradient per step (averaged over the processes).

Each form's time is the mean training time of epochs 2 and 3 from its ``metrics.csv`` (the
first pays for start-up), as training windows per minute; the ratios are to the first form.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from styleerd.atomic import atomic_write_text

FORMS = {  # name -> (processes, threads each)
    "1 process x 1 thread": (1, 1),
    "1 process x 2 threads": (1, 2),
    "2 processes x 1 thread (torchrun)": (2, 1),
}


def epoch_seconds(config: dict, processes: int, threads: int, work: Path, data: str | None) -> tuple[float, int]:
    """The training seconds of an epoch after the first of ``config`` trained in this form, and
    its steps."""
    batch = config["batch_size"] // processes
    path = work / "config.yaml"
    path.write_text(yaml.safe_dump({**config, "batch_size": batch, "threads": threads}))
    out = work / "run"
    cli = ["-m", "styleerd.cli", "train", "--config", str(path), "--out", str(out)] + (["--data", data] if data else [])
    if processes > 1:
        cli = ["-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(processes)] + cli
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    p = subprocess.run([sys.executable, *cli], capture_output=True, text=True, env=env, check=False)
    if p.returncode != 0:
        err = p.stderr if len(p.stderr) <= 4000 else f"{p.stderr[:2000]}\n...\n{p.stderr[-2000:]}"
        raise SystemExit(f"training failed ({processes} x {threads}):\n{p.stdout[-2000:]}{err}")
    rows = list(csv.DictReader((out / "metrics.csv").read_text().splitlines()))
    later = len(rows) - 1
    return 60 * (float(rows[-1]["minutes"]) - float(rows[0]["minutes"])) / later, (
        int(rows[-1]["steps"]) - int(rows[0]["steps"])
    ) // later


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/bandai2-critic-rot.yaml")
    ap.add_argument("--clips", type=int, default=400, help="training clips (the epoch's length, not the recipe)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--data", help="data folder")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    recipe = yaml.safe_load(Path(args.config).read_text())
    # the recipe's step, from scratch on fewer clips; the classifier the perceptual loss needs is
    # trained for one epoch only (its time is not in the epoch's)
    config = {
        **recipe,
        "init_from": "",
        "epochs": 3,
        "max_minutes": 0,
        "max_train_clips": args.clips,
        "val_every": 1000,
        "val_windows": 64,
        "classifier_epochs": 1,
    }
    times: dict[str, list[float]] = {name: [] for name in FORMS}
    steps = {}
    for r in range(args.rounds):
        for name, (processes, threads) in FORMS.items():
            with tempfile.TemporaryDirectory() as work:
                seconds, steps[name] = epoch_seconds(config, processes, threads, Path(work), args.data)
            times[name].append(seconds)
            print(f"round {r + 1}: {name}: {seconds:.2f} s for {steps[name]} steps", flush=True)
    batch = config["batch_size"]
    base = float(np.median(times[next(iter(FORMS))]))
    report = {"config": args.config, "clips": args.clips, "rounds": args.rounds, "global_batch": batch, "forms": {}}
    print(f"{args.config}, global batch {batch}, the median of {args.rounds} rounds:")
    for name, ts in times.items():
        seconds = float(np.median(ts))
        windows = steps[name] * batch
        report["forms"][name] = {
            "epoch_s": round(seconds, 3),
            "steps": steps[name],
            "windows_per_minute": round(60 * windows / seconds),
            "speedup": round(base / seconds, 3),
        }
        print(f"  {name:36s} {seconds:7.2f} s/epoch  {60 * windows / seconds:8.0f} windows/min  {base / seconds:.2f}x")
    if args.json:
        atomic_write_text(Path(args.json), json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
