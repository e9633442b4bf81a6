"""Where a training step's time goes, and two recipes side by side in one run.

    python benchmarks/bench_train_step.py [--steps 40] [--batch 32] [--threads 2]
        [--before configs/bandai2-content.yaml] [--after configs/bandai2-fast.yaml]

Runs the trainer's own step (``train.trainer.train_step``) of each recipe on real
Bandai-Namco-2 windows and times each of its parts. Steps of the two recipes alternate, so both
see the same machine (its speed drifts by 2x between sessions). Prints the mean time per step of
every part, the step and epoch time of each recipe and their ratio.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from styleerd.atomic import atomic_write_text
from styleerd.model.classifiers import WindowClassifier
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import make_critic, make_generator, setup, train_step

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--batch", type=int, help="the batch size of both recipes (default: each config's own)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--before", default="configs/bandai2-content.yaml")
    ap.add_argument("--after", default="configs/bandai2-fast.yaml")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    batch = {"batch_size": args.batch} if args.batch else {}
    recipes = {name: TrainConfig.from_yaml(getattr(args, name), **batch) for name in ("before", "after")}
    s = setup(recipes["after"], None, progress=False)
    rng = np.random.default_rng(0)
    parts: dict[str, dict[str, float]] = {name: {} for name in recipes}
    runs = {}
    for name, config in recipes.items():  # each recipe its own generator, critic and optimisers
        torch.manual_seed(0)
        G, D = make_generator(config, s), make_critic(config, s)
        C = WindowClassifier(10 * G.config.n_joints, len(s.data.contents), instance_norm=True).requires_grad_(False)
        opts = torch.optim.Adam(G.parameters(), lr=config.lr_g), torch.optim.Adam(D.parameters(), lr=config.lr_d)
        runs[name] = (G, D, *opts, C, config)

    for i in range(args.steps + 3):
        for name, run in runs.items():
            times, clock = parts[name], [time.perf_counter()]

            def tick(part: str) -> None:
                t = time.perf_counter()
                if i >= 3:  # after three warm-up steps
                    times[part] = times.get(part, 0.0) + t - clock[0]
                clock[0] = t

            B = run[-1].batch_size
            rows = rng.choice(len(s.train.starts), B)
            train_step(*run, s, rows, rng.integers(0, len(s.data.styles), B), i, tick)
    print(f"{args.threads} threads, mean of {args.steps} steps, recipes alternating step by step")
    epoch, report = {}, {"threads": args.threads, "steps": args.steps}
    for name, times in parts.items():
        # each part's time per step, averaged over all steps: a part run on some steps only
        # (R1 on every 4th, a lazy cycle) counts with its share
        mean = {k: v / args.steps * 1000 for k, v in times.items()}
        step, B = sum(mean.values()), recipes[name].batch_size
        steps = len(s.train.starts) // B
        epoch[name] = steps * step / 1000
        report[name] = {"config": getattr(args, name), "batch": B, "parts_ms": {k: round(v, 2) for k, v in mean.items()}, "step_ms": round(step, 2),
                        "steps_per_epoch": steps, "epoch_s": round(epoch[name], 3)}  # fmt: skip
        print(f"{name}: {getattr(args, name)} (batch {B})")
        for k, v in mean.items():
            print(f"  {k:38s} {v:7.2f} ms")
        print(f"  {'step':38s} {step:7.2f} ms -> {steps} steps/epoch, {epoch[name]:.1f} s/epoch")
    report["speedup"] = round(epoch["before"] / epoch["after"], 3)
    print(f"after / before epoch time: {epoch['after'] / epoch['before']:.3f} ({report['speedup']:.2f}x the training windows per minute)")
    if args.json:
        atomic_write_text(Path(args.json), json.dumps(report, indent=1) + "\n")

if __name__ == "__main__":
    main()
