"""StreamStylizer: frame in, stylised frame out, for one stream or a batch of streams.

Frames are poses on the model's skeleton: local joint rotations ``[N, J, 4]`` and local
translations ``[N, J, 3]`` (N streams). Output frame t depends on input frames <= t only.
The output keeps the input's root trajectory (root position and facing) and joint
translations; the network replaces the joint rotations.

Changing the target (style, intensity, mixture) mid-stream blends the target weights
linearly over ``blend_frames`` frames, so the output does not pop.

The input's style and content labels are optional: a label not given is inferred after every
frame by the OnlineLabeller from the frames seen so far, and its posterior (probabilities)
takes the label's place.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from styleerd.data.features import pose_features
from styleerd.errors import StyleERDError
from styleerd.model.checkpoint import load_labeller
from styleerd.model.generator import StyleERD
from styleerd.model.labeller import OnlineLabeller
from styleerd.motion import quat
from styleerd.motion.kinematics import forward_positions
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.backends import NumpyLabeller, make_backend


def label_vector(names: tuple[str, ...], weights: dict[str, float], what: str) -> np.ndarray:
    """{"elderly": 0.7, "normal": 0.3} -> weights in the model's label order."""
    v = np.zeros(len(names))
    for name, w in weights.items():
        if name not in names:
            raise StyleERDError(f"unknown {what} {name!r}; valid: {', '.join(names)}")
        v[names.index(name)] = w
    return v


def target_weights(model: StyleERD, style: str | None = None, intensity: float = 1.0, mix: dict[str, float] | None = None, max_intensity: float = 2.0) -> dict[str, float]:
    """Target weights from a style and intensity (the rest goes to neutral; 0 = neutral,
    1 = full style, above 1 exaggerates up to ``max_intensity``), or from a mixture."""
    neutral = model.config.neutral_style
    if mix:
        total = sum(mix.values())
        if total <= 0 or any(w < 0 for w in mix.values()):
            raise StyleERDError(f"mixture weights must be non-negative and sum above 0, got {mix}")
        return {k: v / total for k, v in mix.items()}
    if style is None:
        raise StyleERDError("give a target style or a mixture")
    if not 0.0 <= intensity <= max_intensity:
        raise StyleERDError(f"intensity {intensity:g} is outside [0, {max_intensity:g}]")
    if style == neutral:
        return {neutral: 1.0}
    return {style: intensity, neutral: max(0.0, 1.0 - intensity)}


def _per_stream(value, n: int) -> list:
    """One value for every stream, or a list with one per stream."""
    if isinstance(value, list):
        if len(value) != n:
            raise StyleERDError(f"{len(value)} per-stream values for {n} streams")
        return value
    return [value] * n


@dataclass
class _Blend:
    start: np.ndarray  # [N, nS] weights when the change began
    end: np.ndarray  # [N, nS] weights to reach
    frame: np.ndarray  # [N] frames since the change


class StreamStylizer:
    """``input_style``, ``content`` and ``target`` apply to every stream, or are lists with
    one value per stream; labels left None are inferred."""

    def __init__(
        self,
        model: StyleERD,
        input_style: str | list[str] | None,
        content: str | list[str] | None,
        target: dict[str, float] | list[dict[str, float]],
        n_streams: int = 1,
        fps: float = 30.0,
        blend_frames: int = 8,
        labeller: OnlineLabeller | None = None,
        backend: str = "numpy",
    ):
        self.model = model.eval()
        self.backend = make_backend(backend, model, n_streams)
        self.skeleton = model.skeleton
        self.roles = BodyRoles.of(self.skeleton)
        self.stats = model.stats()
        self.fps = fps
        self.n = n_streams
        self.blend_frames = max(1, blend_frames)
        c = model.config
        self.given_style, self.given_content = (
            None if label is None else np.stack([label_vector(names, {x: 1.0}, what) for x in _per_stream(label, n_streams)]).astype(np.float32)
            for label, names, what in ((input_style, c.styles, "style"), (content, c.contents, "content"))
        )
        self.labeller = None
        if input_style is None or content is None:
            labeller = labeller or load_labeller()[0]
            if (labeller.n_styles, labeller.n_contents, labeller.in_dim) != (len(c.styles), len(c.contents), c.feature_dim):
                raise StyleERDError("the labeller does not fit this model's labels: give --input-style and --content")
            self.labeller = NumpyLabeller(labeller, n_streams)
        w = np.stack([label_vector(c.styles, t, "style") for t in _per_stream(target, n_streams)])
        self.blend = _Blend(w.copy(), w, np.full(n_streams, self.blend_frames))
        self.reset()

    def reset(self) -> None:
        """Forget the past: the next frame is a first frame (learned initial states)."""
        self.backend.reset()
        self.previous: np.ndarray | None = None  # global joint positions of the last frame
        if self.labeller is not None:
            self.labeller.reset()
        self.labels: tuple[np.ndarray, np.ndarray] | None = None  # (style, content) used last frame

    def inferred_labels(self) -> list[tuple[str, str]]:
        """Per stream, the (style, content) the last frame was stylised as (given or inferred)."""
        if self.labels is None:
            return []
        c = self.model.config
        return [(c.styles[int(s)], c.contents[int(k)]) for s, k in zip(self.labels[0].argmax(-1), self.labels[1].argmax(-1))]

    def current_weights(self) -> np.ndarray:
        a = np.minimum(1.0, self.blend.frame / self.blend_frames)[:, None]
        return self.blend.start + a * (self.blend.end - self.blend.start)

    def set_target(self, target: dict[str, float], streams: list[int] | None = None) -> None:
        """New target weights for some (default all) streams, reached over ``blend_frames``."""
        rows = np.arange(self.n) if streams is None else np.asarray(streams)
        w = label_vector(self.model.config.styles, target, "style")
        now = self.current_weights()
        self.blend.start[rows] = now[rows]
        self.blend.end[rows] = w
        self.blend.frame[rows] = 0

    def step(self, rotations: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One frame of every stream -> the stylised frame. A frame with NaN/inf is rejected
        with an error and leaves the state unchanged."""
        rotations = np.asarray(rotations, dtype=np.float64).reshape(self.n, self.skeleton.n_joints, 4)
        positions = np.asarray(positions, dtype=np.float64).reshape(self.n, self.skeleton.n_joints, 3)
        if not (np.isfinite(rotations).all() and np.isfinite(positions).all()):
            bad = np.argwhere(~np.isfinite(rotations).all(-1) | ~np.isfinite(positions).all(-1))[0]
            raise StyleERDError(f"frame rejected: stream {bad[0]}, joint {self.skeleton.names[bad[1]]!r} has a NaN or infinite value")
        rotations = quat.normalize(rotations)
        if self.previous is None:
            previous = forward_positions(rotations, positions, self.skeleton.parents)
        else:
            previous = self.previous
        feats, traj, g = pose_features(rotations, positions, previous, self.skeleton, self.roles, self.fps)
        x = self.stats.normalize(feats).astype(np.float32)
        style, content, labeller_state = self.given_style, self.given_content, None
        if self.labeller is not None:
            p_style, p_content, labeller_state = self.labeller.step(x)
            style = style if style is not None else p_style
            content = content if content is not None else p_content
        rot, _ = self.backend.step(x, style, content, self.current_weights().astype(np.float32))
        out = rot.astype(np.float64)
        out[:, 0] = quat.mul(traj[:, 3:7], out[:, 0])
        if self.labeller is not None:
            self.labeller.h = labeller_state
        self.previous, self.labels = g, (style, content)
        self.blend.frame += 1
        return quat.normalize(out), positions
