"""Runtime speed of the shipped model, per backend, measured side by side in one run.

    python benchmarks/bench_runtime.py [--steps 2000] [--json out/bench_runtime.json]

1. network step latency at batch 1, 1 thread (p50 / p99): the network alone, normalised
   features in, rotations out;
2. end-to-end latency at batch 1, 1 thread: raw BVH channel values of one frame of a
   22-joint Mixamo-named skeleton in -> stylised channel values out (Euler conversions,
   retargeting both ways, features, network, foot cleanup);
3. throughput of StreamStylizer on the model's skeleton (features + network) for 1, 10, 100
   and 1,000 concurrent streams, 2 threads, in frames per second.
Targets (issue 4): step p50 <= 100 us, end-to-end p50 <= 300 us, >= 200,000 frames/s at 1,000.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from styleerd.model.checkpoint import load_generator
from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.runtime.backends import BACKENDS, make_backend
from styleerd.runtime.channels import ChannelStylizer
from styleerd.runtime.stylizer import StreamStylizer


def percentiles(seconds: list[float]) -> dict[str, float]:
    us = np.array(seconds) * 1e6
    return {"p50_us": round(float(np.percentile(us, 50)), 1), "p99_us": round(float(np.percentile(us, 99)), 1)}


def set_threads(n: int) -> None:
    torch.set_num_threads(n)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(n)
    except ImportError:
        pass


def network_step(model, backend: str, steps: int) -> dict:
    b = make_backend(backend, model, 1)
    c = model.config
    rng = np.random.default_rng(0)
    x = rng.normal(0, 1, (steps + 50, 1, c.feature_dim)).astype(np.float32)
    style = np.eye(len(c.styles), dtype=np.float32)[[c.neutral_index]]
    content = np.eye(len(c.contents), dtype=np.float32)[[0]]
    target = np.eye(len(c.styles), dtype=np.float32)[[(c.neutral_index + 1) % len(c.styles)]]
    times = []
    for t in range(steps + 50):
        t0 = time.perf_counter()
        b.step(x[t], style, content, target)
        times.append(time.perf_counter() - t0)
    return percentiles(times[50:])


def end_to_end(model, backend: str, steps: int) -> dict:
    source = walk(seconds=max(2.0, steps / 30.0 + 2), fps=30.0)
    values = bvh.channel_values(source)
    stream = ChannelStylizer(model, source.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0, backend=backend)
    times = []
    for t in range(min(steps + 50, len(values))):
        t0 = time.perf_counter()
        stream.step(values[t])
        times.append(time.perf_counter() - t0)
    return percentiles(times[50:])


def throughput(model, backend: str, n_streams: int, seconds: float = 2.0) -> float:
    source = walk(seconds=4.0, fps=30.0)
    from styleerd.motion.retarget import joint_map, to_target

    m = to_target(source, joint_map(model.skeleton, source.skeleton))
    st = StreamStylizer(model, "normal", "walk", {"elderly": 1.0}, n_streams=n_streams, backend=backend)
    rot = np.repeat(m.rotations[:, None], n_streams, 1)
    pos = np.repeat(m.positions[:, None], n_streams, 1)
    frames, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds or frames < 3 * n_streams:
        t = (frames // n_streams) % m.n_frames
        st.step(rot[t], pos[t])
        frames += n_streams
    return frames / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--streams", type=int, nargs="+", default=[1, 10, 100, 1000])
    ap.add_argument("--json", help="also write the figures here")
    args = ap.parse_args()
    model, _ = load_generator()
    report: dict = {"cpu_count": os.cpu_count(), "backends": {}}
    print(f"{'backend':<8} {'step p50':>9} {'p99':>8} {'e2e p50':>9} {'p99':>8}   frames/s at " + " ".join(f"{n:>9,}" for n in args.streams))
    for name in BACKENDS:
        set_threads(1)
        step = network_step(model, name, args.steps)
        e2e = end_to_end(model, name, args.steps)
        set_threads(2)
        rates = {n: round(throughput(model, name, n)) for n in args.streams}
        report["backends"][name] = {"network_step": step, "end_to_end": e2e, "frames_per_second": rates}
        print(f"{name:<8} {step['p50_us']:>7.0f}us {step['p99_us']:>6.0f}us {e2e['p50_us']:>7.0f}us {e2e['p99_us']:>6.0f}us   {'':11}" + " ".join(f"{rates[n]:>9,}" for n in args.streams), flush=True)
    print("targets: step p50 <= 100 us, end-to-end p50 <= 300 us, >= 200,000 frames/s at 1,000 streams")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
