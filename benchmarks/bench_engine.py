"""The per-frame path before and after, side by side: each figure measured by the code of two
commits in alternating rounds on this machine (a shared machine's speed drifts up to 2-4x over
minutes; alternating puts both under the same conditions); the median over rounds is kept, and
each figure's best round (the one least disturbed by other work on the machine).

Per commit: the network step at batch 1 (numba backend, and the ONNX graphs in onnxruntime through ``OnnxBackend``: the
graph of every style's branches, and of one style's), end to end at batch 1 (raw BVH channel values in and out of a
22-joint Mixamo-named skeleton: retargeting both ways, features, network, foot cleanup; numba and numpy backends), 64
and 256 streams on 2 threads (numba, end to end), and 1,000 streams on 2 threads (numba: end to end, and the network
alone; numpy and ONNX: the network alone) against the float32 matrix-multiply peak measured in the same process; and
end to end at batch 1 and 1,000 streams (numba) with the input's style and content inferred by the labeller, as users'
streams run.

    python benchmarks/bench_engine.py [--before COMMIT|FOLDER] [--rounds 3] [--json docs/engine-bench.json]

``--before`` takes a commit of this repository, or a folder holding another version's tree (``git archive``'s,
for a machine the repository's history is not on).

Writes the JSON (with the CPU's model) and prints a table.
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BEFORE = "bc2080d"  # the last commit before the compiled per-frame path and the batched ONNX graphs
FIGURES = (
    "step_us numba",
    "step_us onnx",
    "step_us onnx one style",
    "step_us onnx-plain",
    "step_us onnx-plain one style",
    "end_to_end_us numba",
    "end_to_end_us numpy",
    "frames_per_s 1000 streams numba",
    "fraction_of_peak 1000 streams numba",
    "frames_per_s 1000 streams numba, network alone",
    "fraction_of_peak 1000 streams numba, network alone",
    "frames_per_s 1000 streams numpy, network alone",
    "frames_per_s 1000 streams onnx, network alone",
    "fraction_of_peak 1000 streams numba, products alone",
    "frames_per_s 64 streams numba",
    "frames_per_s 256 streams numba",
    "end_to_end_us numba, labels inferred",
    "frames_per_s 1000 streams numba, labels inferred",
    *(f"frames_per_s {n} streams {b}, network alone" for n in (1, 4, 16, 64, 256) for b in ("numba", "numpy")),
)


def measure(steps: int) -> dict:
    """The figures of the styleerd importable here (run in a worker process per commit)."""
    from styleerd.eval import bench
    from styleerd.eval.bench import end_to_end, flops_per_frame, matmul_peak, network_step, set_threads, throughput
    from styleerd.model.stored import load_generator_weights

    model = load_generator_weights()
    set_threads(1)
    out = {"step_us numba": network_step(model, "numba", steps)["p50_us"]}
    by_itself = (
        "every_branch" in inspect.signature(network_step).parameters
    )  # the backend picks the target's graph itself
    for form in ("onnx", "onnx-plain"):
        out[f"step_us {form}"] = network_step(model, form, steps, **({"every_branch": True} if by_itself else {}))[
            "p50_us"
        ]
        out[f"step_us {form} one style"] = network_step(
            model, form, steps, **({} if by_itself else {"one_style": True})
        )["p50_us"]
    for backend in ("numba", "numpy"):
        out[f"end_to_end_us {backend}"] = end_to_end(model, backend, steps)["p50_us"]
    out["end_to_end_us numba, labels inferred"] = inferred_end_to_end(model, steps)
    peak = matmul_peak(2)
    set_threads(2)
    # not kept, for every commit alike: a process's first second of many streams, and the first
    # after the matmul peak (OpenBLAS's threads spin on for a while), ran slower
    throughput(model, "numba", 1000, seconds=0.5)
    fps = throughput(model, "numba", 1000)
    out["frames_per_s 1000 streams numba"] = round(fps)
    out["fraction_of_peak 1000 streams numba"] = round(fps * flops_per_frame(model) / peak, 4)
    for n in (64, 256):  # fewer streams than a step once needed to be split over threads
        out[f"frames_per_s {n} streams numba"] = round(throughput(model, "numba", n))
    out["frames_per_s 1000 streams numba, labels inferred"] = round(inferred_throughput(model, 1000))
    if hasattr(bench, "network_throughput"):  # the network alone, as `styleerd bench` measures it
        net = bench.network_throughput(model, "numba")
        out["frames_per_s 1000 streams numba, network alone"] = round(net)
        out["fraction_of_peak 1000 streams numba, network alone"] = round(net * flops_per_frame(model) / peak, 4)
        for backend in ("numpy", "onnx"):
            out[f"frames_per_s 1000 streams {backend}, network alone"] = round(bench.network_throughput(model, backend))
        for n in (1, 4, 16, 64, 256):  # numpy sharded over threads only from many streams, as StreamStylizer does
            for backend, threads in (("numba", 2), ("numpy", 1)):
                out[f"frames_per_s {n} streams {backend}, network alone"] = round(
                    bench.network_throughput(model, backend, n, seconds=0.7, threads=threads)
                )
    if hasattr(bench, "products_alone"):  # the ceiling: the numba step's matrix products alone
        out["fraction_of_peak 1000 streams numba, products alone"] = round(
            bench.products_alone(model) * flops_per_frame(model) / peak, 4
        )
    out["matmul_peak_gflops"] = round(peak / 1e9, 1)
    try:  # the breakdown reads this version's internals: an older tree's differ, and it has none
        out.update({f"stage_us {k}": v for k, v in stages(steps).items()})
    except (AttributeError, ImportError, TypeError, ValueError):
        pass
    return out


def inferred_end_to_end(model, steps: int) -> float:
    """``bench.end_to_end`` (numba) with the input's style and content left to the labeller, as users'
    streams run: p50 us a frame."""
    import time

    from styleerd.motion import bvh
    from styleerd.motion.procedural import walk
    from styleerd.runtime.channels import ChannelStylizer

    source = walk(seconds=steps / 30.0 + 2.0, fps=30.0)
    values = bvh.channel_values(source)
    stream = ChannelStylizer(model, source.skeleton, {"elderly": 1.0}, None, None, fps=30.0, backend="numba")
    times = []
    for t in range(len(values)):
        t0 = time.perf_counter()
        stream.step(values[t])
        times.append(time.perf_counter() - t0)
    return round(float(np.median(times[50:])) * 1e6, 1)


def inferred_throughput(model, n: int, seconds: float = 1.5) -> float:
    """``bench.throughput`` (numba, 2 threads) with the labels left to the labeller: frames/s."""
    import itertools

    from styleerd.eval.bench import _model_walk, _steady_rate
    from styleerd.runtime.stylizer import StreamStylizer

    m = _model_walk(model, 4.0)
    st = StreamStylizer(model, None, None, {"elderly": 1.0}, n_streams=n, backend="numba", threads=2)
    rot, pos = np.repeat(m.rotations[:, None], n, 1), np.repeat(m.positions[:, None], n, 1)
    frame = itertools.count()

    def step() -> None:
        t = next(frame) % m.n_frames
        st.step(rot[t], pos[t])

    return _steady_rate(step, n, seconds)


STAGES = (
    "check values",
    "channels to motion",
    "retarget to the model",
    "features",
    "network",
    "stylizer bookkeeping",
    "retarget back",
    "foot cleanup",
    "motion to channels",
)


def stages(steps: int) -> dict:
    """Where a frame's microseconds go end to end (numba backend, batch 1): the median of each
    stage of ``ChannelStylizer.step``, each call timed on its own; the stylizer's step is split
    into its features, its network step (timed again on a second backend) and the rest."""
    import time

    from styleerd.eval.bench import set_threads
    from styleerd.model.stored import load_generator_weights
    from styleerd.motion import bvh
    from styleerd.motion.motion import Motion
    from styleerd.motion.procedural import walk
    from styleerd.motion.retarget import to_source, to_target
    from styleerd.runtime.backends import make_backend
    from styleerd.runtime.channels import ChannelStylizer

    set_threads(1)
    model = load_generator_weights()
    source = walk(seconds=steps / 30.0 + 2.0, fps=30.0)
    values = bvh.channel_values(source)
    cs = ChannelStylizer(model, source.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0, backend="numba")
    net, st = make_backend("numba", model, 1), cs.stylizer
    target = st.current_weights().astype(np.float32)
    times: dict = {k: [] for k in (*STAGES, "stylizer step")}

    def timed(stage, f, *a):
        t0 = time.perf_counter()
        out = f(*a)
        times[stage].append(time.perf_counter() - t0)
        return out

    for t in range(len(values)):
        v = values[t : t + 1]
        timed("check values", bvh.channel_problem, cs.skeleton, v)
        src = timed("channels to motion", bvh.motion_from_channels, cs.skeleton, v, cs.fps)
        on_model = timed("retarget to the model", to_target, src, cs.map)
        rot, pos = timed("stylizer step", st.step, on_model.rotations, on_model.positions)
        x = timed("features", st._features, on_model.rotations, on_model.positions, slice(None))[0]
        timed("network", net.step, x, st.given_style, st.given_content, target)
        out = timed("retarget back", to_source, Motion(cs.map.target, rot, pos, cs.fps), cs.map, src)
        out.rotations, out.positions = timed(
            "foot cleanup", cs.lock.step, out.rotations, out.positions, src.rotations, src.positions
        )
        timed("motion to channels", bvh.channel_values, out)
    us = {k: float(np.median(v[50:])) * 1e6 for k, v in times.items()}
    us["stylizer bookkeeping"] = max(0.0, us.pop("stylizer step") - us["features"] - us["network"])
    return {k: round(us[k], 1) for k in STAGES}


def worker(tree: Path, steps: int) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (str(tree), os.environ.get("PYTHONPATH")))))
    code = (
        f"import json, sys; sys.path.insert(0, {str(ROOT / 'benchmarks')!r}); from bench_engine import measure; "
        f"print(json.dumps(measure({steps})))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=tree, env=env, capture_output=True, text=True, check=False
    )
    if result.returncode:
        raise SystemExit(f"worker in {tree} failed:\n{result.stderr[-3000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def summary(rounds: dict[str, list[dict]]) -> tuple[dict, dict]:
    """Per commit, the median of each figure over the rounds, and its best round (least disturbed
    by other tenants): the lowest time, the highest rate. Every fraction of peak is against the
    best peak of all rounds of both commits (the machine's; a round's own peak, measured while
    the machine was busy, flatters the round: it once made products 1.16x "the peak")."""
    peak = max(m["matmul_peak_gflops"] for ms in rounds.values() for m in ms)
    achieved = lambda m, k: m[k] * m["matmul_peak_gflops"] / peak if k.startswith("fraction") else m[k]
    median = {
        name: {k: round(float(np.median([achieved(m, k) for m in ms])), 4) for k in ms[0]}
        for name, ms in rounds.items()
    }
    best = {
        name: {
            k: round(
                float((max if k.startswith(("frames", "fraction", "matmul")) else min)(achieved(m, k) for m in ms)), 4
            )
            for k in ms[0]
        }
        for name, ms in rounds.items()
    }
    return median, best


def stage_column(figures: dict) -> list[str]:
    """A version's stage times and their sum, or dashes where it has no breakdown."""
    us = [figures.get("stage_us " + k) for k in STAGES]
    return [f"{u:.1f}" for u in (*us, sum(us))] if None not in us else ["-"] * (len(STAGES) + 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default=BEFORE)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--json", type=Path, default=ROOT / "docs" / "engine-bench.json")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        given = Path(args.before).is_dir()
        before = Path(args.before).resolve() if given else Path(tmp) / "before"
        if not given:
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(before), args.before],
                check=True,
                capture_output=True,
            )
        try:
            trees = {f"before ({args.before})": before, "now": ROOT}
            for tree in trees.values():  # compile the numba caches outside the timed rounds
                worker(tree, 100)
            rounds: dict[str, list[dict]] = {name: [] for name in trees}
            for r in range(args.rounds):
                for name in list(trees)[:: 1 if r % 2 == 0 else -1]:
                    rounds[name].append(worker(trees[name], args.steps))
                    print(f"round {r + 1}, {name}: {rounds[name][-1]}", flush=True)
        finally:
            if not given:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(before)], check=False)
    median, best = summary(rounds)
    from styleerd.runtime.system import cpu_model

    report = {
        "cpu": cpu_model(),
        "rounds": args.rounds,
        "steps": args.steps,
        "cpu_count": os.cpu_count(),
        "median": median,
        "best": best,
        "each_round": rounds,
    }
    out = args.json
    out.write_text(json.dumps(report, indent=1) + "\n")
    b, a = median.values()
    bb, ab = best.values()
    print(f"\nCPU: {report['cpu']}, {report['cpu_count']} cores")
    print(
        f"| figure ({args.rounds} alternating rounds) | {' | '.join(median)}: median | speed-up | best round: "
        f"{' | '.join(best)} | speed-up |\n| --- | --- | --- | --- | --- | --- | --- |"
    )
    for k in FIGURES:
        if k not in b or k not in a:
            continue
        up = k.startswith(("frames", "fraction"))
        print(
            f"| {k} | {b[k]:,} | {a[k]:,} | {(a[k] / b[k] if up else b[k] / a[k]):.2f}x | {bb[k]:,} | {ab[k]:,} | "
            f"{(ab[k] / bb[k] if up else bb[k] / ab[k]):.2f}x |"
        )
    print(f"matmul peak (GFLOP/s, 2 threads): {b['matmul_peak_gflops']} / {a['matmul_peak_gflops']}")
    print(f"\n| end to end, batch 1, numba: stage (us, median of rounds) | {' | '.join(median)} |\n| --- | --- | --- |")
    for k, x, y in zip((*STAGES, "sum of the stages"), stage_column(b), stage_column(a)):
        print(f"| {k} | {x} | {y} |")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
