"""Where a training step's time goes, and two recipes side by side in one run.

    python benchmarks/bench_train_step.py [--steps 40] [--threads 1] [--batch N]
        [--before configs/bandai2-content.yaml] [--before-code 66b7252]
        [--after configs/bandai2-quick.yaml] [--json docs/train-step.json]

Runs the trainer's own step (``train.trainer.train_step``) of each recipe on real
Bandai-Namco-2 windows and times each of its parts. Each recipe runs in its own process: the
"before" one on the trainer's code at ``--before-code`` (taken from git; default: the working
tree's), the "after" one on the working tree's. The two processes take turns step by step, one
step at a time, so both see the same machine (its speed drifts by 2x between sessions), and
draw the same batches. Prints the mean time per step of every part, the step and epoch time of
each recipe and their ratio; where a recipe's model is kept (``models/recipes/<name>.json``),
also how long its training run takes on this machine now (its epochs times the epoch measured
here; validation left out) and the ratio of the two runs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WARM_UP = 3


def worker(config_path: str, threads: int, batch: int | None) -> None:
    """One recipe's steps, one per line "step" on stdin; "report" prints its parts' times (ms,
    summed over the measured steps) as JSON and ends."""
    import numpy as np
    import torch

    import styleerd
    from styleerd.model.classifiers import WindowClassifier
    from styleerd.train import trainer
    from styleerd.train.config import TrainConfig

    torch.set_num_threads(threads)
    config = TrainConfig.from_yaml(config_path, **({"batch_size": batch} if batch else {}))
    s = trainer.setup(config, None, progress=False)
    torch.manual_seed(0)
    G, D = trainer.make_generator(config, s), trainer.make_critic(config, s)
    C = WindowClassifier(10 * G.config.n_joints, len(s.data.contents), instance_norm=True).requires_grad_(False)
    if hasattr(trainer, "make_optimisers"):
        opts = trainer.make_optimisers(config, G, D)
    else:  # the trainer's optimisers before make_optimisers
        opts = (
            torch.optim.Adam([p for p in G.parameters() if p.requires_grad], lr=config.lr_g, betas=(0.5, 0.999)),
            torch.optim.Adam(D.parameters(), lr=config.lr_d, betas=(0.5, 0.999)),
        )
    rng = np.random.default_rng(0)  # the same batches in both processes
    times: dict[str, float] = {}
    print(
        json.dumps(
            {
                "code": str(Path(styleerd.__file__).parent),
                "name": config.name,
                "batch": config.batch_size,
                "windows": len(s.train.starts),
            }
        ),
        flush=True,
    )

    def timer(step: int):
        """A tick that adds the time since the last tick to ``part``, after the warm-up steps."""
        clock = [time.perf_counter()]

        def tick(part: str) -> None:
            t = time.perf_counter()
            if step >= WARM_UP:
                times[part] = times.get(part, 0.0) + (t - clock[0]) * 1000
            clock[0] = t

        return tick

    for i, line in enumerate(sys.stdin):
        if line.strip() == "report":
            print(json.dumps(times), flush=True)
            return
        B = config.batch_size
        rows = rng.choice(len(s.train.starts), B)
        trainer.train_step(G, D, *opts, C, config, s, rows, rng.integers(0, len(s.data.styles), B), i, timer(i))
        print("done", flush=True)


def code_at(commit: str, into: Path) -> Path:
    """The package ``styleerd`` as it was at ``commit``, unpacked under ``into``."""
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", commit, "styleerd"], capture_output=True, check=True
    ).stdout
    with tarfile.open(fileobj=__import__("io").BytesIO(archive)) as tar:
        tar.extractall(into, filter="data")
    return into


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--batch", type=int, help="the batch size of both recipes (default: each config's own)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--before", default="configs/bandai2-content.yaml")
    ap.add_argument(
        "--before-code", help="the git commit whose trainer runs the before recipe (default: the working tree's)"
    )
    ap.add_argument("--after", default="configs/bandai2-quick.yaml")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args.worker, args.threads, args.batch)

    with tempfile.TemporaryDirectory() as tmp:
        procs, info = {}, {}
        for name in ("before", "after"):
            env = dict(os.environ)
            if name == "before" and args.before_code:
                env["PYTHONPATH"] = str(code_at(args.before_code, Path(tmp)))
            cmd = [sys.executable, __file__, "--worker", getattr(args, name), "--threads", str(args.threads)] + (
                ["--batch", str(args.batch)] if args.batch else []
            )
            procs[name] = subprocess.Popen(
                cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT
            )
            info[name] = json.loads(procs[name].stdout.readline() or "null") or sys.exit(
                f"the {name} recipe's process failed"
            )
        expected = {
            "before": Path(tmp) / "styleerd" if args.before_code else ROOT / "styleerd",
            "after": ROOT / "styleerd",
        }
        for name, p in procs.items():
            if Path(info[name]["code"]).resolve() != expected[name].resolve():
                sys.exit(f"the {name} recipe ran the trainer at {info[name]['code']}, not {expected[name]}")
        for _ in range(args.steps + WARM_UP):
            for name, p in procs.items():  # turn by turn: one step of one recipe at a time
                p.stdin.write("step\n")
                p.stdin.flush()
                if p.stdout.readline().strip() != "done":
                    sys.exit(f"the {name} recipe's process failed")
        parts = {}
        for name, p in procs.items():
            p.stdin.write("report\n")
            p.stdin.flush()
            parts[name] = json.loads(p.stdout.readline())
            p.wait()

    code = {"before": args.before_code or "working tree", "after": "working tree"}
    print(f"{args.threads} threads, mean of {args.steps} steps, recipes alternating step by step")
    epoch, report = {}, {"threads": args.threads, "steps": args.steps}
    for name, times in parts.items():
        # each part's time per step, averaged over all steps: a part run on some steps only
        # (R1 on every 4th, a lazy cycle) counts with its share
        mean = {k: v / args.steps for k, v in times.items()}
        step, B = sum(mean.values()), info[name]["batch"]
        steps = info[name]["windows"] // B
        epoch[name] = steps * step / 1000
        report[name] = {
            "config": getattr(args, name),
            "code": code[name],
            "batch": B,
            "parts_ms": {k: round(v, 2) for k, v in mean.items()},
            "step_ms": round(step, 2),
            "steps_per_epoch": steps,
            "epoch_s": round(epoch[name], 3),
        }
        print(f"{name}: {getattr(args, name)} on the trainer of {code[name]} (batch {B})")
        for k, v in mean.items():
            print(f"  {k:38s} {v:7.2f} ms")
        print(f"  {'step':38s} {step:7.2f} ms -> {steps} steps/epoch, {epoch[name]:.1f} s/epoch")
        kept = ROOT / "models" / "recipes" / f"{info[name]['name']}.json"
        if kept.is_file():
            epochs = json.loads(kept.read_text())["training"]["epochs_trained"]
            report[name] |= {
                "model": str(kept.relative_to(ROOT).with_suffix("")),
                "epochs_trained": epochs,
                "training_min": round(epochs * epoch[name] / 60, 2),
            }
            print(
                f"  its kept model {report[name]['model']}: {epochs} epochs -> {report[name]['training_min']:.1f} min "
                "of training steps here"
            )
    report["speedup"] = round(epoch["before"] / epoch["after"], 3)
    print(
        f"after / before epoch time: {epoch['after'] / epoch['before']:.3f} ({report['speedup']:.2f}x the training "
        "windows per minute)"
    )
    if "training_min" in report["before"] and "training_min" in report["after"]:
        report["training_ratio"] = round(report["after"]["training_min"] / report["before"]["training_min"], 3)
        print(f"after / before training run: {report['training_ratio']:.3f}")
    if args.json:
        sys.path.insert(0, str(ROOT))
        from styleerd.atomic import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
