"""What placing the limbs costs where the posture is reached on every frame: 1,000 streams of the
generated walk with the fists held at the chin (an action the network never learnt, so every frame
is the input's pose turned by the posture) into active, stepped on one thread, with the two-bone limbs
placed and a hand's rise eased below the eyes (as shipped) and with every joint turned on its own (no
limbs: the reach before), side by side in alternating rounds (us a stream-frame, median and best).

    python benchmarks/bench_limbs.py [--rounds 5] [--json docs/limbs-bench.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from styleerd.atomic import atomic_write_text
from styleerd.eval.bench import set_threads
from styleerd.model.stored import load_generator_weights
from styleerd.motion.procedural import walk
from styleerd.motion.retarget import to_target
from styleerd.runtime.offline import map_skeleton
from styleerd.runtime.stylizer import StreamStylizer

STREAMS, WARM, STEPS = 1000, 30, 60


def stream_frame_us(stylizer: StreamStylizer, rot: np.ndarray, pos: np.ndarray) -> float:
    """One round: ``STEPS`` steps after the warm-up frames, us a stream-frame."""
    t0 = time.perf_counter()
    for t in range(WARM, WARM + STEPS):
        stylizer.step(rot[t], pos[t])
    return (time.perf_counter() - t0) / STEPS / STREAMS * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    set_threads(1)
    model = load_generator_weights()
    source = walk(seconds=(WARM + STEPS) / 30.0 + 0.5, fps=30.0, guard=True)
    guard = to_target(source, map_skeleton(source.skeleton, model, first_pose=source.rotations[0]))
    rot = np.repeat(guard.rotations[:, None], STREAMS, 1)
    pos = np.repeat(guard.positions[:, None], STREAMS, 1)
    cases = {}
    for case in ("limbs placed", "each joint on its own"):
        s = StreamStylizer(model, "normal", "walk", {"active": 1.0}, n_streams=STREAMS, threads=1)
        if case == "each joint on its own":
            s.limb_ends = np.full_like(s.limb_ends, -1)
        cases[case] = s
    runs: dict[str, list[float]] = {case: [] for case in cases}
    for _ in range(args.rounds):
        for case, s in cases.items():
            s.reset()  # each round from fresh states, warmed up on the same frames
            for t in range(WARM):
                s.step(rot[t], pos[t])
            runs[case].append(stream_frame_us(s, rot, pos))
    unfamiliar = {case: float(s.unfamiliar_sum.mean() / s.frames.mean()) for case, s in cases.items()}
    out = {
        "streams": STREAMS,
        "rounds": args.rounds,
        "unfamiliar_share": unfamiliar,
        "median_us": {c: round(float(np.median(v)), 2) for c, v in runs.items()},
        "best_us": {c: round(min(v), 2) for c, v in runs.items()},
        "runs": runs,
    }
    a, b = out["median_us"]["each joint on its own"], out["median_us"]["limbs placed"]
    print(f"us a stream-frame (median of {args.rounds}): each joint on its own {a}, limbs placed {b} ({b / a:.2f}x)")
    print(f"share of frames unfamiliar: {unfamiliar}")
    if args.json:
        atomic_write_text(args.json, json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
