"""Where a server's step of a crowd goes: ``ChannelStylizer`` (what ``styleerd serve`` steps: BVH
channels in and out on the user's skeleton, retargeting, the stylizer, the foot lock) stepping N streams
of the load test's walk with labels given, on one thread, timed and then profiled (cProfile): each
function's own time, in us a frame and as a share of the step.

    python benchmarks/profile_channels.py [--streams 320] [--pose input|network] [--steps 200] [--top 10]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--streams", type=int, default=320, help="about a crowd's batch in the served load test")
    p.add_argument("--pose", choices=("input", "network"), default="input")
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--top", type=int, default=10)
    args = p.parse_args()

    from styleerd.model.stored import load_generator_weights
    from styleerd.motion import bvh
    from styleerd.motion.procedural import walk
    from styleerd.runtime.channels import ChannelStylizer
    from styleerd.serve.client import LABELS, PHASE

    model, motion, n = load_generator_weights(), walk(10.0, fps=30.0), args.streams
    channels = ChannelStylizer(
        model, motion.skeleton, {"elderly": 1.0}, *LABELS, n_streams=n, backend="numba", pose=args.pose, threads=1
    )
    values = bvh.channel_values(motion).astype(np.float64)
    frame = lambda t: values[(t + PHASE * np.arange(n)) % len(values)]
    for t in range(50):  # compiled, and past the streams' first frames
        channels.step(frame(t))
    t0 = time.perf_counter()
    for t in range(50, 50 + args.steps):
        channels.step(frame(t))
    step_us = (time.perf_counter() - t0) / args.steps * 1e6
    profile = cProfile.Profile()
    profile.enable()
    for t in range(50 + args.steps, 50 + 2 * args.steps):
        channels.step(frame(t))
    profile.disable()
    stats = pstats.Stats(profile).stats
    total = sum(own for _, _, own, _, _ in stats.values())
    print(
        f"{n} streams, pose {args.pose}, one thread: {step_us:,.0f} us a step, {step_us / n:.2f} us a frame "
        f"(timed without the profiler)\n\n| function (own time) | us a frame | share of the step |\n| --- | --- | --- |"
    )
    for (path, line, name), (_, _, own, _, _) in sorted(stats.items(), key=lambda kv: -kv[1][2])[: args.top]:
        where = f"{path.split('styleerd/')[-1]}:{line} {name}" if "styleerd/" in path else name
        print(f"| {where} | {own / args.steps * 1e6 / n:.2f} | {100 * own / total:.0f} % |")


if __name__ == "__main__":
    main()
