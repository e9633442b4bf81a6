"""Where a style puts the hands on the held-out strikes: per clip, the share of frames with a hand
above the head joint (the skull's base: a fist there is at the chin), the share with one above the
eyes (``motion.humanoid.eyes_above_head`` higher), and how far above the head joint a hand goes (90th
percentile, cm of a 170 cm body), in the input and in its transfer into a style (pose input), on the
model's skeleton.

    python benchmarks/hands_over_head.py --style active
"""

from __future__ import annotations

import argparse

import numpy as np

from styleerd.eval.actions import _body_scale, _map, _model_points, held_out_clips
from styleerd.model.stored import load_generator_weights
from styleerd.motion.humanoid import eyes_above_head
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.retarget import to_target
from styleerd.runtime.offline import TransferOptions, transfer_motion

STRIKES = ("punch_normal_001", "punch_normal_002", "cmu 002_05", "cmu 002_06", "xia depressed_18_000")


def hands_over_head(motion, jm) -> np.ndarray:
    """Per frame, the higher hand's height over the head joint (the model skeleton's units)."""
    on_model = to_target(motion, jm)
    _, g = forward_kinematics(on_model.rotations, on_model.positions, on_model.skeleton.parents)
    names = on_model.skeleton.names
    hands = np.maximum(g[:, names.index("Hand_L"), 1], g[:, names.index("Hand_R"), 1])
    return hands - g[:, names.index("Head"), 1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--style", default="active")
    args = p.parse_args()
    model = load_generator_weights(None)
    clips = {c.name: c for c in held_out_clips(None)}
    eyes = eyes_above_head(model.skeleton)
    print(
        "| clip | frames with a hand over the head joint: input / output | over the eyes: input / output "
        "| hand over the head joint, p90 cm: input / output |"
    )
    print("|---|---:|---:|---:|")
    for name in STRIKES:
        c = clips[name]
        jm = _map(c, model)
        scale = _body_scale(model.skeleton, _model_points(jm))
        styled = transfer_motion(
            c.motion, model, 30.0, TransferOptions({args.style: 1.0}, c.input_style or "normal"), where=name
        )
        given, out = hands_over_head(c.motion, jm), hands_over_head(styled, jm)
        print(
            f"| {name} | {np.mean(given > 0):.2f} / {np.mean(out > 0):.2f} | "
            f"{np.mean(given > eyes):.2f} / {np.mean(out > eyes):.2f} | "
            f"{np.percentile(given, 90) * scale:.1f} / {np.percentile(out, 90) * scale:.1f} |"
        )


if __name__ == "__main__":
    main()
