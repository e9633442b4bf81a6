"""Stylise a whole motion on the model's skeleton (the network run over every frame in one
causal pass; frame t of the output depends on input frames <= t only)."""

from __future__ import annotations

import torch

from styleerd.data.features import motion_features
from styleerd.errors import StyleERDError
from styleerd.model.generator import StyleERD
from styleerd.motion import quat
from styleerd.motion.motion import Motion


def label_vector(names: tuple[str, ...], weights: dict[str, float], what: str) -> torch.Tensor:
    """{"elderly": 0.7, "normal": 0.3} -> weights in the model's label order."""
    v = torch.zeros(len(names))
    for name, w in weights.items():
        if name not in names:
            raise StyleERDError(f"unknown {what} {name!r}; valid: {', '.join(names)}")
        v[names.index(name)] = w
    return v


@torch.no_grad()
def stylise_motion(model: StyleERD, motion: Motion, input_style: str, content: str, target: dict[str, float]) -> Motion:
    """The motion in the target style(s): joint rotations from the network, root trajectory
    (position and heading) from the input, other joint translations from the input."""
    c = model.config
    feats, traj = motion_features(motion)
    x = torch.tensor(model.stats().normalize(feats), dtype=torch.float32).unsqueeze(0)
    s = label_vector(c.styles, {input_style: 1.0}, "style").unsqueeze(0)
    k = label_vector(c.contents, {content: 1.0}, "content").unsqueeze(0)
    t = label_vector(c.styles, target, "style").unsqueeze(0)
    rot, _, _ = model(x, s, k, t)
    rot = rot[0].double().numpy()
    rot[:, 0] = quat.mul(traj[:, 3:7], rot[:, 0])
    return Motion(motion.skeleton, quat.normalize(rot), motion.positions.copy(), motion.fps)
