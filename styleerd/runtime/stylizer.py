"""StreamStylizer: frame in, stylised frame out, for one stream or a batch of streams.

Frames are poses on the model's skeleton: local joint rotations ``[N, J, 4]`` and local
translations ``[N, J, 3]`` (N streams). Output frame t depends on input frames <= t only.
The output keeps the input's root trajectory (root position and facing) and joint
translations. ``pose="network"`` takes the network's joint rotations (the paper's output), which
rebuilds every pose from the actions it was trained on: a kick comes back as standing. So by
default (``pose="input"``) a second pass, with style branches of its own, gives the network's
output in the input's own style (the identity transfer; on the numpy and numba backends it shares
the target pass's encoder and neutral stack, whose state depends on the input alone:
``step_pair``), and how far that is from the input says how unfamiliar the input is
(``unfamiliar``, per stream and frame, 0..1). Where the network rebuilds
the input well, the output is the network's; where it does not, the input's own pose turned, joint
by joint, by the target style's posture (``runtime.posture``; for a model without one, by the change
from the identity output to the target's), then turned so that its joints go where the posture moves
the input's (``_reach``, where the posture has joint offsets) (``_towards_the_input``), so a pose the
network never learnt passes through with the style on it; in between, a blend of the two.

Changing the target (style, intensity, mixture) mid-stream blends the target weights
linearly over ``blend_frames`` frames, so the output does not pop.

The input's style and content labels are optional: a label not given is inferred after every
frame by the OnlineLabeller from the frames seen so far, and its posterior (probabilities)
takes the label's place.
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import nullcontext
from dataclasses import dataclass

import numba as nb
import numpy as np

from styleerd.data.features import FeatureLayout, stream_features
from styleerd.data.parallel import on_kernel_threads
from styleerd.errors import StyleERDError, unknown_name
from styleerd.model.config import LIMB_ROUNDS, RELEASE, RISE
from styleerd.model.stored import (
    GeneratorWeights,
    LabellerWeights,
    generator_weights,
    labeller_stem,
    labeller_weights,
    load_labeller_weights,
    toward_neutral,
)
from styleerd.motion import quat
from styleerd.motion.humanoid import eyes_above_head, limb_ends
from styleerd.motion.retarget import BODY_PARTS, part_joints
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.backends import make_backend
from styleerd.runtime.numpy_step import NumpyLabeller, one_blas_thread

MAX_FEATURE = 1e6
# Streams per step from which a numpy or onnx step is split into one shard per thread of the stylizer's pool: below it
# the GIL and onnxruntime's cost per call make shards lose (measurements: docs/benchmarks.md, "Shards of streams").
# The numba backend's threads run inside its compiled kernels instead (``data.parallel``).
# From this many streams, the numba backend's labeller runs its numpy products on one BLAS thread:
# numpy's BLAS threads beside scipy's (the compiled step's) spin against each other, 2.3x slower at
# 100 streams on 2 cores (benchmarks/labeller_blas.py); the limit costs about 0.2 ms a step.
LABELLER_ONE_BLAS_FROM = 64  # at 32 streams the limit costs more than it saves
NUMPY_SHARD_FROM = 600
SHARD_FROM = {"numpy": NUMPY_SHARD_FROM, "onnx": 128, "onnx-plain": 128}
# how long an inferred input style takes to follow the labeller's readings (1 - 1/e of the way), once it has read the
# stream's first STYLE_SETTLED seconds (taken as they come: smoothing them delays the first reading of a style)
STYLE_SECONDS, STYLE_SETTLED = 0.5, 1.0
POSES = ("input", "network")  # what a stylised pose is built on (module docstring)
# backends whose steps run on threads of their own (torch's pool, numba's parallel loops), never on the stylizer's pool
OWN_THREADS = ("torch", "numba")
PAIRED = ("numpy", "numba")  # backends with ``step_pair``: the identity pass shares the encoder and neutral stack
_ALL = slice(None)  # every stream (state rows as views)


def label_vector(names: tuple[str, ...], weights: dict[str, float], what: str) -> np.ndarray:
    """{"elderly": 0.7, "normal": 0.3} -> weights in the model's label order."""
    v = np.zeros(len(names))
    for name, w in weights.items():
        if name not in names:
            raise unknown_name(what, name, names)
        v[names.index(name)] = w
    return v


def parse_mix(text: str) -> dict[str, float] | None:
    """A mixture written ``"elderly=0.5,feminine=0.5"`` (``--mix``, the Blender add-on's field) as
    style -> weight; None for an empty text. The weights are checked by ``target_weights``."""
    if not text.strip():
        return None
    try:
        mix = {k.strip(): float(v) for k, v in (part.split("=") for part in text.split(","))}
    except ValueError:
        mix = None
    if mix is None or "" in mix:
        raise StyleERDError(f"mix {text!r}: expected STYLE=WEIGHT,STYLE=WEIGHT, e.g. elderly=0.5,feminine=0.5")
    return mix


def target_weights(
    model: GeneratorWeights,
    style: str | None = None,
    intensity: float = 1.0,
    mix: dict[str, float] | None = None,
    max_intensity: float = 2.0,
) -> dict[str, float]:
    """Target weights from a style or (not both) a mixture of styles (weights normalised to sum 1), at an
    intensity (the rest goes to neutral; 0 = neutral, 1 = full style, above 1 exaggerates up to
    ``max_intensity``)."""
    neutral = model.config.neutral_style
    if not 0.0 <= intensity <= max_intensity:  # NaN fails this too
        raise StyleERDError(f"intensity {intensity:g} is outside [0, {max_intensity:g}]")
    if style is not None and mix:
        raise StyleERDError("give a style or a mixture, not both: a mixture names each of its styles")
    if mix:
        if (
            not all(isinstance(w, (int, float)) and not isinstance(w, bool) and 0 <= w < math.inf for w in mix.values())
            or max(mix.values()) <= 0
        ):
            raise StyleERDError(f"mixture weights must be finite, non-negative numbers, not all 0; got {mix}")
        top = max(mix.values())  # scaled to at most 1 first: 1e308 + 1e308 would overflow the sum
        total = sum(v / top for v in mix.values())
        weights = {k: v / top / total for k, v in mix.items()}
    elif style is None:
        raise StyleERDError("give a target style or a mixture")
    else:
        weights = {style: 1.0}
    if intensity == 1.0:
        return weights
    out = {k: v * intensity for k, v in weights.items() if k != neutral}
    out[neutral] = weights.get(neutral, 0.0) * intensity + max(0.0, 1.0 - intensity)
    return out


def part_targets(model: GeneratorWeights, parts: str | dict | None) -> dict[str, dict[str, float] | None]:
    """Per body part (``BODY_PARTS``), its own target: ``"legs=elderly,torso=exhausted:0.5,arms=input"``
    (a style, a style at an intensity, or ``input``: the input's own motion) or the same as a
    dict (values: a style name, target weights, or None / "input"). Parts left out follow the
    stylizer's target."""
    if not parts:
        return {}
    if not isinstance(parts, (str, dict)):
        raise StyleERDError(f"parts: give 'part=style,...' or an object of part -> style, got {parts!r}"[:300])
    if isinstance(parts, str):
        items = [item.partition("=")[::2] for item in parts.split(",") if item.strip()]
        if any(not value for _, value in items):
            raise StyleERDError(
                "--parts: give part=style, part=style:intensity or part=input, e.g. legs=elderly,arms=input; got "
                f"{parts!r}"
            )
        parts = {k.strip(): v.strip() for k, v in items}
    out: dict[str, dict[str, float] | None] = {}
    for part, value in parts.items():
        if part not in BODY_PARTS:
            raise StyleERDError(f"unknown body part {part!r}; valid: {', '.join(BODY_PARTS)}"[:300])
        if value is None or value == "input":
            out[part] = None
        elif isinstance(value, dict):  # a mixture: weights checked and normalised
            out[part] = target_weights(model, None, 1.0, value)
        elif not isinstance(value, str):
            raise StyleERDError(
                f"body part {part}: give a style name, style:intensity, input or a mixture, got {value!r}"[:300]
            )
        else:
            style, _, intensity = str(value).partition(":")
            try:
                level = float(intensity) if intensity else 1.0
            except ValueError:
                raise StyleERDError(f"body part {part}: intensity {intensity!r} is not a number") from None
            out[part] = target_weights(model, style, level)
        if out[part] is not None:
            label_vector(model.config.styles, out[part], "style")  # names checked here, once
    return out


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


@nb.njit(cache=True, nogil=True)
def _root_on_heading(rot, trajectory, out):
    """``out`` = the network's rotations ``[N, J, 4]`` as float64 unit quaternions, the root's
    turned from the heading frame (``trajectory [N, 7]``: root position, heading) back to the
    world (heading * root); one pass, no temporaries."""
    for n in range(rot.shape[0]):
        hw, hx, hy, hz = trajectory[n, 3], trajectory[n, 4], trajectory[n, 5], trajectory[n, 6]
        for j in range(rot.shape[1]):
            w, x, y, z = float(rot[n, j, 0]), float(rot[n, j, 1]), float(rot[n, j, 2]), float(rot[n, j, 3])
            if j == 0:
                w, x, y, z = quat.mul_scalars(hw, hx, hy, hz, w, x, y, z)
            scale = 1.0 / max(np.sqrt(w * w + x * x + y * y + z * z), 1e-12)
            out[n, j, 0], out[n, j, 1], out[n, j, 2], out[n, j, 3] = w * scale, x * scale, y * scale, z * scale


@nb.njit(cache=True, nogil=True, parallel=True)
def _root_on_heading_on_shards(shards, rot, trajectory, out):
    """``_root_on_heading`` on ``shards`` slices of the streams, one per thread."""
    N = rot.shape[0]
    for k in nb.prange(shards):
        s, e = N * k // shards, N * (k + 1) // shards
        _root_on_heading(rot[s:e], trajectory[s:e], out[s:e])


class StreamStylizer:
    """``input_style``, ``content`` and ``target`` apply to every stream, or are lists with
    one value per stream; labels left None are inferred.

    The N streams are slots: ``step(..., rows)`` advances some of them only, and
    ``configure(rows, ...)`` + ``reset(rows)`` give a slot to a new stream (a server)."""

    def __init__(
        self,
        model: GeneratorWeights,
        input_style: str | list[str | None] | None,
        content: str | list[str | None] | None,
        target: dict[str, float] | list[dict[str, float]],
        n_streams: int = 1,
        fps: float = 30.0,
        blend_frames: int = 8,
        labeller: LabellerWeights | None = None,
        backend: str = "numpy",
        threads: int = 1,
        parts: str | dict | None = None,
        root_speed: bool = False,
        pose: str = "input",
    ):
        if pose not in POSES:
            raise StyleERDError(f"pose must be one of {', '.join(POSES)}, got {pose!r}")
        self.model = model = generator_weights(model)  # a torch StyleERD is read as its arrays
        # body parts with their own target (``part_targets``): one more network pass per
        # distinct target, each with its own recurrent state (rows p*N .. p*N + N - 1 of the
        # backend); per joint, the pass whose output it takes (0: the stylizer's target; -1:
        # the input's own rotation)
        self.part_passes: list[np.ndarray] = []
        self.joint_pass = np.zeros(model.config.n_joints, dtype=int)
        joints = part_joints(model.skeleton)
        for part, part_target in part_targets(model, parts).items():
            if part_target is None:
                self.joint_pass[joints[part]] = -1
                continue
            w = label_vector(model.config.styles, part_target, "style").astype(np.float32)
            known = [k for k, v in enumerate(self.part_passes) if np.array_equal(v, w)]
            if not known:
                self.part_passes.append(w)
            self.joint_pass[joints[part]] = 1 + (known[0] if known else len(self.part_passes) - 1)
        self.input_joints = np.nonzero(self.joint_pass < 0)[0]
        # steps of many streams split into this many shards on a thread pool, each shard's
        # network step on one thread (numpy and onnxruntime release the GIL); the numba
        # backend's compiled kernels run on the threads themselves (``kernel_threads``), torch
        # has its own
        self.threads = max(1, threads) if backend not in OWN_THREADS else 1
        self.kernel_threads = max(1, threads) if backend == "numba" else 1
        self.shard_from = SHARD_FROM.get(backend, NUMPY_SHARD_FROM)
        self.backend_name = backend
        # pose "input": the identity transfer's pass, whose output the style's change is taken from; the
        # numpy and numba backends run it on the stylizer's own encoder and neutral stack (``step_pair``)
        self.pose = pose
        paired = pose == "input" and backend in PAIRED
        self.backend = make_backend(
            backend,
            model,
            n_streams * (1 + len(self.part_passes)),
            threads=max(1, threads) // self.threads,
            paired=paired,
        )
        self.identity = (
            make_backend(backend, model, n_streams, threads=max(1, threads) // self.threads)
            if pose == "input" and not paired
            else None
        )
        self.unfamiliar = np.zeros(n_streams)  # per stream, of its last frame (pose "input")
        self.unread = np.zeros(n_streams)  # per stream, of its last frame: 1 - the labeller's familiarity
        # since the stream's reset: frames, and the sums of each frame's unfamiliar share to the network and to
        # the labeller (its state unlike its training streams': the input's style read as neutral)
        self.unfamiliar_sum, self.unread_sum, self.frames = (
            np.zeros(n_streams),
            np.zeros(n_streams),
            np.zeros(n_streams, np.int64),
        )
        self._pool: ThreadPoolExecutor | None = None
        self._sharded_step = (
            threading.Lock()
        )  # steps from several threads take turns: the barrier needs all of one step's shards running
        self.skeleton = model.skeleton
        self.roles = r = BodyRoles.of(self.skeleton)
        self.frame_joints = np.array([r.hips, r.head, *r.left, *r.right], np.int64)  # a posture's body axes
        self.limb_ends, self.eyes = limb_ends(self.skeleton), eyes_above_head(self.skeleton)
        self.stats = model.stats()
        self.fps = fps
        # an inferred style's running mean: its weight for each new reading, and the frames read as they come first
        self.style_ease, self.style_settled = 1.0 - math.exp(-1.0 / (STYLE_SECONDS * fps)), STYLE_SETTLED * fps
        self.n = n_streams
        self.blend_frames = max(1, blend_frames)
        c = model.config
        S, I, C = len(c.styles), len(c.input_styles), len(c.contents)
        self.neutral = c.styles.index(c.neutral_style)
        self.given_style, self.given_content = (
            np.zeros((n_streams, I), np.float32),
            np.zeros((n_streams, C), np.float32),
        )
        self.known_style, self.known_content = np.zeros(n_streams, bool), np.zeros(n_streams, bool)
        self.labeller: NumpyLabeller | None = None
        self.labeller_model = None if labeller is None else labeller_weights(labeller)
        self.blend = _Blend(
            np.zeros((n_streams, S), np.float32),
            np.zeros((n_streams, S), np.float32),
            np.full(n_streams, self.blend_frames),
        )
        self.previous = np.zeros((n_streams, self.skeleton.n_joints, 3))  # global joint positions of the last frame
        self.facing = np.zeros((n_streams, 3))  # facing direction of the last frame
        self.started = np.zeros(n_streams, bool)
        self.labels = (np.zeros((n_streams, I), np.float32), np.zeros((n_streams, C), np.float32))  # used last frame
        # root speed from the network (``root_speed``): the input's path, each frame's ground
        # step scaled by the network's root speed over the input's; the offset it makes
        self.root_speed = root_speed
        root = FeatureLayout(self.skeleton.n_joints).velocities.start  # the velocities' first joint is the root
        self.root_velocity_stats = self.stats.mean[root : root + 3], self.stats.std[root : root + 3], root
        self.root_offset = np.zeros((n_streams, 3))
        self.speed_ratio = np.ones(n_streams)
        self.configure(np.arange(n_streams), input_style, content, target)

    def configure(self, streams, input_style, content, target) -> None:
        """Labels (None: inferred) and target (reached at once, no blend) of some streams:
        one value for all of them, or a list with one per stream."""
        rows = np.asarray(streams, dtype=int).reshape(-1)
        c = self.model.config
        added = set(_per_stream(input_style, len(rows))) & set(c.added_styles)  # checked before any state changes
        if added:
            raise StyleERDError(
                f"style {added.pop()!r} was added to this model as a target only; an input's style is one of: "
                f"{', '.join(c.input_styles)} (or left to be inferred)"
            )
        for labels, names, what, given, known in (
            (input_style, c.input_styles, "input style", self.given_style, self.known_style),
            (content, c.contents, "content", self.given_content, self.known_content),
        ):
            for r, label in zip(rows, _per_stream(labels, len(rows))):
                known[r] = label is not None
                given[r] = 0.0 if label is None else label_vector(names, {label: 1.0}, what)
        w = np.stack([label_vector(c.styles, t, "style") for t in _per_stream(target, len(rows))])
        self.blend.start[rows] = self.blend.end[rows] = w
        self.blend.frame[rows] = self.blend_frames
        if self.labeller is None and not (self.known_style[rows].all() and self.known_content[rows].all()):
            labeller = self.labeller_model or load_labeller_weights(labeller_stem(c))
            if (labeller.config["n_styles"], labeller.config["n_contents"], labeller.config["in_dim"]) != (
                len(c.input_styles),
                len(c.contents),
                c.feature_dim,
            ):
                raise StyleERDError("the labeller does not fit this model's labels: give --input-style and --content")
            stepper = NumpyLabeller
            if self.backend_name == "numba":  # numba's own modules are imported only when asked for
                from styleerd.runtime.compiled import CompiledLabeller as stepper
            self.labeller = stepper(labeller, self.n)

    def reset(self, streams=None) -> None:
        """Forget the past of some (default all) streams: their next frame is a first frame
        (learned initial states)."""
        rows = slice(None) if streams is None else np.asarray(streams, dtype=int)
        self.backend.reset(
            rows if streams is None else np.concatenate([rows + p * self.n for p in range(1 + len(self.part_passes))])
        )
        if self.identity is not None:
            self.identity.reset(None if streams is None else rows)
        self.unfamiliar[rows] = self.unfamiliar_sum[rows] = self.frames[rows] = 0
        self.unread[rows] = self.unread_sum[rows] = 0
        self.started[rows] = False
        self.root_offset[rows], self.speed_ratio[rows] = 0.0, 1.0
        if self.labeller is not None:
            self.labeller.reset(rows)

    def inferred_labels(self) -> list[tuple[str, str]]:
        """Per stream, the (style, content) its last frame was stylised as (given or inferred)."""
        c = self.model.config
        return [
            (c.input_styles[int(s)], c.contents[int(k)])
            for s, k in zip(self.labels[0].argmax(-1), self.labels[1].argmax(-1))
        ]

    def current_weights(self) -> np.ndarray:
        """Each stream's target style weights this frame ``[N, styles]``, part way through a
        blend if one is under way."""
        if self.blend.frame.min() >= self.blend_frames:  # no blend under way (the usual case)
            return self.blend.end
        a = np.minimum(1.0, self.blend.frame / self.blend_frames)[:, None].astype(np.float32)
        return self.blend.start + a * (self.blend.end - self.blend.start)

    def set_target(self, target: dict[str, float], streams=None) -> None:
        """New target weights for some (default all) streams, reached over ``blend_frames``."""
        rows = np.arange(self.n) if streams is None else np.asarray(streams, dtype=int)
        w = label_vector(self.model.config.styles, target, "style")
        now = self.current_weights()
        self.blend.start[rows] = now[rows]
        self.blend.end[rows] = w
        self.blend.frame[rows] = 0

    def step(self, rotations: np.ndarray, positions: np.ndarray, rows=None) -> tuple[np.ndarray, np.ndarray]:
        """One frame of every stream (or of the streams ``rows``) -> the stylised frame. A
        frame with NaN/inf, or too large to stylise, is rejected with an error and leaves the
        state unchanged."""
        n = self.n if rows is None else len(rows)
        sel = _ALL if rows is None else as_rows(rows)  # a slice keeps per-stream state as views
        J = self.skeleton.n_joints
        rotations = np.asarray(rotations, dtype=np.float64).reshape(n, J, 4)
        positions = np.asarray(positions, dtype=np.float64).reshape(n, J, 3)
        if not (rows is None and self.threads > 1 and n >= self.shard_from):
            features = self._features(rotations, positions, sel)
            self._refuse_unless(features[4], sel, rotations, positions)
            return self._advance(sel, features, self.current_weights(), rotations, positions, np.empty(rotations.shape))
        # shards of streams, one per thread, each its features and then its network in one pool
        # phase; BLAS gets one thread per call (two callers each asking BLAS for both cores spin
        # against each other)
        shards = _slices(n, self.threads)
        weights, out = self.current_weights(), np.empty(rotations.shape)  # each shard writes its rows
        features: list = [None] * len(shards)
        checked = threading.Barrier(len(shards))

        def shard(k: int, s: slice):
            try:
                features[k] = self._features(rotations[s], positions[s], s)
            except BaseException:
                checked.abort()  # the others stop waiting
                raise
            try:
                checked.wait()  # every shard's frames are checked before any state changes
            except threading.BrokenBarrierError:
                return None  # another shard failed: its error is the one raised
            return (
                self._advance(s, features[k], weights, rotations[s], positions[s], out[s])
                if all(f[4].all() for f in features)
                else None
            )

        with self._sharded_step, one_blas_thread():
            done = self._on_shards(shard, shards)
        for s, f in zip(shards, features):
            self._refuse_unless(f[4], s, rotations[s], positions[s])
        return out, np.concatenate([p for _, p in done]) if self.root_speed else positions

    def _on_shards(self, f, shards: list[slice]) -> list:
        """``[f(k, shards[k])]``, the first shard on this thread, the others on the pool at the
        same time (one thread fewer to wake: 1.03x the frames/s at 1,000 streams on 2 threads);
        every call has ended when this returns or raises."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads - 1, thread_name_prefix="styleerd-shard")
        futures = [self._pool.submit(f, k, s) for k, s in enumerate(shards) if k]
        try:
            first = f(0, shards[0])
        finally:
            wait(futures)  # every call has ended, whichever raised
        return [first, *(future.result() for future in futures)]

    def _refuse_unless(self, ok: np.ndarray, sel, rotations: np.ndarray, positions: np.ndarray) -> None:
        """Raise for the first stream of ``sel`` whose frame cannot be stylised (``ok`` False:
        a NaN or infinite value, or values so large the network would overflow: normalised
        features are O(1), 1e6 is input in the wrong units or garbage)."""
        if ok.all():
            return
        streams = np.arange(self.n)[sel]
        bad = np.argwhere(~np.isfinite(rotations).all(-1) | ~np.isfinite(positions).all(-1))
        if len(bad):
            raise StyleERDError(
                f"frame rejected: stream {streams[bad[0][0]]}, joint {self.skeleton.names[bad[0][1]]!r} has a NaN or "
                "infinite value"
            )
        raise StyleERDError(
            f"frame rejected: stream {streams[np.nonzero(~ok)[0][0]]}: its values are too large to stylise"
        )

    def _features(self, rotations: np.ndarray, positions: np.ndarray, sel):
        return stream_features(
            rotations,
            positions,
            self.previous[sel],
            self.facing[sel],
            self.started[sel],
            self.skeleton,
            self.roles,
            self.fps,
            self.stats,
            MAX_FEATURE,
            threads=self.kernel_threads,
        )

    def _pass_rows(self, sel, p: int):
        """The backend's rows of pass ``p`` for the streams ``sel``."""
        if isinstance(sel, slice):
            start, stop, _ = sel.indices(self.n)
            return slice(p * self.n + start, p * self.n + stop)
        return sel + p * self.n

    def _network(
        self, sel, x, style, content, weights: np.ndarray, identity: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The network's rotations and (normalised) velocities for the streams ``sel``: one
        pass, or with body parts of their own target, each joint's rotation from its part's
        pass (velocities from the stylizer's target); and with ``identity`` (pose "input"), the
        identity transfer's rotations."""
        rows = (None if sel is _ALL else sel) if not self.part_passes else self._pass_rows(sel, 0)
        if identity is None:
            (rot, vel), same = self.backend.step(x, style, content, weights, rows), None
        elif self.identity is None:  # paired
            rot, vel, same = self.backend.step_pair(x, style, content, weights, identity, rows)
        else:
            rot, vel = self.backend.step(x, style, content, weights, rows)
            same = self.identity.step(x, style, content, identity, None if sel is _ALL else sel)[0]
        if not self.part_passes:
            return rot, vel, same
        rot = rot.copy()
        for p, w in enumerate(self.part_passes, 1):
            joints = self.joint_pass == p
            rot[:, joints] = self.backend.step(
                x, style, content, np.broadcast_to(w, weights.shape), self._pass_rows(sel, p)
            )[0][:, joints]
        return rot, vel, same

    def _on_heading(self, rot: np.ndarray, traj: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``_root_on_heading`` into ``out``, on the kernel threads from ``PARALLEL_FROM`` streams."""
        rot = np.ascontiguousarray(rot)
        on_kernel_threads(self.kernel_threads, len(out), _root_on_heading, _root_on_heading_on_shards, rot, traj, out)
        return out

    def _stylised_root(self, sel, x: np.ndarray, velocities: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """``positions`` with the root moved by the offset the root speed makes: each frame's
        ground step of the input root is scaled by the network's root speed over the
        input's (both in the features' units per second, heading frame), smoothed over a few
        frames and kept within [1/2.5, 2.5]; standing still (under 5 % of a leg length per
        second) keeps the input's step."""
        mean, std, root = self.root_velocity_stats
        net = velocities[:, :3] * std + mean
        given = x[:, root : root + 3] * std + mean
        s_net, s_in = np.hypot(net[:, 0], net[:, 2]), np.hypot(given[:, 0], given[:, 2])
        moving = s_in > 0.05 * self.roles.leg_length
        ratio = np.where(moving, np.clip(s_net / np.maximum(s_in, 1e-9), 0.4, 2.5), 1.0)
        if self.pose == "input":  # where the legs are the input's own (unfamiliar), so is the pace
            ratio = 1.0 + (ratio - 1.0) * (1.0 - self.unfamiliar[sel])
        self.speed_ratio[sel] = 0.7 * self.speed_ratio[sel] + 0.3 * ratio
        step = np.where(self.started[sel, None], positions[:, 0] - self.previous[sel, 0], 0.0)
        step[:, 1] = 0.0  # height stays the input's
        self.root_offset[sel] += (self.speed_ratio[sel, None] - 1.0) * step
        out = positions.copy()
        out[:, 0] += self.root_offset[sel]
        return out

    def _advance(
        self, sel, features, weights: np.ndarray, rotations: np.ndarray, positions: np.ndarray, out: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The network and the state updates of the streams ``sel`` (``_ALL``: all), whose
        input frame is ``rotations``, ``positions``; returns the output frame (its rotations
        written into ``out``)."""
        x, traj, g, facing, _ = features
        rows = None if sel is _ALL else sel
        style, content = self.given_style[sel], self.given_content[sel]
        if self.labeller is not None:
            one_thread = self.backend_name == "numba" and len(x) >= LABELLER_ONE_BLAS_FROM
            with one_blas_thread() if one_thread else nullcontext():
                p_style, p_content, labeller_state = self.labeller.step(x, rows)
                familiar = self.labeller.familiarity(labeller_state, self.frames[sel])
            p_style = toward_neutral(p_style, self.neutral, familiar)
            # one frame's reading can swing (a wave read as active every few frames) and the style's change would
            # swing with it: once the labeller has settled, the style used follows its readings over STYLE_SECONDS
            last, settled = self.labels[0][sel], (self.frames[sel] > self.style_settled)[:, None]
            p_style = np.where(settled, last + self.style_ease * (p_style - last), p_style)
            if familiar is not None:
                self.unread[sel] = np.where(self.known_style[sel], 0.0, 1.0 - familiar)
                self.unread_sum[sel] += self.unread[sel]
            style = np.where(self.known_style[sel, None], style, p_style)
            content = np.where(self.known_content[sel, None], content, p_content)
        identity = None
        if self.pose == "input":
            identity = np.zeros_like(weights[sel])
            identity[:, : style.shape[1]] = style  # the input's own style, given or inferred
        rot, vel, same = self._network(sel, x, style, content, weights[sel], identity)
        if self.root_speed:
            positions = self._stylised_root(sel, x, vel, positions)
        self._on_heading(rot, traj, out)
        if identity is not None:
            same = self._on_heading(same, traj, np.empty_like(out))
            bounds = self._unfamiliar_bounds(sel)
            weight = np.empty(len(out))
            blend = (np.ascontiguousarray(rotations), same, bounds, weight, identity, positions, g, facing)
            # a body part with a target of its own: the whole body taken towards that target, the part's joints kept
            parts = [
                (self.joint_pass == p, self._blend_towards_the_input(out.copy(), w, *blend))
                for p, w in enumerate(self.part_passes, 1)
            ]
            self._blend_towards_the_input(out, weights[sel], *blend)
            for joints, turned in parts:
                out[:, joints] = turned[:, joints]
            self.unfamiliar[sel] = weight
            self.unfamiliar_sum[sel] += weight
        if len(self.input_joints):  # parts that keep the input's own motion
            out[:, self.input_joints] = quat.normalize(rotations[:, self.input_joints])
        if self.labeller is not None:
            self.labeller.h[sel] = labeller_state
        self.previous[sel], self.facing[sel], self.started[sel] = g, facing, True
        self.labels[0][sel], self.labels[1][sel] = style, content
        self.blend.frame[sel] += 1
        self.frames[sel] += 1
        return out, positions

    def _unfamiliar_bounds(self, sel) -> np.ndarray:
        """``[N, 2]``: the least and the most each stream's unfamiliarity may be this frame: on a first frame,
        anything; then down by at most RELEASE and up by at most RISE from the last frame's, so neither the
        network's pose nor the input's pops in."""
        last, started = self.unfamiliar[sel], self.started[sel]
        return np.stack([np.where(started, last - RELEASE, 0.0), np.where(started, last + RISE, 1.0)], -1)

    def _blend_towards_the_input(
        self, styled, weights, given, same, bounds, weight, own, positions, g, facing
    ) -> np.ndarray:
        """``styled`` (the network's output into ``weights``) taken, in place, towards the input turned
        by the change from its own style ``own`` to ``weights`` as far as the input is unfamiliar
        (``_towards_the_input``, compiled): the target's posture (``runtime.posture``; rotations, and
        joint offsets where measured) or, for a model without one, the network's change."""
        none = np.empty((len(self.model.config.styles), 0, 3))
        posture = none if self.model.posture is None else self.model.posture
        offsets = none if self.model.posture_offsets is None else self.model.posture_offsets
        on_kernel_threads(
            self.kernel_threads,
            len(styled),
            _towards_the_input,
            _towards_the_input_on_shards,
            *(given, same, styled, np.ascontiguousarray(weights - own, np.float64), posture, offsets, bounds),
            *(*self.model.familiar, weight, np.ascontiguousarray(positions, np.float64), g, facing),
            *(
                self.frame_joints,
                self.model.posture_frame == "body",
                self.model.skeleton.parents,
                self.limb_ends,
                self.eyes,
            ),
        )
        return styled


@nb.njit(cache=True, nogil=True)
def _children(parents):
    """Each joint's children: ``kids[first[j]:first[j + 1]]``."""
    J = len(parents)
    first, kids, seen = np.zeros(J + 1, np.int64), np.empty(max(J - 1, 0), np.int64), np.zeros(J, np.int64)
    for k in range(1, J):
        first[parents[k] + 1] += 1
    for j in range(J):
        first[j + 1] += first[j]
    for k in range(1, J):
        p = parents[k]
        kids[first[p] + seen[p]] = k
        seen[p] += 1
    return first, kids


@nb.njit(cache=True, nogil=True)
def _reach(rot, translations, given, axes, offsets, parents, first, kids, limb_ends, G, X):
    """One stream's pose ``rot [J, 4]`` (local rotations, the root's in the world) turned in place so
    that each joint's children go towards the input's joint positions ``given [J, 3]`` (global) moved
    by ``offsets [J, 3]`` (along the rows of ``axes [3, 3]``: the posture's frame, ``_frame_axes``):
    down the chain, each joint but the root turned by the shortest arc from its children's summed
    bone vectors to the vectors to their targets (so a bone's twist about itself is kept; a bone's
    length is, so a target may be out of reach). The first joint of a two-bone limb (``limb_ends
    [J]``: its end joint, else -1) aims its bone where ``_limb_elbow`` puts the middle joint, so the
    end reaches its target too: turned one joint at a time, a forearm already raised only slides the
    hand along itself. ``first``, ``kids``: the children (``_children``); ``G [J, 4]``, ``X [J, 3]``:
    scratch."""
    J = rot.shape[0]
    for j in range(J):
        p = parents[j]
        if p < 0:
            G[j, 0], G[j, 1], G[j, 2], G[j, 3] = rot[j, 0], rot[j, 1], rot[j, 2], rot[j, 3]
            X[j, 0], X[j, 1], X[j, 2] = given[j, 0], given[j, 1], given[j, 2]
            continue
        G[j, 0], G[j, 1], G[j, 2], G[j, 3] = quat.mul_scalars(
            G[p, 0], G[p, 1], G[p, 2], G[p, 3], rot[j, 0], rot[j, 1], rot[j, 2], rot[j, 3]
        )
        vx, vy, vz = quat.mul_vec_scalars(
            G[p, 0], G[p, 1], G[p, 2], G[p, 3], translations[j, 0], translations[j, 1], translations[j, 2]
        )
        X[j, 0], X[j, 1], X[j, 2] = X[p, 0] + vx, X[p, 1] + vy, X[p, 2] + vz
        if first[j] == first[j + 1]:  # a leaf keeps its rotation
            continue
        cx, cy, cz, dx, dy, dz = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        for i in range(first[j], first[j + 1]):
            k = kids[i]
            vx, vy, vz = quat.mul_vec_scalars(
                G[j, 0], G[j, 1], G[j, 2], G[j, 3], translations[k, 0], translations[k, 1], translations[k, 2]
            )
            tx, ty, tz = _target(given, offsets, axes, X, k, j)
            cx, cy, cz, dx, dy, dz = cx + vx, cy + vy, cz + vz, dx + tx, dy + ty, dz + tz  # bones, and to targets
        h = limb_ends[j]
        if h >= 0:  # a limb: its middle joint where it and the end meet their targets best together
            ex, ey, ez = _target(given, offsets, axes, X, h, j)
            upper = np.sqrt(cx * cx + cy * cy + cz * cz)
            lower = np.sqrt(translations[h, 0] ** 2 + translations[h, 1] ** 2 + translations[h, 2] ** 2)
            dx, dy, dz = _limb_elbow(dx, dy, dz, ex, ey, ez, upper, lower)
        rw, rx, ry, rz = quat.between_scalars(cx, cy, cz, dx, dy, dz)  # none: no change
        G[j, 0], G[j, 1], G[j, 2], G[j, 3] = quat.mul_scalars(rw, rx, ry, rz, G[j, 0], G[j, 1], G[j, 2], G[j, 3])
        rot[j, 0], rot[j, 1], rot[j, 2], rot[j, 3] = quat.mul_scalars(
            G[p, 0], -G[p, 1], -G[p, 2], -G[p, 3], G[j, 0], G[j, 1], G[j, 2], G[j, 3]
        )


@nb.njit(cache=True, nogil=True, inline="always")
def _target(given, offsets, axes, X, k, j):
    """Joint ``k``'s target (the input's ``given [J, 3]`` moved by ``offsets [J, 3]`` along the rows of
    ``axes``) from joint ``j``'s position in ``X [J, 3]``."""
    a, b, c = offsets[k, 0], offsets[k, 1], offsets[k, 2]
    return (
        given[k, 0] + a * axes[0, 0] + b * axes[1, 0] + c * axes[2, 0] - X[j, 0],
        given[k, 1] + a * axes[0, 1] + b * axes[1, 1] + c * axes[2, 1] - X[j, 1],
        given[k, 2] + a * axes[0, 2] + b * axes[1, 2] + c * axes[2, 2] - X[j, 2],
    )


@nb.njit(cache=True, nogil=True)
def _limb_elbow(ex, ey, ez, tx, ty, tz, upper, lower):
    """Where a two-bone limb's middle joint goes, from the limb's first joint, given its target ``e``
    and the end's target ``t`` (both from the first joint): the point at ``upper`` from the first
    joint nearest, in the least squares, to its target and to the sphere of radius ``lower`` about the
    end's (from which the lower bone reaches it); ``torch_quat.limb_elbow``'s twin."""
    x, y, z = ex, ey, ez
    for _ in range(LIMB_ROUNDS):
        n = upper / max(np.sqrt(x * x + y * y + z * z), 1e-12)
        x, y, z = x * n, y * n, z * n
        rx, ry, rz = x - tx, y - ty, z - tz
        m = lower / max(np.sqrt(rx * rx + ry * ry + rz * rz), 1e-12)
        x, y, z = 0.5 * (ex + tx + rx * m), 0.5 * (ey + ty + ry * m), 0.5 * (ez + tz + rz * m)
    n = upper / max(np.sqrt(x * x + y * y + z * z), 1e-12)
    return x * n, y * n, z * n


@nb.njit(cache=True, nogil=True)
def _ends_below_the_eyes(offsets, given, axes, head, eyes, limb_ends, parents, out):
    """Into ``out``, ``offsets [J, 3]`` (along ``axes``' rows: left, up, forward) with each limb's end's
    (``limb_ends``) rise ``r`` cut to the smooth minimum ``(r^-3 + b^-3)^(-1/3)`` of itself and how far
    ``b`` the end is below the eyes, ``eyes`` above the ``head`` joint, in the input's pose ``given [J,
    3]`` (``motion.humanoid.eyes_above_head``; none at or above them), and its middle joint's rise cut in
    the same proportion, so the limb rises as one: a posture measured on walks raises hands that hang at
    the sides, and raised as far, a guard at the chin goes over the head (a cheer, not a punch). The
    minimum is smooth so that a hand moving up past the eyes (a swimmer's stroke) is not held still
    below them. ``torch_quat.ends_below_the_eyes``' twin."""
    out[:] = offsets
    for j in range(len(limb_ends)):
        m = limb_ends[j]
        if m >= 0:
            below = eyes  # how far the end is below the eyes
            for k in range(3):
                below += (given[head, k] - given[m, k]) * axes[1, k]
            rise = offsets[m, 1]
            if rise > 0.0:
                out[m, 1] = rise * below / (rise**3 + below**3) ** (1.0 / 3.0) if below > 0.0 else 0.0
                if offsets[parents[m], 1] > 0.0:
                    out[parents[m], 1] *= out[m, 1] / rise


@nb.njit(cache=True, nogil=True)
def _frame_axes(g, facing, joints, body, axes):
    """Into ``axes [3, 3]``, as rows (left, up, forward), the frame a posture's offsets are in on one
    stream's pose (global positions ``g [J, 3]``): where ``body``, the body's own
    (``motion.kinematics.body_axes`` of ``joints``: hips, head, left hip and shoulder, right ones),
    else its heading's, from its facing direction (``heading_axes``)."""
    if body:
        h, top, l0, l1, r0, r1 = joints[0], joints[1], joints[2], joints[3], joints[4], joints[5]
        for k in range(3):
            axes[1, k] = g[top, k] - g[h, k]
            axes[0, k] = g[l0, k] + g[l1, k] - g[r0, k] - g[r1, k]
        for row, a, b in ((2, 0, 1), (0, 1, 2)):  # forward = across x up, then left = up x forward
            x = axes[a, 1] * axes[b, 2] - axes[a, 2] * axes[b, 1]
            y = axes[a, 2] * axes[b, 0] - axes[a, 0] * axes[b, 2]
            z = axes[a, 0] * axes[b, 1] - axes[a, 1] * axes[b, 0]
            axes[row, 0], axes[row, 1], axes[row, 2] = x, y, z
        for row in range(3):
            d = 1.0 / max(np.sqrt(axes[row, 0] ** 2 + axes[row, 1] ** 2 + axes[row, 2] ** 2), 1e-9)
            axes[row, 0], axes[row, 1], axes[row, 2] = axes[row, 0] * d, axes[row, 1] * d, axes[row, 2] * d
        return
    fx, fz = facing[0], facing[2]
    d = np.sqrt(fx * fx + fz * fz)
    fx, fz = (fx / d, fz / d) if d > 1e-12 else (0.0, 1.0)
    axes[0, 0], axes[0, 1], axes[0, 2] = fz, 0.0, -fx
    axes[1, 0], axes[1, 1], axes[1, 2] = 0.0, 1.0, 0.0
    axes[2, 0], axes[2, 1], axes[2, 2] = fx, 0.0, fz


@nb.njit(cache=True, nogil=True, inline="always")
def _weighted(weights, per_style, j):
    """Joint ``j``'s vector of ``per_style [styles, J, 3]`` summed by ``weights [styles]``."""
    x, y, z = 0.0, 0.0, 0.0
    for s in range(len(weights)):
        k = weights[s]
        x, y, z = x + k * per_style[s, j, 0], y + k * per_style[s, j, 1], z + k * per_style[s, j, 2]
    return x, y, z


@nb.njit(cache=True, nogil=True, inline="always")
def _same_row(rows, a, b):
    """Whether rows ``a`` and ``b`` of ``rows [N, K]`` are equal."""
    for k in range(rows.shape[1]):
        if rows[a, k] != rows[b, k]:
            return False
    return True


@nb.njit(cache=True, nogil=True)
def _towards_the_input(
    given,
    same,
    styled,
    diff,
    posture,
    offsets,
    bounds,
    familiar,
    unfamiliar,
    weight,
    translations,
    globals_,
    facing,
    frame_joints,
    body,
    parents,
    limb_ends,
    eyes,
):
    """Per stream (``[N, J, 4]`` each): its unfamiliarity ``weight`` (the identity output ``same``'s
    mean joint angle to the input ``given``, degrees, from ``familiar`` (0) to ``unfamiliar`` (1),
    within ``bounds [N, 2]``: least, most), and ``styled`` slerped by it towards the input turned by the style's change,
    in place. The change from the input's own style to the target, ``diff [N, styles]`` (weights
    less the own style's): per joint (local rotations, the roots' in the world) the rotation of the
    postures' rotation vectors ``posture [styles, J, 3]`` weighted by it (``[styles, 0, 3]``: no
    posture, the network's own change inv(same) * styled), then, with posture ``offsets [styles, J,
    3]`` (``[styles, 0, 3]``: none), turned so that the joints go where the input's are moved by the
    offsets weighted alike, a limb's end's rise eased below the eyes (``_ends_below_the_eyes``,
    ``_reach``; ``translations``, ``globals_``: the input's local joint translations and global
    positions; ``limb_ends``, ``eyes``: ``motion.humanoid``'s). The offsets are along the body's own
    axes where ``body`` (from its joints ``frame_joints``), else along its heading's (from its facing directions
    ``facing``): ``_frame_axes``. The posture is put together only for a stream that needs it, and
    once for a run of streams with the same change of style (a crowd's)."""
    N, J = given.shape[0], given.shape[1]
    turn, reach = posture.shape[1] == J, offsets.shape[1] == J
    target, moved, G, X, axes = np.empty((J, 4)), np.empty((J, 3)), np.empty((J, 4)), np.empty((J, 3)), np.empty((3, 3))
    change, capped = np.empty((J, 4)), np.empty((J, 3))
    first, kids = _children(parents)
    last = -1  # the stream whose change of style ``change`` and ``moved`` hold: the next may share it
    for n in range(N):
        total = 0.0
        for j in range(J):
            gw, gx, gy, gz = given[n, j, 0], given[n, j, 1], given[n, j, 2], given[n, j, 3]
            d = 1.0 / max(np.sqrt(gw * gw + gx * gx + gy * gy + gz * gz), 1e-12)
            w, x, y, z = quat.mul_scalars(
                same[n, j, 0], -same[n, j, 1], -same[n, j, 2], -same[n, j, 3], gw * d, gx * d, gy * d, gz * d
            )
            total += 2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), abs(w))
        u = min(1.0, max(0.0, (np.degrees(total / J) - familiar) / (unfamiliar - familiar)))
        weight[n] = u = min(max(u, bounds[n, 0]), bounds[n, 1])
        if u <= 0.0:
            continue
        if last < 0 or not _same_row(diff, n, last):
            for j in range(J):
                if turn:  # the weighted rotation vector, as a quaternion
                    x, y, z = _weighted(diff[n], posture, j)
                    angle = np.sqrt(x * x + y * y + z * z)
                    f = np.sin(0.5 * angle) / max(angle, 1e-12)
                    change[j, 0], change[j, 1], change[j, 2], change[j, 3] = np.cos(0.5 * angle), x * f, y * f, z * f
                if reach:
                    moved[j, 0], moved[j, 1], moved[j, 2] = _weighted(diff[n], offsets, j)
            last = n
        for j in range(J):
            if turn:
                cw, cx, cy, cz = change[j, 0], change[j, 1], change[j, 2], change[j, 3]
            else:
                cw, cx, cy, cz = quat.mul_scalars(
                    same[n, j, 0],
                    -same[n, j, 1],
                    -same[n, j, 2],
                    -same[n, j, 3],
                    styled[n, j, 0],
                    styled[n, j, 1],
                    styled[n, j, 2],
                    styled[n, j, 3],
                )
            gw, gx, gy, gz = given[n, j, 0], given[n, j, 1], given[n, j, 2], given[n, j, 3]
            d = 1.0 / max(np.sqrt(gw * gw + gx * gx + gy * gy + gz * gz), 1e-12)
            target[j, 0], target[j, 1], target[j, 2], target[j, 3] = quat.mul_scalars(
                gw * d, gx * d, gy * d, gz * d, cw, cx, cy, cz
            )
        if reach:
            _frame_axes(globals_[n], facing[n], frame_joints, body, axes)
            _ends_below_the_eyes(moved, globals_[n], axes, frame_joints[1], eyes, limb_ends, parents, capped)
            _reach(target, translations[n], globals_[n], axes, capped, parents, first, kids, limb_ends, G, X)
        for j in range(J):
            sw, sx, sy, sz = styled[n, j, 0], styled[n, j, 1], styled[n, j, 2], styled[n, j, 3]
            tw, tx, ty, tz = target[j, 0], target[j, 1], target[j, 2], target[j, 3]
            dot = sw * tw + sx * tx + sy * ty + sz * tz
            if dot < 0.0:  # the shorter arc
                tw, tx, ty, tz, dot = -tw, -tx, -ty, -tz, -dot
            if u >= 1.0:  # all the way: the target itself, as the arc gives it, without its sines
                a, b = 0.0, 1.0
            else:
                theta = np.arccos(min(1.0, dot))
                s = np.sin(theta)
                a, b = (1.0 - u, u) if s < 1e-6 else (np.sin((1.0 - u) * theta) / s, np.sin(u * theta) / s)
            w, x, y, z = a * sw + b * tw, a * sx + b * tx, a * sy + b * ty, a * sz + b * tz
            d = 1.0 / max(np.sqrt(w * w + x * x + y * y + z * z), 1e-12)
            styled[n, j, 0], styled[n, j, 1], styled[n, j, 2], styled[n, j, 3] = w * d, x * d, y * d, z * d


@nb.njit(cache=True, nogil=True, parallel=True)
def _towards_the_input_on_shards(
    shards,
    given,
    same,
    styled,
    diff,
    posture,
    offsets,
    bounds,
    familiar,
    unfamiliar,
    weight,
    translations,
    globals_,
    facing,
    frame_joints,
    body,
    parents,
    limb_ends,
    eyes,
):
    """``_towards_the_input`` on ``shards`` slices of the streams, one per thread."""
    N = given.shape[0]
    for k in nb.prange(shards):
        s, e = N * k // shards, N * (k + 1) // shards
        _towards_the_input(
            given[s:e],
            same[s:e],
            styled[s:e],
            diff[s:e],
            posture,
            offsets,
            bounds[s:e],
            familiar,
            unfamiliar,
            weight[s:e],
            translations[s:e],
            globals_[s:e],
            facing[s:e],
            frame_joints,
            body,
            parents,
            limb_ends,
            eyes,
        )


def as_rows(rows) -> slice | np.ndarray:
    """Stream rows as a slice where they are consecutive and ascending (a server's batch of all its
    streams: every per-stream array is then a view, nothing gathered and written back), else as
    indices."""
    rows = np.asarray(rows, dtype=int)
    if len(rows) and (np.diff(rows) == 1).all():  # one row: no differences, a slice of one
        return slice(int(rows[0]), int(rows[0]) + len(rows))
    return rows


def _slices(n: int, parts: int) -> list[slice]:
    return [slice(n * k // parts, n * (k + 1) // parts) for k in range(parts)]
