"""Where an ONNX step's time goes in onnxruntime, per op type: both graph forms (the LSTM-op
graph and the plain one) with every style, and the LSTM-op graph of one style (its layers
fused by depth), at batch 1 and at 1,000 streams, 1 intra-op thread, from
onnxruntime's own profiler (its per-node kernel times, as shares; the step time beside them
is timed without the profiler, whose own cost inflates short kernels). Writes docs/onnx-profile.json and prints a table.

    python benchmarks/onnx_profile.py [--steps 300] [--streams 1 1000] [--out docs/onnx-profile.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import onnxruntime as ort

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from styleerd.atomic import atomic_write_text
from styleerd.model.stored import load_generator_weights
from styleerd.runtime.onnx_export import FORMS, state_shape, step_graph


def feeds(model, form: str, styles: tuple[str, ...] | None, n: int) -> dict[str, np.ndarray]:
    """N streams past their first frame, each sent to one style (the usual case: the graph's
    first style branch)."""
    c = model.config
    rows, _, width = state_shape(model, form, styles)
    eye = lambda k, i: np.eye(k, dtype=np.float32)[np.full(n, i)]
    rng = np.random.default_rng(0)
    return {
        "features": rng.normal(0, 1, (n, c.feature_dim)).astype(np.float32),
        "style": eye(len(c.input_styles), c.neutral_index),
        "content": eye(len(c.contents), 0),
        "target": eye(len(c.styles), c.styles.index(styles[0]) if styles else c.branch_styles[0]),
        "first_frame": np.zeros((n, 1), np.float32),
        "h": rng.normal(0, 0.1, (rows, n, width)).astype(np.float32),
        "c": rng.normal(0, 0.1, (rows, n, width)).astype(np.float32),
    }


def profile(graph: bytes, inputs: dict, steps: int) -> dict:
    """Step time (p50, no profiler) and the profiler's kernel time per op type per step."""
    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = 1, 1
    plain = ort.InferenceSession(graph, options, providers=["CPUExecutionProvider"])
    for _ in range(20):
        plain.run(None, inputs)
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        plain.run(None, inputs)
        times.append(time.perf_counter() - t0)
    with tempfile.TemporaryDirectory() as tmp:
        options.enable_profiling, options.profile_file_prefix = True, str(Path(tmp) / "ort")
        profiled = ort.InferenceSession(graph, options, providers=["CPUExecutionProvider"])
        for _ in range(steps):
            profiled.run(None, inputs)
        events = json.loads(Path(profiled.end_profiling()).read_text())
    per_op, nodes = Counter(), Counter()
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            per_op[e["args"]["op_name"]] += e["dur"]  # microseconds
            nodes[e["args"]["op_name"]] += 1
    runs = steps  # one profiled run per step
    kernels = sum(per_op.values()) / runs
    p50 = float(np.percentile(np.array(times) * 1e6, 50))
    return {
        "step_p50_us": round(p50, 1),
        "kernels_us": round(kernels, 1),
        # the profiler's own cost inflates short kernels: "us" is its time, "of_step_us" the
        # op type's share of the kernel time applied to the unprofiled step time
        "per_op": {
            op: {
                "us": round(t / runs, 1),
                "share": round(t / sum(per_op.values()), 3),
                "of_step_us": round(t / sum(per_op.values()) * p50, 1),
                "nodes": nodes[op] // runs,
            }
            for op, t in per_op.most_common()
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--streams", type=int, nargs="+", default=[1, 1000])
    ap.add_argument("--out", default=str(ROOT / "docs" / "onnx-profile.json"))
    args = ap.parse_args()
    model = load_generator_weights()
    report = {}
    one = (model.config.styles[model.config.branch_styles[0]],)
    for name, form, styles in [*((form, form, None) for form in FORMS), ("lstm one style", "lstm", one)]:
        graph = step_graph(model, form, styles).SerializeToString()
        for n in args.streams:
            r = profile(graph, feeds(model, form, styles, n), args.steps if n == 1 else max(10, args.steps // 10))
            report[f"{name}, {n} streams"] = r
            top = ", ".join(
                f"{op} {100 * v['share']:.0f} % ({v['nodes']} nodes)" for op, v in list(r["per_op"].items())[:5]
            )
            print(
                f"{name:14s} {n:5d} streams: step p50 {r['step_p50_us']:.0f} us; kernel time by op type: {top}",
                flush=True,
            )
    atomic_write_text(Path(args.out), json.dumps(report, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
