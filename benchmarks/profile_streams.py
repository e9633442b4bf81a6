"""Where a step of many streams spends its time: StreamStylizer (numba backend) stepping 1,000
streams on 2 threads, each compiled kernel call timed from Python (the features, the network,
the root put back on its heading) and the rest (the stylizer's Python, the backend's arrays,
the BLAS limit), in microseconds per step, over several rounds.

    python benchmarks/profile_streams.py [--streams 1000] [--threads 2] [--steps 400] [--rounds 3] [--json
    docs/stream-profile.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--streams", type=int, default=1000)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--json", help="write the rounds here too")
    args = p.parse_args()

    from styleerd.data import features
    from styleerd.eval.bench import _model_walk, flops_per_frame, matmul_peak
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime import compiled, stylizer

    model = load_generator_weights()
    walk = _model_walk(model, 4.0)
    N = args.streams
    rot, pos = np.repeat(walk.rotations[:, None], N, 1), np.repeat(walk.positions[:, None], N, 1)
    st = stylizer.StreamStylizer(
        model, "normal", "walk", {"elderly": 1.0}, n_streams=N, backend="numba", threads=args.threads
    )
    spent: dict[str, float] = {}

    def timed(module, name: str, label: str) -> None:
        kernel = getattr(module, name)

        def call(*a):
            t0 = time.perf_counter()
            kernel(*a)
            spent[label] = spent.get(label, 0.0) + time.perf_counter() - t0

        setattr(module, name, call)

    step = lambda t: st.step(rot[t % walk.n_frames], pos[t % walk.n_frames])
    for t in range(100):
        step(t)
    # wrapped once compiled (a kernel compiled later would find a Python function among its
    # callees); the serial kernels too: below data.parallel.PARALLEL_FROM streams, or on one thread
    for module, name, label in (
        (features, "_stream_features_on_shards", "features"),
        (features, "_stream_features_kernel", "features"),
        (compiled, "compiled_step_on_shards", "network"),
        (compiled, "compiled_step", "network"),
        (compiled, "compiled_pair_step_on_shards", "network"),  # the default pose: the target's and the identity's
        (compiled, "compiled_pair_step", "network"),
        (stylizer, "_root_on_heading_on_shards", "root_on_heading"),
        (stylizer, "_root_on_heading", "root_on_heading"),
    ):
        timed(module, name, label)
    peak = matmul_peak(args.threads)
    print(f"{N:,} streams, {args.threads} threads; matmul peak {peak / 1e9:.1f} GFLOP/s")
    rounds = []
    print(
        "| round | step (us) | features | network | root on heading | the rest | frames/s | fraction of peak |\n| --- "
        "| --- | --- | --- | --- | --- | --- | --- |"
    )
    for r in range(args.rounds):
        spent.clear()
        t0 = time.perf_counter()
        for t in range(args.steps):
            step(t)
        total = (time.perf_counter() - t0) / args.steps * 1e6
        parts = {k: v / args.steps * 1e6 for k, v in spent.items()}
        rest = total - sum(parts.values())
        fps = N / total * 1e6
        cells = " | ".join(
            f"{parts[k]:.0f} ({100 * parts[k] / total:.0f} %)" for k in ("features", "network", "root_on_heading")
        )
        print(
            f"| {r + 1} | {total:.0f} | {cells} | {rest:.0f} ({100 * rest / total:.0f} %) | {fps:,.0f} | "
            f"{fps * flops_per_frame(model) / peak:.3f} |"
        )
        rounds.append(
            {
                "step_us": round(total, 1),
                **{f"{k}_us": round(v, 1) for k, v in parts.items()},
                "rest_us": round(rest, 1),
                "frames_per_s": round(fps),
                "fraction_of_peak": round(fps * flops_per_frame(model) / peak, 4),
            }
        )
    if args.json:
        report = {
            "streams": N,
            "threads": args.threads,
            "steps": args.steps,
            "matmul_peak_gflops": round(peak / 1e9, 1),
            "rounds": rounds,
        }
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
