"""The ONNX step graphs side by side in one run, in onnxruntime: the plain-op graph of the
first export (10171e4, taken from git), the graphs of the commit before this round's changes
(``--before``, both forms), and the graphs now, each with every style's branch and with one
style's; next to the numpy and numba backends' network step.

Batch 1 (1 thread), each graph called in turn with its counterpart before (two graphs at a
time, call by call, so both meet the same machine): step latency
p50 / p99 through ``session.run`` with numpy inputs (what a Python host pays) and through
I/O binding with the inputs and outputs bound once (what an engine host pays: bound tensors,
no per-call conversion). 1,000 streams: frames/s, 1 and 2 intra-op threads. Every graph gets a
style target with one style weighted (the usual case). Writes docs/onnx-bench.json.

    python benchmarks/bench_onnx.py [--before COMMIT]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from styleerd.model.stored import load_generator_weights
from styleerd.runtime.backends import make_backend
from styleerd.runtime.onnx_export import step_graph

FIRST = "10171e4"  # the last commit whose export was the plain-op graph only (opset 17)
BEFORE = "bc2080d"  # the LSTM-op export as it stood before the batched graphs


def graph_at(commit: str, model, *args) -> bytes | None:
    """The step graph as the code at ``commit`` exported it (``args``: form, styles); None,
    said, when that code cannot read today's model (its weights' layout has moved on since)."""
    source = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{commit}:styleerd/runtime/onnx_export.py"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    module = types.ModuleType("onnx_export_before")
    exec(compile(source, f"{commit}:onnx_export.py", "exec"), module.__dict__)  # noqa: S102  this repository's own code
    try:
        return module.step_graph(model, *args).SerializeToString()
    except Exception as e:  # noqa: BLE001  old code on today's weights: leave that graph out, say why
        print(
            f"left out: the export at {commit} {args or ''} cannot read today's model ({type(e).__name__}: {e})",
            flush=True,
        )
        return None


def feeds(session: ort.InferenceSession, model, n: int) -> dict:
    """Zeros for every input of the graph (its own names and shapes, N = n), labels one-hot:
    input neutral, content walk, target the first style branch."""
    c = model.config
    out = {}
    for i in session.get_inputs():
        shape = [n if not isinstance(d, int) else d for d in i.shape]
        out[i.name] = np.zeros(shape, np.float32)
    out["style"][:, c.neutral_index] = 1.0
    out["content"][:, c.contents.index("walk") if "walk" in c.contents else 0] = 1.0
    out["target"][:, c.branch_styles[0]] = 1.0
    return out


def latencies(steps: dict, n: int = 2000, warm: int = 200) -> dict:
    """p50 / p99 (us) of a few steps called in turn, call by call, so the machine's drift hits
    them alike (a shared machine's speed wanders 2x within minutes)."""
    for step in steps.values():
        for _ in range(warm):
            step()
    times: dict = {name: [] for name in steps}
    for _ in range(n):
        for name, step in steps.items():
            t0 = time.perf_counter()
            step()
            times[name].append(time.perf_counter() - t0)
    return {
        name: {
            "p50_us": round(float(np.percentile(us, 50)) * 1e6, 1),
            "p99_us": round(float(np.percentile(us, 99)) * 1e6, 1),
        }
        for name, us in times.items()
    }


def bound(session: ort.InferenceSession, feeds: dict):
    """A step through I/O binding, inputs and outputs bound once."""
    binding = session.io_binding()
    for name, value in feeds.items():
        binding.bind_ortvalue_input(name, ort.OrtValue.ortvalue_from_numpy(value))
    for o in session.get_outputs():
        binding.bind_output(o.name)
    session.run_with_iobinding(binding)
    return lambda: session.run_with_iobinding(binding)


def rate(step, n_streams: int, seconds: float = 2.0) -> float:
    step()
    frames, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        step()
        frames += n_streams
    return round(frames / (time.perf_counter() - t0))


def session(graph: bytes, threads: int) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads, options.inter_op_num_threads = threads, 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(graph, options, providers=["CPUExecutionProvider"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default=BEFORE)
    args = parser.parse_args()
    model = load_generator_weights()
    c = model.config
    one = (c.styles[c.branch_styles[0]],)
    graphs = {f"plain, first export ({FIRST}, opset 17)": graph_at(FIRST, model)}
    for when in (f"before ({args.before})", "now"):
        for form, label in (("lstm", "LSTM op"), ("plain", "plain")):
            for styles, which in ((None, "all styles"), (one, f"one style ({one[0]})")):
                graphs[f"{label}, {which}, {when}"] = (
                    graph_at(args.before, model, form, styles)
                    if when != "now"
                    else step_graph(model, form, styles).SerializeToString()
                )
    graphs = {name: graph for name, graph in graphs.items() if graph is not None}
    report: dict = {"graphs": {}, "backends": {}}
    steps = {}
    for name, graph in graphs.items():
        s1 = session(graph, 1)
        f1, f1000 = feeds(s1, model, 1), feeds(s1, model, 1000)
        s2 = session(graph, 2)
        steps[(name, "run")] = lambda s1=s1, f1=f1: s1.run(None, f1)
        steps[(name, "bound")] = bound(s1, f1)
        report["graphs"][name] = {
            "nodes": len(onnx.load_from_string(graph).graph.node),
            "frames_per_s_1000_streams_1_thread": rate(lambda s1=s1, f1000=f1000: s1.run(None, f1000), 1000),
            "frames_per_s_1000_streams_2_threads": rate(lambda s2=s2, f1000=f1000: s2.run(None, f1000), 1000),
        }
        print(name, report["graphs"][name], flush=True)
    labels = lambda n: (
        np.eye(len(c.styles), dtype=np.float32)[[c.neutral_index] * n],
        np.eye(len(c.contents), dtype=np.float32)[[0] * n],
        np.eye(len(c.styles), dtype=np.float32)[[c.branch_styles[0]] * n],
    )
    x1, x1000 = (np.zeros((n, c.feature_dim), np.float32) for n in (1, 1000))
    with threadpool_limits(1):
        for name in ("numpy", "numba"):
            b1, b1000 = make_backend(name, model, 1), make_backend(name, model, 1000)
            steps[(name, "backend")] = lambda b1=b1: b1.step(x1, *labels(1))
            report["backends"][name] = {
                "frames_per_s_1000_streams_1_thread": rate(lambda b1000=b1000: b1000.step(x1000, *labels(1000)), 1000)
            }
        timed = {}
        for how in ("run", "bound"):
            for kind in (
                "LSTM op, all styles",
                f"LSTM op, one style ({one[0]})",
                "plain, all styles",
                f"plain, one style ({one[0]})",
            ):
                timed.update(latencies({k: steps[k] for k in steps if k[1] == how and k[0].startswith(kind)}))
            timed.update(latencies({k: steps[k] for k in steps if k[1] == how and k[0].startswith("plain, first")}))
        timed.update(latencies({k: steps[k] for k in steps if k[1] == "backend"}))
    for (name, how), t in timed.items():
        (report["graphs"] if how != "backend" else report["backends"])[name][f"batch_1_{how}"] = t
    out = ROOT / "docs" / "onnx-bench.json"
    out.write_text(json.dumps(report, indent=1) + "\n")
    print(
        f"\n| graph (onnxruntime {ort.__version__}) | nodes | batch 1 p50 / p99 (us, 1 thread): session.run | I/O "
        "binding | 1,000 streams, frames/s (1 thread / 2 threads) |\n| --- | --- | --- | --- | --- |"
    )
    for name, r in report["graphs"].items():
        print(
            f"| {name} | {r['nodes']} | {r['batch_1_run']['p50_us']:.0f} / {r['batch_1_run']['p99_us']:.0f} | "
            f"{r['batch_1_bound']['p50_us']:.0f} / {r['batch_1_bound']['p99_us']:.0f} "
            f"| {r['frames_per_s_1000_streams_1_thread']:,} / {r['frames_per_s_1000_streams_2_threads']:,} |"
        )
    for name, r in report["backends"].items():
        print(
            f"| {name} backend (network step) | | {r['batch_1_backend']['p50_us']:.0f} / "
            f"{r['batch_1_backend']['p99_us']:.0f} | | {r['frames_per_s_1000_streams_1_thread']:,} / |"
        )
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
