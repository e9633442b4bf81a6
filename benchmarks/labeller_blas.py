"""The numba backend with the labeller (the input's style inferred, as for users' streams):
its numpy products held to one BLAS thread from ``stylizer.LABELLER_ONE_BLAS_FROM`` streams,
against the same step without that limit, in alternating rounds in one process.

    python benchmarks/labeller_blas.py [--streams 1 32 100 1000] [--rounds 5]

Prints us a frame (the best of the rounds) per number of streams, and the ratio.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from styleerd.model.stored import load_generator_weights
from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.runtime import stylizer
from styleerd.runtime.channels import ChannelStylizer
from styleerd.runtime.system import cpu_model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--streams", type=int, nargs="+", default=[1, 32, 100, 1000])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    m = walk(10.0, fps=30.0)
    values, model, threshold = bvh.channel_values(m), load_generator_weights(), stylizer.LABELLER_ONE_BLAS_FROM
    print(f"{cpu_model()}: the numba backend with the labeller, us a frame (best of {args.rounds} alternating rounds)")
    print("| streams | one BLAS thread for the labeller | BLAS's own threads | ratio |\n| --- | --- | --- | --- |")
    for n in args.streams:
        st = ChannelStylizer(model, m.skeleton, {"elderly": 1.0}, fps=30.0, n_streams=n, backend="numba")
        frames = values[(np.arange(300)[:, None] + 7 * np.arange(n)) % len(values)]  # [300, n, channels]
        steps = max(10, 300 // n)
        for i in range(10):
            st.step(frames[i])
        best = {"limit": np.inf, "none": np.inf}
        for _ in range(args.rounds):
            for arm, limit_from in (("limit", threshold), ("none", 1 << 30)):
                stylizer.LABELLER_ONE_BLAS_FROM = limit_from
                t0 = time.perf_counter()
                for i in range(steps):
                    st.step(frames[i])
                best[arm] = min(best[arm], (time.perf_counter() - t0) / steps / n * 1e6)
        stylizer.LABELLER_ONE_BLAS_FROM = threshold
        print(f"| {n} | {best['limit']:.1f} | {best['none']:.1f} | {best['none'] / best['limit']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
