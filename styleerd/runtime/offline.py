"""Stylise a whole motion on the model's skeleton: exactly the streaming path, frame by frame."""

from __future__ import annotations

import numpy as np

from styleerd.model.generator import StyleERD
from styleerd.motion.motion import Motion
from styleerd.runtime.stylizer import StreamStylizer


def stylise_motion(model: StyleERD, motion: Motion, input_style: str, content: str, target: dict[str, float]) -> Motion:
    """The motion in the target style(s): joint rotations from the network, root trajectory
    (position and facing) and joint translations from the input."""
    stylizer = StreamStylizer(model, input_style, content, target, fps=motion.fps)
    out = np.empty_like(motion.rotations)
    for t in range(motion.n_frames):
        out[t] = stylizer.step(motion.rotations[t : t + 1], motion.positions[t : t + 1])[0][0]
    return Motion(motion.skeleton, out, motion.positions.copy(), motion.fps)
