"""The blend towards the input alone (``runtime.stylizer._towards_the_input``, the default pose's last
kernel) of this checkout and of another commit, in one process, on one thread: both get the same
arguments, captured from a ``StreamStylizer`` stepping N streams of a walk into one style, and are timed
in alternating rounds (median and best, us a step of N streams). Each case once as the walk leaves it
(part way to the input) and once with every stream all the way (``seen`` = 1: an action the network
never learnt). The outputs of the two kernels are compared too.

    python benchmarks/blend_kernel_ab.py --before COMMIT [--streams 1000] [--rounds 15] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from step_kernel_ab import module_at  # this folder's: run as python benchmarks/blend_kernel_ab.py


def fresh(args: list) -> list:
    """A kernel's arguments with its arrays copied: the kernel writes into some of them."""
    return [x.copy() if isinstance(x, np.ndarray) else x for x in args]


def captured_arguments(streams: int) -> list:
    """The arguments of the blend in a step of ``streams`` streams of the model's walk into elderly."""
    from styleerd.eval.bench import _model_walk
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime import stylizer

    model = load_generator_weights()
    walk = _model_walk(model, 4.0)
    rot = np.repeat(walk.rotations[:, None], streams, 1)
    pos = np.repeat(walk.positions[:, None], streams, 1)
    st = stylizer.StreamStylizer(model, "normal", "walk", {"elderly": 1.0}, n_streams=streams, threads=1)
    for t in range(60):
        st.step(rot[t], pos[t])
    kernel, seen = stylizer._towards_the_input, []
    stylizer._towards_the_input = lambda *a: (seen.append(fresh(a)), kernel(*a))
    try:
        st.step(rot[60], pos[60])
    finally:
        stylizer._towards_the_input = kernel
    return seen[0]


def timed(kernel, args: list) -> float:
    copied = fresh(args)
    t0 = time.perf_counter()
    kernel(*copied)
    return (time.perf_counter() - t0) * 1e6


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", required=True)
    p.add_argument("--streams", type=int, default=1000)
    p.add_argument("--rounds", type=int, default=15)
    p.add_argument("--json", help="also write the figures here")
    args = p.parse_args()

    from styleerd.runtime.stylizer import _towards_the_input

    captured = captured_arguments(args.streams)
    all_the_way = fresh(captured)
    all_the_way[6][:] = 1.0  # seen: every stream as unfamiliar as can be
    report: dict = {"streams": args.streams, "before": args.before, "cases": {}}
    with tempfile.TemporaryDirectory() as tmp:
        kernels = {
            "before": module_at(args.before, "styleerd/runtime/stylizer.py", Path(tmp))._towards_the_input,
            "now": _towards_the_input,
        }
        for case, base in (("part way (the walk's own)", captured), ("all the way", all_the_way)):
            outs = {}
            for name, kernel in kernels.items():
                out = fresh(base)
                kernel(*out)  # compiled, and its output kept
                outs[name] = out
            times: dict[str, list[float]] = {name: [] for name in kernels}
            for r in range(args.rounds):
                for name in list(kernels)[:: 1 if r % 2 == 0 else -1]:
                    times[name].append(timed(kernels[name], base))
            weight = outs["now"][9]
            row = {
                "unfamiliar_mean": round(float(weight.mean()), 3),
                "largest_difference": float(np.abs(outs["now"][2] - outs["before"][2]).max()),
                **{f"{n}_us_median": round(float(np.median(v)), 1) for n, v in times.items()},
                **{f"{n}_us_best": round(float(np.min(v)), 1) for n, v in times.items()},
            }
            report["cases"][case] = row
            print(
                f"{case}: unfamiliar {row['unfamiliar_mean']}, {args.streams} streams on one thread: before "
                f"{row['before_us_median']:.0f} us (best {row['before_us_best']:.0f}), now {row['now_us_median']:.0f} "
                f"us (best {row['now_us_best']:.0f}); largest difference between them {row['largest_difference']:.1e}"
            )
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
