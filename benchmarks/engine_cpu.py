"""Why the numba step reaches a different fraction of the matmul peak on different CPUs: its
parts measured on this machine, each the best of alternating rounds.

1. The step's matrix products alone (the same sgemm calls and shapes: ``compiled.products``) on one
   thread over 512 streams, by the block of streams each call takes: sgemm's cost per call against
   the cache a small block saves.
2. The whole network step on the same streams and blocks: the products' share, and the rest: the
   LSTM cells' activations (``compiled._cells``, timed alone on the same streams and layers) and
   the copies between layers.
3. Two threads over 1,024 streams: the step's shards in numba's OpenMP region, against the same
   shards on two Python threads (the compiled step releases the GIL), BLAS held to one thread in
   both; and the products alone on two Python threads against one (does a thread lose speed when
   the other core works too?).

    python benchmarks/engine_cpu.py [--rounds 3] [--json docs/engine-cpu-<cpu>.json]
"""

from __future__ import annotations

import argparse
import json
import re
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BLOCKS = (8, 16, 32, 64, 128, 256, 512)


def best_seconds(run, rounds: int, least_s: float = 0.05) -> float:
    """The best time of one call of ``run`` over ``rounds`` windows of at least ``least_s``."""
    run()
    best = float("inf")
    for _ in range(rounds):
        calls, t0 = 0, time.perf_counter()
        while calls < 3 or time.perf_counter() - t0 < least_s:
            run()
            calls += 1
        best = min(best, (time.perf_counter() - t0) / calls)
    return best


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--json", type=Path)
    args = p.parse_args()

    from threadpoolctl import threadpool_limits

    from styleerd.eval.bench import flops_per_frame, matmul_peak, step_products
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime import compiled
    from styleerd.runtime.calibration import EngineSettings, StepChoice
    from styleerd.runtime.compiled import CompiledBackend
    from styleerd.runtime.system import cpu_model

    model = load_generator_weights()
    c, flops = model.config, flops_per_frame(model)
    P, calls = step_products(model)
    rng = np.random.default_rng(0)

    def inputs(n: int) -> tuple:
        one_hot = lambda k, i: np.eye(k, dtype=np.float32)[np.full(n, i)]
        return (
            rng.normal(0, 1, (n, c.feature_dim)).astype(np.float32),
            one_hot(len(c.input_styles), c.neutral_index),
            one_hot(len(c.contents), 0),
            one_hot(len(c.styles), c.styles.index("elderly")),
        )

    def network(n: int, choice: StepChoice) -> CompiledBackend:
        return CompiledBackend(model, n, choice.threads, EngineSettings((1,), (choice,), (choice,), "benchmark"))

    peaks = {t: matmul_peak(t) for t in (1, 2)}
    report: dict = {"cpu": cpu_model(), "matmul_peak_gflops": {t: round(v / 1e9, 1) for t, v in peaks.items()}}
    print(
        f"CPU: {report['cpu']}; matmul peak {report['matmul_peak_gflops'][1]} GFLOP/s on 1 thread, "
        f"{report['matmul_peak_gflops'][2]} on 2"
    )

    n = 512
    buffer = rng.normal(0, 1, 2 * n * int(calls[:, 1:].max())).astype(np.float32)
    x = inputs(n)
    rows = []
    layers = c.neutral_layers + c.style_layers
    H = c.hidden
    gates, bias = rng.normal(0, 1, (n, 4 * H)).astype(np.float32), np.zeros(4 * H, np.float32)
    hs, cs = np.zeros((n, layers * H), np.float32), np.zeros((n, layers * H), np.float32)

    def cells() -> None:  # the state laid out as the step's: one row a stream, a layer's columns
        for i in range(layers):
            compiled._cells(gates, bias, hs, cs, i * H, H)

    with threadpool_limits(1):
        cells_us = round(best_seconds(cells, args.rounds) * 1e6, 1)
        for b in BLOCKS:
            products = best_seconds(lambda b=b: compiled.products(P, calls, n, buffer, b), args.rounds)
            step = network(n, StepChoice(b, False, 1))
            whole = best_seconds(lambda step=step: step.step(*x), args.rounds)
            rows.append(
                {
                    "block_rows": b,
                    "products_us": round(products * 1e6, 1),
                    "products_fraction_of_peak": round(n * flops / products / peaks[1], 4),
                    "network_us": round(whole * 1e6, 1),
                    "network_fraction_of_peak": round(n * flops / whole / peaks[1], 4),
                    "rest_us": round((whole - products) * 1e6, 1),
                }
            )
    report["one_thread_512_streams"] = rows
    report["cells_alone_512_streams_us"] = cells_us
    print(
        f"\n{n} streams, 1 thread, by block (us a step; fraction of the 1-thread peak); "
        f"the cells alone ({layers} layers): {cells_us:.0f} us\n"
        "| block | products alone | network | the rest (cells, copies) |\n| --- | --- | --- | --- |"
    )
    for r in rows:
        print(
            f"| {r['block_rows']} | {r['products_us']:.0f} ({100 * r['products_fraction_of_peak']:.1f} %) | "
            f"{r['network_us']:.0f} ({100 * r['network_fraction_of_peak']:.1f} %) | {r['rest_us']:.0f} |"
        )

    n = 1024
    x = inputs(n)
    halves = [slice(0, n // 2), slice(n // 2, n)]
    buffers = [rng.normal(0, 1, len(buffer)).astype(np.float32) for _ in halves]  # one per thread, as shards
    alone = {r["block_rows"]: r["products_us"] for r in report["one_thread_512_streams"]}
    rows = []
    for b in (32, 64, 256, 512):
        in_openmp = network(n, StepChoice(b, False, 2))
        openmp = best_seconds(lambda s=in_openmp: s.step(*x), args.rounds)
        on_pool = network(n, StepChoice(b, False, 1))
        with ThreadPoolExecutor(2) as pool, threadpool_limits(1):
            shard = lambda s, st=on_pool: st.step(*(a[s] for a in x), s)
            pooled = best_seconds(lambda shard=shard: list(pool.map(shard, halves)), args.rounds)
            half = lambda buf, b=b: compiled.products(P, calls, n // 2, buf, b)
            both = best_seconds(lambda half=half: list(pool.map(half, buffers)), args.rounds)
        rows.append(
            {
                "block_rows": b,
                "openmp_us": round(openmp * 1e6, 1),
                "openmp_fraction_of_peak": round(n * flops / openmp / peaks[2], 4),
                "python_threads_us": round(pooled * 1e6, 1),
                "python_threads_fraction_of_peak": round(n * flops / pooled / peaks[2], 4),
                "products_two_threads_us": round(both * 1e6, 1),
                "products_two_threads_fraction_of_peak": round(n * flops / both / peaks[2], 4),
                "products_two_threads_against_one": round(alone[b] / (both * 1e6), 3),
            }
        )
    report["two_threads_1024_streams"] = rows
    print(
        f"\n{n} streams, 2 threads, network (us a step; fraction of the 2-thread peak)\n"
        "| block | numba's OpenMP region | two Python threads | the products alone, two Python threads "
        "(a thread's speed against one thread alone) |\n| --- | --- | --- | --- |"
    )
    for r in rows:
        print(
            f"| {r['block_rows']} | {r['openmp_us']:.0f} ({100 * r['openmp_fraction_of_peak']:.1f} %) | "
            f"{r['python_threads_us']:.0f} ({100 * r['python_threads_fraction_of_peak']:.1f} %) | "
            f"{r['products_two_threads_us']:.0f} ({100 * r['products_two_threads_fraction_of_peak']:.1f} %; "
            f"{r['products_two_threads_against_one']:.2f}x) |"
        )
    path = (
        args.json or ROOT / "docs" / f"engine-cpu-{re.sub(r'[^a-z0-9]+', '-', report['cpu'].lower()).strip('-')}.json"
    )
    path.write_text(json.dumps(report, indent=1) + "\n")
    print(f"\nwrote {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}")


if __name__ == "__main__":
    main()
