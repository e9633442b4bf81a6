"""What a server's batch costs when its streams are not consecutive rows: the stylizer (numba, labels
inferred, the default pose, 2 threads) stepping 97 of 200 streams chosen at random (rows by index:
each per-stream state gathered before the step and written back after it) against 97 consecutive
streams (a slice: the state stepped in place, as views), in alternating rounds, median us a frame.
A server with 200 clients at 30 fps steps batches of about this size whose rows are scattered.

    python benchmarks/batch_rows.py [--rounds 7]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--streams", type=int, default=200)
    p.add_argument("--batch", type=int, default=97)
    args = p.parse_args()

    from styleerd.model.stored import load_generator_weights, load_labeller_weights
    from styleerd.motion import bvh
    from styleerd.motion.procedural import walk
    from styleerd.runtime.channels import ChannelStylizer

    source = walk(seconds=20, fps=30.0)
    values = bvh.channel_values(source)
    stylizer = ChannelStylizer(
        load_generator_weights(),
        source.skeleton,
        {"elderly": 1.0},
        fps=30.0,
        n_streams=args.streams,
        backend="numba",
        labeller=load_labeller_weights(),
        threads=2,
    )
    scattered = np.sort(np.random.default_rng(0).choice(args.streams, args.batch, replace=False))
    batches = {"rows by index": scattered, "consecutive rows": np.arange(args.batch)}

    def step(rows: np.ndarray, t: int) -> None:
        stylizer.step(np.repeat(values[t % len(values)][None], len(rows), 0), rows)

    for t in range(30):  # compiled, calibrated and past every stream's first frame
        for rows in batches.values():
            step(rows, t)
    us: dict = {k: [] for k in batches}
    for _ in range(args.rounds):
        for k, rows in batches.items():
            t0, n = time.perf_counter(), 0
            while time.perf_counter() - t0 < 0.3:
                step(rows, n)
                n += 1
            us[k].append((time.perf_counter() - t0) / n / len(rows) * 1e6)
    for k, v in us.items():
        print(f"{k}: {np.median(v):.2f} us a frame ({args.batch} of {args.streams} streams, median of {args.rounds})")


if __name__ == "__main__":
    main()
