"""Style per body part: are there seams where parts of different targets meet?

Every Bandai-Namco-2 test clip (90 frames, labels given) is streamed three ways: with one
target for the whole body, with body parts of their own targets (``--parts``), and as it is.
At each part boundary (the first joint of a part whose parent is in another part, and the
joint below it) the largest joint move per frame is compared: per stream the largest over the
clip, averaged over the streams; beside it, the 99th percentile of per-frame moves of those
joints in the real clips. Writes docs/parts.json and a filmstrip, docs/parts-bandai2.png.

    python benchmarks/parts_seams.py [--style active] [--parts legs=elderly,torso=exhausted,arms=input] [--data DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from styleerd.eval.metrics import _streams
from styleerd.eval.plots import filmstrip
from styleerd.model.stored import load_generator_weights
from styleerd.motion.kinematics import forward_positions
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import part_joints
from styleerd.runtime.stylizer import StreamStylizer


def stream(model, rot, pos, styles, contents, target: dict, parts: str | None) -> np.ndarray:
    st = StreamStylizer(model, styles, contents, target, n_streams=len(rot), backend="numba", parts=parts)
    return np.stack([st.step(rot[:, t], pos[:, t])[0] for t in range(rot.shape[1])], 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--style", default="active")
    parser.add_argument("--parts", default="legs=elderly,torso=exhausted,arms=input")
    parser.add_argument("--data")
    args = parser.parse_args()
    model = load_generator_weights()
    sk = model.skeleton
    rot, pos, styles, contents, _ = _streams(model, args.data, 90)
    owner = np.empty(sk.n_joints, int)
    for k, joints in enumerate(part_joints(sk).values()):
        owner[joints] = k
    starts = [j for j in range(1, sk.n_joints) if owner[j] != owner[sk.parents[j]]]
    boundary = sorted(set(starts) | {j for j in range(sk.n_joints) if sk.parents[j] in starts})

    def largest_moves(r: np.ndarray) -> np.ndarray:  # [N, T-1] the largest move per frame at the boundary
        g = forward_positions(r, pos, sk.parents)[:, :, boundary]
        return np.linalg.norm(np.diff(g, axis=1), axis=-1).max(-1)

    whole = stream(model, rot, pos, styles, contents, {args.style: 1.0}, None)
    mixed = stream(model, rot, pos, styles, contents, {args.style: 1.0}, args.parts)
    report = {
        "clips": len(rot),
        "frames": rot.shape[1],
        "style": args.style,
        "parts": args.parts,
        "boundary_joints": [sk.names[j] for j in boundary],
        "largest_move_per_frame_cm": {
            "input": round(float(largest_moves(rot).max(1).mean()), 3),
            "one target": round(float(largest_moves(whole).max(1).mean()), 3),
            "parts": round(float(largest_moves(mixed).max(1).mean()), 3),
        },
        "input_p99_cm": round(float(np.percentile(largest_moves(rot), 99)), 3),
    }
    (ROOT / "docs" / "parts.json").write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    k = next(i for i, (s, c) in enumerate(zip(styles, contents)) if c == "walk" and s == model.config.neutral_style)
    rows = [
        (f"input ({styles[k]})", Motion(sk, rot[k], pos[k], 30.0)),
        (f"target {args.style}", Motion(sk, whole[k], pos[k], 30.0)),
        (f"target {args.style}, --parts {args.parts}", Motion(sk, mixed[k], pos[k], 30.0)),
    ]
    filmstrip(rows, ROOT / "docs" / "parts-bandai2.png", title="style per body part (styleerd transfer --parts)")
    print("wrote docs/parts.json and docs/parts-bandai2.png")


if __name__ == "__main__":
    main()
