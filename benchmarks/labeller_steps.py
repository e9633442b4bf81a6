"""The labeller's step, numpy (``NumpyLabeller``: the numpy and onnx backends') against compiled
(``CompiledLabeller._compiled``, one numba call), by number of streams, on one BLAS thread as the
numba backend runs it from ``LABELLER_ONE_BLAS_FROM`` streams: where ``COMPILED_LABELLER_BELOW``
comes from.

    python benchmarks/labeller_steps.py [--streams 1 4 8 12 16 32 64 1000] [--rounds 5]

Prints us a step (the best of the rounds) per number of streams.
"""

from __future__ import annotations

import argparse
import timeit
from functools import partial

import numpy as np

from styleerd.model.stored import load_labeller_weights
from styleerd.runtime.compiled import COMPILED_LABELLER_BELOW, CompiledLabeller
from styleerd.runtime.numpy_step import NumpyLabeller, one_blas_thread
from styleerd.runtime.system import cpu_model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--streams", type=int, nargs="+", default=[1, 4, 8, 12, 16, 32, 64, 1000])
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    labeller = load_labeller_weights()
    print(f"{cpu_model()}: the labeller's step, us (best of {args.rounds}); compiled below {COMPILED_LABELLER_BELOW}")
    print("| streams | numpy | compiled |\n| --- | --- | --- |")
    for n in args.streams:
        x = np.random.default_rng(0).normal(0, 1, (n, labeller.config["in_dim"])).astype(np.float32)
        numpy, compiled = NumpyLabeller(labeller, n), CompiledLabeller(labeller, n)
        compiled._compiled(x, None)  # compiled before it is timed
        calls = max(20, 2000 // n)
        with one_blas_thread():
            us = [
                min(timeit.repeat(partial(f, x, None), number=calls, repeat=args.rounds)) / calls * 1e6
                for f in (numpy.step, compiled._compiled)
            ]
        print(f"| {n} | {us[0]:.1f} | {us[1]:.1f} |", flush=True)


if __name__ == "__main__":
    main()
