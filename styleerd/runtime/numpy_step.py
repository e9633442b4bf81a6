"""The network's per-frame step in numpy: the generator's weights laid out for ``x @ W + b``
and its arithmetic fused by hand (no framework overhead), for N streams whose recurrent state
the backend keeps; and the online labeller's step the same way. The compiled backend
(``runtime.compiled``) and the ONNX export (``runtime.onnx_export``) build on these."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from styleerd.model.stored import (
    GeneratorWeights,
    LabellerWeights,
    familiarity,
    generator_weights,
    labeller_weights,
)
from styleerd.motion import quat


@dataclass
class StepWeights:
    """The generator's parameters as float32 arrays laid out for ``x @ W + b``."""

    encoder: list[tuple[np.ndarray, np.ndarray]]
    neutral: list[
        tuple[np.ndarray, np.ndarray]
    ]  # per layer: [W_input; W_hidden] [in + H, 4H] (for [x | h] @ W), b [4H]
    branches: list[list[tuple[np.ndarray, np.ndarray]]]
    branch_styles: list[int]
    decoder: list[tuple[np.ndarray, np.ndarray]]
    neutral_init: tuple[np.ndarray, np.ndarray]  # h0, c0: [nC, L0, H]
    branch_init: tuple[np.ndarray, np.ndarray]  # h0, c0: [K, L1, H]
    n_joints: int
    hidden: int
    input_styles: int  # the style labels the encoder reads; targets cover these and the added styles
    decoder_added: np.ndarray | None = None  # [added styles, decoder[0] outputs]: their target rows, apart
    # ``pose_change``: the rotation features' mean and std [4J], to read the input's own rotations back; None: the
    # decoder's rotations are the pose
    given: tuple[np.ndarray, np.ndarray] | None = None


def step_weights(model) -> StepWeights:
    """The step's layout of a generator (``GeneratorWeights`` or a torch ``StyleERD``)."""
    model = generator_weights(model)
    sd = model.arrays

    def linear(prefix: str, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
        return [(sd[f"{prefix}.{2 * i}.weight"].T.copy(), sd[f"{prefix}.{2 * i}.bias"]) for i in range(count)]

    def lstm(prefix: str, layers: int) -> list[tuple[np.ndarray, np.ndarray]]:
        return [
            (
                np.concatenate([sd[f"{prefix}.weight_ih_l{i}"].T, sd[f"{prefix}.weight_hh_l{i}"].T]),
                sd[f"{prefix}.bias_ih_l{i}"] + sd[f"{prefix}.bias_hh_l{i}"],
            )
            for i in range(layers)
        ]

    c = model.config
    return StepWeights(
        encoder=linear("encoder", len(c.encoder)),
        neutral=lstm("neutral", c.neutral_layers),
        branches=[lstm(f"branches.{k}", c.style_layers) for k in range(len(model.branch_styles))],
        branch_styles=list(model.branch_styles),
        decoder=linear("decoder", len(c.decoder) + 1),
        neutral_init=(sd["neutral_h0"], sd["neutral_c0"]),
        branch_init=(sd["branch_h0"], sd["branch_c0"]),
        n_joints=c.n_joints,
        hidden=c.hidden,
        input_styles=len(c.input_styles),
        decoder_added=sd.get("decoder_added"),
        given=(sd["mean"][: 4 * c.n_joints], sd["std"][: 4 * c.n_joints]) if c.pose_change else None,
    )


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * np.tanh(0.5 * x) + 0.5


def _numpy_cell(g: np.ndarray, b: np.ndarray, h: np.ndarray, c: np.ndarray) -> None:
    """An LSTM cell's update from its pre-activations ``g [N, 4H]`` (bias not yet added; torch
    gate order i, f, g, o): writes h, c ``[N, H]`` in place."""
    H = h.shape[-1]
    g += b
    s = _sigmoid(g)
    c[:] = s[:, H : 2 * H] * c + s[:, :H] * np.tanh(g[:, 2 * H : 3 * H])
    h[:] = s[:, 3 * H :] * np.tanh(c)


def _lstm_stack(layers, x: np.ndarray, h: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Run stacked LSTM cells one step; updates h, c [N, L, H] in place and returns the last
    layer's output. Each layer is one product [x | h] @ [W_input; W_hidden] into one buffer
    (at 1,000 streams 3x faster than two products, their temporaries and a sum)."""
    N, H = h.shape[0], h.shape[2]
    xh, g = np.empty((N, max(x.shape[1], H) + H), np.float32), np.empty((N, 4 * H), np.float32)
    for i, (w, b) in enumerate(layers):
        k = x.shape[1]
        xh[:, :k], xh[:, k : k + H] = x, h[:, i]
        np.matmul(xh[:, : k + H], w, out=g)
        _numpy_cell(g, b, h[:, i], c[:, i])
        x = h[:, i]
    return x


def _rotations(y: np.ndarray, n_joints: int) -> tuple[np.ndarray, np.ndarray]:
    q = y[:, : 4 * n_joints].reshape(len(y), n_joints, 4)
    return q / np.maximum(np.sqrt(np.einsum("nji,nji->nj", q, q))[..., None], 1e-8), y[:, 4 * n_joints :]


class NumpyBackend:
    """``paired``: ``step_pair`` runs a second target on the same encoder and neutral stack (their
    state depends on the input alone), with style branches of its own (``hb2``, ``cb2``)."""

    rows_in_place = False  # streams stepped by index: their rows gathered before the step, written back after

    def __init__(self, model: GeneratorWeights, n_streams: int, paired: bool = False):
        self.w, self.n = step_weights(model), n_streams
        w, H = self.w, self.w.hidden
        # streams first: a shard of streams (a slice of rows) is one contiguous block
        self.h = np.zeros((n_streams, len(w.neutral), H), np.float32)
        self.c = np.zeros_like(self.h)
        self.hb = np.zeros((n_streams, len(w.branches), len(w.branches[0]) if w.branches else 0, H), np.float32)
        self.cb = np.zeros_like(self.hb)
        self.hb2, self.cb2 = (np.zeros_like(self.hb), np.zeros_like(self.hb)) if paired else (None, None)
        self.first = np.ones(n_streams, dtype=bool)

    def reset(self, streams: np.ndarray | None = None) -> None:
        self.first[slice(None) if streams is None else streams] = True

    def step(
        self, x: np.ndarray, style: np.ndarray, content: np.ndarray, target: np.ndarray, rows: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """One frame of every stream, or of the streams ``rows`` only (the others keep their
        state): what a server with streams arriving at different times steps. Rows given as a
        slice are stepped in place (views), so disjoint slices may step concurrently."""
        rot, vel, _ = self._stepped(x, style, content, target, None, rows)
        return rot, vel

    def step_pair(
        self,
        x: np.ndarray,
        style: np.ndarray,
        content: np.ndarray,
        target: np.ndarray,
        second: np.ndarray,
        rows: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``step`` to ``target``, and the rotations the same step gives to the ``second`` target
        (a backend made ``paired``, its streams stepped so from their first frame): what two
        backends stepped alike give, for one encoder and neutral stack instead of two."""
        if self.hb2 is None:
            raise ValueError("step_pair needs a backend made paired")
        return self._stepped(x, style, content, target, np.ascontiguousarray(second, np.float32), rows)

    def _stepped(self, x, style, content, target, second, rows) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        f32 = np.ascontiguousarray
        x, style, content, target = (
            f32(x, np.float32),
            f32(style, np.float32),
            f32(content, np.float32),
            f32(target, np.float32),
        )
        sel = slice(None) if rows is None else rows
        whole = (self.h, self.c, self.hb, self.cb, self.hb2, self.cb2, self.first)
        by_index = not isinstance(sel, slice)
        if by_index and self.rows_in_place:  # the step reads and writes the streams' rows itself
            state_rows = np.asarray(sel, np.int64)
            if len(np.unique(state_rows)) != len(state_rows):
                raise ValueError("a stream is stepped at most once a step (its rows repeat)")
            return self._posed(x, *self._arithmetic(x, style, content, target, second, *whole, state_rows))
        state = whole if rows is None else tuple(None if a is None else a[sel] for a in whole)
        rot, vel, rot2 = self._arithmetic(x, style, content, target, second, *state)
        if by_index:  # rows by index gave copies: put them back
            for a, part in zip(whole, state):
                if a is not None:
                    a[sel] = part
        return self._posed(x, rot, vel, rot2)

    def _posed(self, x, rot, vel, rot2) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        if self.w.given is not None:
            rot, rot2 = posed(self.w, x, rot), None if rot2 is None else posed(self.w, x, rot2)
        return rot, vel, rot2

    def _arithmetic(
        self, x, style, content, target, second, h, c, hb, cb, hb2, cb2, first
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The step on explicit state arrays (updated in place); the numba backend overrides it."""
        if first.any():
            _start(self.w, content, first, h, c, hb, cb, *((hb2, cb2) if second is not None else ()))
        z = _dense_layers(np.concatenate([x, style, content], -1), self.w.encoder)
        out = _lstm_stack(self.w.neutral, z, h, c)
        rot, vel = _head(self.w, z, out.copy(), target, hb, cb)
        return rot, vel, None if second is None else _head(self.w, z, out.copy(), second, hb2, cb2)[0]


def _start(w: StepWeights, content, first, h, c, hb, cb, hb2=None, cb2=None) -> None:
    """The streams ``first`` start from the learned initial states (the neutral stack's by content)."""
    rows = np.nonzero(first)[0]
    h[rows] = np.einsum("nc,clh->nlh", content[rows], w.neutral_init[0])
    c[rows] = np.einsum("nc,clh->nlh", content[rows], w.neutral_init[1])
    hb[rows], cb[rows] = w.branch_init
    if hb2 is not None:
        hb2[rows], cb2[rows] = w.branch_init
    first[:] = False


def _head(w: StepWeights, z, out, target, hb, cb) -> tuple[np.ndarray, np.ndarray]:
    """The style branches ``target`` weights (their states hb, cb [N, K, L, H] advanced in place)
    added to the neutral stack's output ``out``, then the decoder."""
    for k, s in enumerate(w.branch_styles):
        rows = np.nonzero(target[:, s])[0]
        if len(rows) == len(z):
            out += target[:, s, None] * _lstm_stack(w.branches[k], z, hb[:, k], cb[:, k])
        elif len(rows):
            hk, ck = hb[rows, k], cb[rows, k]
            out[rows] += target[rows, s, None] * _lstm_stack(w.branches[k], z[rows], hk, ck)
            hb[rows, k], cb[rows, k] = hk, ck
    nI = w.input_styles
    return _rotations(
        _dense_layers(np.concatenate([out, target[:, :nI]], -1), w.decoder, (target[:, nI:], w.decoder_added)),
        w.n_joints,
    )


def posed(w: StepWeights, x: np.ndarray, change: np.ndarray) -> np.ndarray:
    """``pose_change``: the decoder's rotations ``[N, J, 4]`` applied to the input's own rotations,
    read from the features ``x`` (given * change)."""
    mean, std = w.given
    given = (x[:, : 4 * w.n_joints] * std + mean).reshape(len(x), w.n_joints, 4)
    return quat.mul(quat.normalize(given), change).astype(np.float32)


def _dense_layers(
    y: np.ndarray,
    layers: list[tuple[np.ndarray, np.ndarray]],
    added: tuple[np.ndarray, np.ndarray | None] = (None, None),
) -> np.ndarray:
    """Linear layers with ReLU between them, in place after each product (one temporary
    array per layer, not three). ``added``: inputs and weights summed into the first layer
    apart (the added styles' target weights)."""
    for i, (W, b) in enumerate(layers):
        y = y @ W
        y += b
        if i == 0 and added[1] is not None:
            y += added[0] @ added[1]
        if i < len(layers) - 1:
            np.maximum(y, 0.0, out=y)
    return y


class NumpyLabeller:
    """The OnlineLabeller's step in numpy (torch's GRU gate order r, z, n), one state row per
    stream; returns style and content probabilities after each frame."""

    def __init__(self, labeller: LabellerWeights, n_streams: int):
        labeller = labeller_weights(labeller)
        sd = labeller.arrays
        self.w_in, self.b_in = sd["inp.0.weight"].T.copy(), sd["inp.0.bias"]
        self.w_ih, self.b_ih = sd["gru.weight_ih_l0"].T.copy(), sd["gru.bias_ih_l0"]
        self.w_hh, self.b_hh = sd["gru.weight_hh_l0"].T.copy(), sd["gru.bias_hh_l0"]
        self.heads = [
            (sd["style.weight"].T.copy(), sd["style.bias"]),
            (sd["content.weight"].T.copy(), sd["content.bias"]),
        ]
        self.h = np.zeros((n_streams, labeller.config["hidden"]), np.float32)
        self.familiar = labeller.familiar

    def familiarity(self, state: np.ndarray, frames: np.ndarray) -> np.ndarray | None:
        """How like its training streams' the states of streams ``frames`` frames in are
        (``stored.familiarity``; ``None``: a labeller without that measure)."""
        return None if self.familiar is None else familiarity(state, frames, self.familiar)

    def reset(self, streams: np.ndarray | None = None) -> None:
        self.h[slice(None) if streams is None else streams] = 0.0

    def step(self, x: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """-> (style probabilities, content probabilities, the new state of the streams
        ``rows`` (default all)); the state is kept only when the caller commits it
        (``self.h[rows] = state``)."""
        H = self.h.shape[1]
        h = self.h if rows is None else self.h[rows]
        a = np.maximum(x @ self.w_in + self.b_in, 0.0)
        gi, gh = a @ self.w_ih + self.b_ih, h @ self.w_hh + self.b_hh
        r, z = _sigmoid(gi[:, :H] + gh[:, :H]), _sigmoid(gi[:, H : 2 * H] + gh[:, H : 2 * H])
        n = np.tanh(gi[:, 2 * H :] + r * gh[:, 2 * H :])
        h = (1.0 - z) * n + z * h
        probs = []
        for W, b in self.heads:
            logits = h @ W + b
            e = np.exp(logits - logits.max(-1, keepdims=True))
            probs.append(e / e.sum(-1, keepdims=True))
        return probs[0], probs[1], h


@cache
def _blas_pools():
    """Every BLAS a step may call: numpy's, and scipy's, which the numba backend's compiled
    step calls (loaded here first, or a controller made before that backend would miss it)."""
    import importlib

    from threadpoolctl import ThreadpoolController

    importlib.import_module("scipy.linalg.cython_blas")
    return ThreadpoolController().select(user_api="blas")


def one_blas_thread():
    """BLAS held to one thread while steps run on several threads of their own (two callers
    each asking BLAS for both cores spin against each other)."""
    return _blas_pools().limit(limits=1)
