"""The network's one-frame step as an ONNX graph, with the recurrent state as explicit inputs
and outputs, for onnxruntime, onnxruntime-web, Unity's inference engine (Sentis) or Unreal NNE.

Two forms of the same step (opset 15, IR version 8; equal to the torch model to 1e-5):
- ``lstm`` (the default): ONNX ``LSTM`` ops (seq_len 1; with one style, one per layer depth), the form
  engines run natively (Unity supports LSTM, not GRU, Loop or Scan; opsets 7-15);
- ``plain``: the LSTM cells written out as MatMul / Add / Sigmoid / Tanh / Mul, for runtimes
  without the LSTM op.

Inputs (N streams, float32): ``features [N, D]`` (normalised per-frame features),
``style [N, nS]`` and ``content [N, nC]`` (the input's labels, one-hot or probabilities
summing to 1), ``target [N, nS]`` (target style weights), ``first_frame [N, 1]`` (1 on a
stream's first frame: the state inputs are then replaced by the learned initial states), and
the recurrent state ``h``, ``c`` (one row of H per LSTM layer, ``state_layers``: side by side,
``[1, N, S H]``, in the LSTM form; ``[S, N, H]`` in the plain one: ``state_shape``).
Outputs: ``rotations [N, J, 4]`` (unit quaternions w, x, y, z; the root's relative to the
heading frame), ``velocities [N, 3J]`` (normalised), ``h_out``, ``c_out`` (the state for the
next frame). A style branch's rows only advance where its target weight is non-zero.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from styleerd.atomic import atomic_write, atomic_write_text
from styleerd.data.features import CONTACT_SPEED
from styleerd.errors import StyleERDError
from styleerd.model.config import LIMB_ROUNDS, RELEASE, RISE
from styleerd.model.stored import GeneratorWeights, generator_weights
from styleerd.motion import quat
from styleerd.motion.humanoid import eyes_above_head, limb_ends
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.numpy_step import step_weights

OPSET = 15  # the LSTM op with explicit state, as engines support it (Unity: opsets 7-15)
FORMS = ("lstm", "plain")
# torch packs LSTM gates as (input, forget, cell, output), ONNX as (input, output, forget, cell)
TORCH_TO_ONNX_GATES = (0, 3, 1, 2)
# LSTM form: with this many style branches or fewer, the layers of one depth are one op; fusing
# more wastes arithmetic on block-diagonal weights, growing as the square of the branches
# (docs/benchmarks.md, "Tuned constants")
FUSE_UP_TO = 1


class _Graph:
    """A tiny builder: ``op`` adds a node and returns its output's name."""

    def __init__(self):
        self.nodes, self.initializers, self.count = [], [], 0

    def const(self, array: np.ndarray, name: str | None = None) -> str:
        self.count += 1
        name = name or f"c{self.count}"
        self.initializers.append(numpy_helper.from_array(np.asarray(array), name))
        return name

    def op(self, kind: str, *inputs: str, outputs: int = 1, **attrs) -> str | list[str]:
        self.count += 1
        names = [f"{kind.lower()}{self.count}_{i}" for i in range(outputs)]
        self.nodes.append(helper.make_node(kind, list(inputs), names, **attrs))
        return names[0] if outputs == 1 else names


def _onnx_gates(a: np.ndarray, H: int, order=TORCH_TO_ONNX_GATES) -> np.ndarray:
    return np.concatenate([a[k * H : (k + 1) * H] for k in order]).astype(np.float32)


def _lockstep_cells(
    g: _Graph, x: str, h: str, c: str, arrays: dict, members: list[tuple[str, int]], H: int
) -> tuple[str, str]:
    """Layer i of several branches at once, written out in plain ops: the branches are a batch
    axis of the matrix products (``x [1 or B, N, in]``, ``h, c [B, N, H]``, weights [B, in, 4H]),
    so a graph has one cell's worth of nodes per layer depth however many branches it holds."""
    order = (0, 1, 3, 2)  # torch's gates (i, f, g, o) as (i, f, o, g): one Sigmoid, one Tanh
    w_in = np.stack([_onnx_gates(arrays[f"{p}.weight_ih_l{i}"], H, order).T for p, i in members])
    w_hid = np.stack([_onnx_gates(arrays[f"{p}.weight_hh_l{i}"], H, order).T for p, i in members])
    b = np.stack(
        [_onnx_gates(arrays[f"{p}.bias_ih_l{i}"] + arrays[f"{p}.bias_hh_l{i}"], H, order)[None] for p, i in members]
    )
    if members[0][1] == 0:  # the first layer's input (the encoding) is shared by every branch
        gates = g.op("Add", g.op("MatMul", x, g.const(w_in)), g.op("MatMul", h, g.const(w_hid)))
    else:
        gates = g.op("MatMul", g.op("Concat", x, h, axis=2), g.const(np.concatenate([w_in, w_hid], axis=1)))
    ifo, g_ = g.op("Split", g.op("Add", gates, g.const(b)), _ints(g, 3 * H, H), outputs=2, axis=2)
    i_, f_, o_ = g.op("Split", g.op("Sigmoid", ifo), outputs=3, axis=2)
    c_new = g.op("Add", g.op("Mul", f_, c), g.op("Mul", i_, g.op("Tanh", g_)))
    return g.op("Mul", o_, g.op("Tanh", c_new)), c_new


def _fold_into_first_layers(arrays: dict, W: np.ndarray, b: np.ndarray, prefixes: list[str]) -> dict:
    """``arrays`` with a linear layer ``x @ W + b`` before layer 0 of the stacks ``prefixes``
    folded into that layer's input weights (one matrix product fewer per frame)."""
    arrays = dict(arrays)
    for p in prefixes:
        w_ih = arrays[f"{p}.weight_ih_l0"].astype(np.float64)
        arrays[f"{p}.weight_ih_l0"] = (w_ih @ W.T).astype(np.float32)
        arrays[f"{p}.bias_ih_l0"] = (arrays[f"{p}.bias_ih_l0"] + w_ih @ b).astype(np.float32)
    return arrays


def _ints(g: _Graph, *values: int) -> str:
    return g.const(np.array(values, dtype=np.int64))


def _depths(c, branches: list[str]) -> list[list[tuple[str, int]]]:
    """Per layer depth, the (stack, layer) pairs at that depth: the neutral branch first, then
    the style branches."""
    stacks = [("neutral", c.neutral_style, c.neutral_layers)] + [
        (f"branches.{k}", s, c.style_layers) for k, s in branches
    ]
    return [
        [(prefix, name, i) for prefix, name, layers in stacks if i < layers]
        for i in range(max(c.neutral_layers, c.style_layers))
    ]


def _branches(c, styles: tuple[str, ...] | None) -> list[tuple[int, str]]:
    """(index among the model's branches, style) of the branches a graph of ``styles`` holds."""
    return [(k, c.styles[s]) for k, s in enumerate(c.branch_styles) if styles is None or c.styles[s] in styles]


def state_layers(model: GeneratorWeights, styles: tuple[str, ...] | None = None) -> list[tuple[str, int]]:
    """The rows of the state tensors ``h, c`` (``state_shape``), depth by depth: (branch, layer) for
    layer 0 of the neutral branch and of each included style branch (all, or those of
    ``styles``), then layer 1, and so on."""
    c = generator_weights(model).config
    return [(name, i) for depth in _depths(c, _branches(c, styles)) for _, name, i in depth]


def initial_states(model: GeneratorWeights, styles: tuple[str, ...] | None = None) -> np.ndarray:
    """The learned initial states of the state rows ``state_layers(model, styles)`` per content,
    ``[nC, 2 S H]`` (the h rows, then the c rows): ``content @ table`` is a stream's first state."""
    model = generator_weights(model)
    c = model.config
    rows = [(prefix, i) for depth in _depths(c, _branches(c, styles)) for prefix, _, i in depth]
    return _initial_states(step_weights(model), rows, len(c.contents))


def _initial_states(w, rows: list[tuple[str, int]], n_contents: int) -> np.ndarray:
    """The learned initial states as one product's weights ``[nC, 2 S H]``: the h rows, then the
    c rows, each (branch, layer) of ``rows`` H wide; the neutral rows by content, a branch's the
    same for every content (so ``content @ table`` is every stream's first state)."""
    return np.concatenate(
        [
            (
                init[:, i]
                if prefix == "neutral"
                else np.broadcast_to(branch_init[int(prefix.split(".")[1]), i], (n_contents, init.shape[-1]))
            ).astype(np.float32)
            for init, branch_init in zip(w.neutral_init, w.branch_init)
            for prefix, i in rows
        ],
        1,
    )


def _lstm_form(
    g: _Graph, z: str, first: str | None, arrays: dict, w, c, depths: list, branches: list, fuse: bool
) -> tuple[str, np.ndarray]:
    """The branches as ``LSTM`` ops on the state ``h, c [1, N, S H]`` (rows side by side, in
    ``state_layers`` order): ``fuse``, the layers of one depth run as one op (block-diagonal
    weights: fewer ops in sequence), else one op per layer. ``first`` None: a grouped graph
    (``step_graph``), every row advances and no first frame is reset. Writes
    ``h_out``, ``c_out``; returns the decoder's first input ``[N, K]`` (the last layers' outputs,
    branches weighted, then the target) and the rows of its first weight for those K columns."""
    H, nC, nS = c.hidden, len(c.contents), len(c.styles)
    rows = [(prefix, i) for depth in depths for prefix, _, i in depth]
    T = len(rows) * H
    ops = [[(prefix, i) for prefix, _, i in depth] for depth in depths] if fuse else [[row] for row in rows]
    # a stream's first frame: the learned initial states, content [N, nC] @ [nC, 2T]; h and c
    # side by side [1, N, 2T]: one Where, one Split, one Concat for both
    state = g.op("Concat", "h", "c", axis=2)
    if first is not None:
        state = g.op("Where", first, g.op("MatMul", "content", g.const(_initial_states(w, rows, nC))), state)
    widths = [len(members) * H for members in ops]
    parts = g.op("Split", state, _ints(g, *widths, *widths), outputs=2 * len(ops), axis=2)
    parts = {"h": parts[: len(ops)], "c": parts[len(ops) :]}
    x0 = g.op("Unsqueeze", z, _ints(g, 0))  # [1, N, E]: a sequence of one frame
    out_of: dict[
        tuple[str, int], tuple[str, int, int]
    ] = {}  # (branch, layer) -> its op's output h, its first column there, the op's width
    new = {"h": [], "c": []}
    for k, members in enumerate(ops):
        B, (first_prefix, depth) = (
            len(members),
            members[0],
        )  # every member's input is the op below's output (or the encoding)
        x, _, width = (
            (x0, 0, arrays[f"{first_prefix}.weight_ih_l0"].shape[1])
            if depth == 0
            else out_of[(first_prefix, depth - 1)]
        )
        W, R, bias = (
            np.zeros((4 * B * H, width), np.float32),
            np.zeros((4 * B * H, B * H), np.float32),
            np.zeros((2, 4 * B * H), np.float32),
        )
        for m, (prefix, i) in enumerate(members):
            for gate, torch_gate in enumerate(TORCH_TO_ONNX_GATES):
                to, src = slice((gate * B + m) * H, (gate * B + m + 1) * H), slice(torch_gate * H, (torch_gate + 1) * H)
                w_ih = arrays[f"{prefix}.weight_ih_l{i}"][src]
                if i == 0:
                    W[to] = w_ih
                else:
                    at = out_of[(prefix, i - 1)][1]  # its input: its own layer below
                    W[to, at : at + H] = w_ih
                R[to, m * H : (m + 1) * H] = arrays[f"{prefix}.weight_hh_l{i}"][src]
                bias[0, to], bias[1, to] = arrays[f"{prefix}.bias_ih_l{i}"][src], arrays[f"{prefix}.bias_hh_l{i}"][src]
        g.count += 1
        h_new, c_new = f"lstm{g.count}_h", f"lstm{g.count}_c"
        g.nodes.append(
            helper.make_node(
                "LSTM",
                [x, g.const(W[None]), g.const(R[None]), g.const(bias.reshape(1, -1)), "", parts["h"][k], parts["c"][k]],
                ["", h_new, c_new],
                hidden_size=B * H,
            )
        )
        new["h"].append(h_new)
        new["c"].append(c_new)
        for m, member in enumerate(members):
            out_of[member] = (h_new, m * H, B * H)
    # per state column, the style whose weight lets it advance (the neutral columns always do):
    # a branch's columns keep their state where the target gives its style no weight
    style_of = {prefix: c.styles.index(style) for prefix, style in ((f"branches.{k}", style) for k, style in branches)}
    kept = g.op("Concat", *new["h"], *new["c"], axis=2)
    if first is not None:  # (a grouped graph advances every column)
        pick, neutral = np.zeros((nS, T), np.float32), np.zeros(T, np.float32)
        for r, (prefix, _) in enumerate(rows):
            if prefix == "neutral":
                neutral[r * H : (r + 1) * H] = 1.0
            else:
                pick[style_of[prefix], r * H : (r + 1) * H] = 1.0
        keep = g.op(
            "Equal",
            g.op("Gemm", "target", g.const(np.tile(pick, 2)), g.const(np.tile(neutral, 2))),
            g.const(np.zeros(1, np.float32)),
        )  # [N, 2T]
        kept = g.op("Where", keep, state, kept)
    g.nodes.append(helper.make_node("Split", [kept], ["h_out", "c_out"], axis=2))
    # the decoder reads neutral + sum_k w_k branch_k: the ops holding the last layers, side by
    # side, each column weighted (1 for the neutral branch's, w_k for branch k's, 0 for others),
    # and the decoder's first weight repeated for each last layer's columns
    last = [("neutral", c.neutral_layers - 1)] + [(f"branches.{k}", c.style_layers - 1) for k, _ in branches]
    held = {out_of[member][0]: out_of[member][2] for member in last}  # op output -> width, in order
    offsets = dict(zip(held, np.cumsum([0, *held.values()])))
    K = sum(held.values())
    weigh, ones, copies = np.zeros((nS, K), np.float32), np.zeros(K, np.float32), np.zeros((K, H), np.float32)
    for prefix, i in last:
        name, at, _ = out_of[(prefix, i)]
        cols = slice(offsets[name] + at, offsets[name] + at + H)
        copies[cols] = np.eye(H, dtype=np.float32)
        if prefix == "neutral":
            ones[cols] = 1.0
        else:
            weigh[style_of[prefix], cols] = 1.0
    joined = g.op("Concat", *held, axis=2) if len(held) > 1 else next(iter(held))
    weighted = g.op("Squeeze", g.op("Mul", joined, g.op("Gemm", "target", g.const(weigh), g.const(ones))), _ints(g, 0))
    return g.op("Concat", weighted, "target", axis=1), copies


def _plain_form(
    g: _Graph, z: str, first: str | None, arrays: dict, w, c, depths: list, branches: list
) -> tuple[str, np.ndarray]:
    """The branches written out in plain ops on the state ``h, c [S, N, H]`` (a row per layer,
    ``state_layers`` order), the cells of one depth one batched cell (``_lockstep_cells``);
    ``first`` None: a grouped graph (``_lstm_form``).
    Writes ``h_out``, ``c_out``; returns the decoder's first input ``[N, H + nS]`` and the rows
    of its first weight for the first H columns (the identity)."""
    rows = [(prefix, i) for depth in depths for prefix, _, i in depth]
    nS, nC, H, S = len(c.styles), len(c.contents), c.hidden, len(rows)
    # content [N, nC] @ [nC, 2 S H] -> [2S, N, H] (h rows, then c rows); 2-D products
    # throughout: onnxruntime runs a batched product as one small GEMM call per batch entry
    states = {"h": "h", "c": "c"}
    if first is not None:
        start = g.op(
            "Transpose",
            g.op("Reshape", g.op("MatMul", "content", g.const(_initial_states(w, rows, nC))), _ints(g, -1, 2 * S, H)),
            perm=[1, 0, 2],
        )
        starts = g.op("Split", start, outputs=2, axis=0)
        states = {name: g.op("Where", first, s0, name) for name, s0 in zip(("h", "c"), starts)}
    new = {"h": [], "c": []}
    sizes = _ints(g, *(len(d) for d in depths))
    parts = {
        name: g.op("Split", states[name], sizes, outputs=len(depths), axis=0) if len(depths) > 1 else [states[name]]
        for name in states
    }
    x, previous = z, None
    for d, depth in enumerate(depths):
        members = [(prefix, i) for prefix, _, i in depth]
        if previous is not None and members != [(p, i + 1) for p, _, i in previous][: len(members)]:
            raise ValueError(
                "a depth's branches must be the first of the depth before"
            )  # the neutral branch is the deepest or as deep
        if previous is not None and len(members) < len(previous):
            x = g.op("Slice", x, _ints(g, 0), _ints(g, len(members)), _ints(g, 0))
        x, c_new = _lockstep_cells(g, x, parts["h"][d], parts["c"][d], arrays, members, H)
        new["h"].append(x)
        new["c"].append(c_new)
        previous = depth
        if d == c.style_layers - 1:
            branch_last = g.op("Slice", x, _ints(g, 1), _ints(g, 1 + len(branches)), _ints(g, 0)) if branches else None
        if d == c.neutral_layers - 1:
            neutral_last = g.op("Slice", x, _ints(g, 0), _ints(g, 1), _ints(g, 0)) if len(depth) > 1 else x
    # the target's weight per branch [K, N, 1] and per state row [S, N, 1], read off by one product
    # (a grouped graph: the branches' weights only)
    pick = np.zeros((nS, len(branches) + (S if first is not None else 0)), np.float32)
    for j, (_, style) in enumerate(branches):
        pick[c.styles.index(style), j] = 1.0
    style_of = dict(branches)
    for r, (prefix, _) in enumerate(rows if first is not None else []):
        if prefix != "neutral":
            pick[c.styles.index(style_of[int(prefix.split(".")[1])]), len(branches) + r] = 1.0
    picked = (
        g.op("Unsqueeze", g.op("Transpose", g.op("MatMul", "target", g.const(pick)), perm=[1, 0]), _ints(g, 2))
        if pick.size
        else None
    )  # [K + S, N, 1]
    if first is None:  # the branches' weights only
        weights = picked
    else:
        weights, row_weights = (
            g.op("Split", picked, _ints(g, len(branches), S), outputs=2, axis=0) if branches else (None, picked)
        )
    out = neutral_last  # out = neutral + sum_k w_k branch_k
    if branches:
        out = g.op("Add", out, g.op("ReduceSum", g.op("Mul", branch_last, weights), _ints(g, 0), keepdims=1))
    out = g.op("Squeeze", out, _ints(g, 0))  # [N, H]
    # a branch's rows advance only for streams that give its style a weight; the neutral rows always
    if first is not None:
        neutral_rows = np.array([[[float(prefix == "neutral")]] for prefix, _ in rows], np.float32)
        keep = g.op(
            "Equal", g.op("Add", row_weights, g.const(neutral_rows)), g.const(np.zeros(1, np.float32))
        )  # [S, N, 1]
    for name in ("h", "c"):
        joined = [g.op("Concat", *new[name], axis=0) if len(depths) > 1 else new[name][0]]
        g.nodes.append(
            helper.make_node("Where", [keep, states[name], *joined], [f"{name}_out"])
            if first is not None
            else helper.make_node("Identity", joined, [f"{name}_out"])
        )
    return g.op("Concat", out, "target", axis=1), np.eye(H, dtype=np.float32)


def _posed(g: _Graph, change: str, w) -> None:
    """Writes ``rotations``: the input's own rotations (read back from ``features``) times
    ``change [N, J, 4]``, as the outer product of each pair and one product with the Hamilton table."""
    J = w.n_joints
    mean, std = w.given
    given = g.op("Slice", "features", _ints(g, 0), _ints(g, 4 * J), _ints(g, 1))
    given = g.op("Reshape", g.op("Add", g.op("Mul", given, g.const(std)), g.const(mean)), _ints(g, -1, J, 4))
    norm = g.op("Clip", g.op("ReduceL2", given, axes=[2], keepdims=1), g.const(np.array(1e-8, np.float32)))
    given = g.op("Unsqueeze", g.op("Div", given, norm), _ints(g, 3))
    pairs = g.op("Mul", given, g.op("Unsqueeze", change, _ints(g, 2)))
    g.nodes.append(
        helper.make_node(
            "MatMul",
            [g.op("Reshape", pairs, _ints(g, -1, J, 16)), g.const(quat.HAMILTON.astype(np.float32))],
            ["rotations"],
        )
    )


def state_shape(model: GeneratorWeights, form: str = "lstm", styles: tuple[str, ...] | None = None) -> tuple:
    """The shape of ``h`` and ``c`` (N: the number of streams): ``[1, N, S H]`` in the LSTM
    form, ``[S, N, H]`` in the plain one (S = ``len(state_layers)``)."""
    c = generator_weights(model).config
    S = len(state_layers(model, styles))
    return (1, "N", S * c.hidden) if form == "lstm" else (S, "N", c.hidden)


def step_graph(
    model: GeneratorWeights,
    form: str = "lstm",
    styles: tuple[str, ...] | None = None,
    fuse: bool | None = None,
    grouped: bool = False,
) -> onnx.ModelProto:
    """The step graph in ``form`` (``FORMS``) with the branches of ``styles`` (default every
    style; a graph for the styles a host uses is smaller and faster), checked by
    ``onnx.checker`` (full check). ``fuse`` (LSTM form): the layers of one depth as one op
    (default: with at most ``FUSE_UP_TO`` style branches); faster at small batches, slower at
    large ones (``backends.UNFUSED_FROM``). ``grouped``: for a host that steps each stream on the
    graph of exactly the styles it weights and sets first frames' states itself (``OnnxBackend``):
    no ``first_frame`` input and none of the ``Where`` ops that reset first frames and keep
    the rows of branches that do not run.

    Per-node cost, not arithmetic, sets a step's time at small batches (onnxruntime: about
    0.5-1 us a plain node, 3-7 us an LSTM op), so the graph has few nodes: one state tensor
    per h and c, split once and joined once; the learned initial states one product; the
    branch outputs weighted in one pass; one ``Where`` per state keeps the rows of branches
    that do not run; in the LSTM form with one style, one op per layer depth; in the plain
    form, the branches' cells of one depth one batched cell."""
    if form not in FORMS:
        raise ValueError(f"unknown ONNX form {form!r}; valid: {', '.join(FORMS)}")
    model = generator_weights(model)
    w, arrays, c = step_weights(model), model.arrays, model.config
    unknown = set(styles or ()) - {c.styles[s] for s in c.branch_styles}
    if unknown:
        raise StyleERDError(
            f"no style branch for {', '.join(sorted(unknown))}; the model's: "
            f"{', '.join(c.styles[s] for s in c.branch_styles)}"
        )
    branches = _branches(c, styles)
    depths = _depths(c, branches)
    D, nI, nS, nC, J = c.feature_dim, len(c.input_styles), len(c.styles), len(c.contents), c.n_joints
    g = _Graph()
    first = None if grouped else g.op("Cast", "first_frame", to=TensorProto.BOOL)  # [N, 1]
    # encoder; its last layer (linear) folded into the first LSTM layers' input weights
    arrays = _fold_into_first_layers(arrays, *w.encoder[-1], [prefix for prefix, _, i in depths[0]])
    z = g.op("Concat", "features", "style", "content", axis=1)
    for W, b in w.encoder[:-1]:
        z = g.op("Relu", g.op("Gemm", z, g.const(W), g.const(b)))
    if form == "lstm":
        y, copies = _lstm_form(
            g, z, first, arrays, w, c, depths, branches, len(branches) <= FUSE_UP_TO if fuse is None else fuse
        )
    else:
        y, copies = _plain_form(g, z, first, arrays, w, c, depths, branches)
    # decoder (added styles' target rows below the trained ones'); its last layer as two
    # products, the rotations' and the velocities'
    for i, (W, b) in enumerate(w.decoder[:-1]):
        if i == 0:
            W = np.concatenate(
                [copies @ W[: c.hidden], W[c.hidden :]] + ([w.decoder_added] if w.decoder_added is not None else [])
            ).astype(np.float32)
        y = g.op("Relu", g.op("Gemm", y, g.const(W), g.const(b)))
    W, b = w.decoder[-1]
    q = g.op("Reshape", g.op("Gemm", y, g.const(W[:, : 4 * J].copy()), g.const(b[: 4 * J].copy())), _ints(g, -1, J, 4))
    g.nodes.append(
        helper.make_node("Gemm", [y, g.const(W[:, 4 * J :].copy()), g.const(b[4 * J :].copy())], ["velocities"])
    )
    norm = g.op(
        "Clip", g.op("ReduceL2", q, axes=[2], keepdims=1), g.const(np.array(1e-8, np.float32))
    )  # Clip, not Max: no broadcasting (1,000 streams: 10x faster)
    if w.given is None:
        g.nodes.append(helper.make_node("Div", [q, norm], ["rotations"]))
    else:  # pose_change: the unit change applied to the input's own rotation (given * change)
        _posed(g, g.op("Div", q, norm), w)

    f32, state = TensorProto.FLOAT, list(state_shape(model, form, styles))
    inputs = [
        helper.make_tensor_value_info(name, f32, shape)
        for name, shape in (
            ("features", ["N", D]),
            ("style", ["N", nI]),
            ("content", ["N", nC]),
            ("target", ["N", nS]),
            ("first_frame", ["N", 1]),
            ("h", state),
            ("c", state),
        )
        if not (grouped and name == "first_frame")
    ]
    outputs = [
        helper.make_tensor_value_info(name, f32, shape)
        for name, shape in (
            ("rotations", ["N", J, 4]),
            ("velocities", ["N", 3 * J]),
            ("h_out", state),
            ("c_out", state),
        )
    ]
    graph = helper.make_graph(g.nodes, f"styleerd_step_{form}", inputs, outputs, g.initializers)
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="styleerd")
    proto.ir_version = 8  # readable by onnxruntime 1.14+, onnxruntime-web and the engines
    onnx.checker.check_model(proto, full_check=True)
    return proto


def sidecar(
    model: GeneratorWeights,
    proto: onnx.ModelProto,
    graph_name: str,
    form: str = "lstm",
    styles: tuple[str, ...] | None = None,
) -> dict:
    """What a host needs around the graph: label orders, the state's rows, the body roles the
    features use, the skeleton and the feature normalisation (docs/ONNX.md)."""
    model = generator_weights(model)
    c, roles, meta = model.config, BodyRoles.of(model.skeleton), model.meta
    layers = state_layers(model, styles)
    return {
        "graph": graph_name,
        "opset": OPSET,
        "form": form,
        "styles": list(c.styles),  # the target's order
        "input_styles": list(c.input_styles),  # the style input's order (the styles trained on)
        "contents": list(c.contents),
        "neutral_style": c.neutral_style,
        "branch_styles": [b for b, layer in layers if layer == 0 and b != c.neutral_style],
        "state_layers": [list(row) for row in layers],
        "state_shapes": {
            i.name: [d.dim_param or d.dim_value for d in i.type.tensor_type.shape.dim]
            for i in proto.graph.input
            if i.name in ("h", "c")
        },
        "feature_layout": "[rotations 4J (w,x,y,z) | positions 3J | velocities 3J | foot contacts 4], see docs/ONNX.md",
        "fps": meta.get("data", {}).get("fps"),
        # who faces where (left and right: hip, shoulder), the contacts' joints (left foot, left
        # toe, right foot, right toe) and the leg length (hip to foot at rest) they are measured in
        "roles": {
            "left": list(roles.left),
            "right": list(roles.right),
            "feet": list(roles.feet),
            "hips": roles.hips,
            "head": roles.head,
            "leg_length": roles.leg_length,
        },
        "contact_speed_leg_lengths": CONTACT_SPEED,
        # per target style (``styles``' order) and joint, the rotation vector (radians) of its posture:
        # what an input the network never learnt is turned by (``runtime.posture``); null: not measured
        "posture": None if model.posture is None else np.round(model.posture, 6).tolist(),
        # per target style and joint, where its posture moves the joint relative to the root, in the frame
        # posture_frame names (the skeleton's units): the input turned by the posture is then turned so its
        # joints go there (``runtime.stylizer._reach``); null: not measured
        "posture_offsets": None if model.posture_offsets is None else np.round(model.posture_offsets, 6).tolist(),
        # "body": along the body's own axes on the input's pose (left: right hip and shoulder to left ones, up:
        # hips to head, forward: left x up, made orthogonal); "heading": the body's heading, up the world's
        "posture_frame": model.posture_frame,
        # per joint, for the first joint of a two-bone limb (shoulder, hip), the limb's end (hand, foot), else -1:
        # its middle joint is put where it and the end meet their targets best together, by limb_rounds rounds
        # of projections (``motion.humanoid.limb_ends``, ``runtime.stylizer._limb_elbow``)
        "limb_ends": limb_ends(model.skeleton).tolist(),
        "limb_rounds": LIMB_ROUNDS,
        # how far above the head joint the eyes are (the skeleton's units): a limb's end the posture raises by r
        # rises by the smooth minimum of r and its way to the eyes, none above them, its middle joint alike
        # (``motion.humanoid.eyes_above_head``, ``runtime.stylizer._ends_below_the_eyes``)
        "eyes_above_head": eyes_above_head(model.skeleton),
        # the identity pass's mean joint angle to the input (degrees) up to which the network's pose is kept,
        # and from which the input's pose turned by the posture is (``model.stored.familiar_range``)
        "familiar_degrees": list(model.familiar),
        # how far that blend's weight may move a frame: up, and down (``model.config``)
        "unfamiliar_rise_release": [RISE, RELEASE],
        "skeleton": model.skeleton.to_dict(),
        "stats": model.stats().to_dict(),
    }


def export(
    model: GeneratorWeights, path: str | Path, form: str = "lstm", styles: tuple[str, ...] | None = None
) -> None:
    """Write the step graph (``form``, the branches of ``styles`` or all) to ``path`` (.onnx)
    and its ``sidecar`` beside it (.json), both atomically."""
    path = Path(path)
    proto = step_graph(model, form, styles)
    atomic_write(path, lambda tmp: onnx.save(proto, tmp))
    atomic_write_text(
        path.with_suffix(".json"), json.dumps(sidecar(model, proto, path.name, form, styles), indent=1) + "\n"
    )
