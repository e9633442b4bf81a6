"""What the default pose costs: ``pose="input"`` (a second network pass, the identity transfer,
and the blend) against ``pose="network"`` (one pass, the paper's output), side by side in one
process, in alternating rounds: end to end at batch 1 (raw BVH channels of a 22-joint skeleton in
and out: retargeting, features, network, foot cleanup) and 1,000 streams on 2 threads (numba).

    python benchmarks/bench_pose.py [--rounds 3] [--json docs/pose-bench.json]
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import numpy as np

from styleerd.atomic import atomic_write_text
from styleerd.eval.bench import end_to_end, set_threads, throughput
from styleerd.model.stored import load_generator_weights


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    model = load_generator_weights()
    rows: dict[str, dict[str, list[float]]] = {
        pose: {"end_to_end_p50_us": [], "frames_per_s_1000_streams": []} for pose in ("network", "input")
    }
    for _ in range(args.rounds):
        for pose in rows:
            set_threads(1)
            rows[pose]["end_to_end_p50_us"].append(end_to_end(model, "numba", args.steps, pose=pose)["p50_us"])
            set_threads(2)
            rows[pose]["frames_per_s_1000_streams"].append(throughput(model, "numba", 1000, seconds=1.0, pose=pose))
    cpu = next(
        (
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        ),
        platform.processor(),
    )
    out = {
        "cpu": cpu,
        "rounds": args.rounds,
        "median": {p: {k: round(float(np.median(v)), 1) for k, v in r.items()} for p, r in rows.items()},
        "runs": rows,
    }
    for k in ("end_to_end_p50_us", "frames_per_s_1000_streams"):
        a, b = out["median"]["network"][k], out["median"]["input"][k]
        print(f"{k}: pose network {a:,.1f}, pose input {b:,.1f} ({b / a:.2f}x)")
    if args.json:
        atomic_write_text(args.json, json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
