"""The network's one-frame step as an ONNX graph, with the recurrent state as explicit inputs
and outputs, for onnxruntime, onnxruntime-web, Unity's inference engine (Sentis) or Unreal NNE.

Two forms of the same step (opset 15, IR version 8; equal to the torch model to 1e-5):
- ``lstm`` (the default): each LSTM layer is one ONNX ``LSTM`` op (seq_len 1), the form
  engines run natively (Unity supports LSTM, not GRU, Loop or Scan; opsets 7-15);
- ``plain``: the LSTM cells written out as MatMul / Add / Sigmoid / Tanh / Mul, for runtimes
  without the LSTM op.

Inputs (N streams, float32): ``features [N, D]`` (normalised per-frame features),
``style [N, nS]`` and ``content [N, nC]`` (the input's labels, one-hot or probabilities
summing to 1), ``target [N, nS]`` (target style weights), ``first_frame [N, 1]`` (1 on a
stream's first frame: the state inputs are then replaced by the learned initial states), and
the recurrent state ``h``, ``c [S, N, H]`` (one row per LSTM layer: ``state_layers``).
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
from styleerd.errors import StyleERDError
from styleerd.data.features import CONTACT_SPEED
from styleerd.model.stored import GeneratorWeights, generator_weights
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.numpy_step import step_weights

OPSET = 15  # the LSTM op with explicit state, as engines support it (Unity: opsets 7-15)
FORMS = ("lstm", "plain")
# torch packs LSTM gates as (input, forget, cell, output), ONNX as (input, output, forget, cell)
TORCH_TO_ONNX_GATES = (0, 3, 1, 2)


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


def _linear(g: _Graph, x: str, W: np.ndarray, b: np.ndarray, relu: bool) -> str:
    y = g.op("Gemm", x, g.const(W.astype(np.float32)), g.const(b.astype(np.float32)))
    return g.op("Relu", y) if relu else y


def _onnx_gates(a: np.ndarray, H: int) -> np.ndarray:
    return np.concatenate([a[k * H : (k + 1) * H] for k in TORCH_TO_ONNX_GATES]).astype(np.float32)


def _lstm_layer(g: _Graph, form: str, x: str, h: str, c: str, arrays: dict, prefix: str, i: int, H: int) -> tuple[str, str]:
    """One LSTM layer's step on ``x [1, N, in]`` and its state ``h, c [1, N, H]`` -> the new
    ``h, c`` (h is also the layer's output): one ``LSTM`` op, or its cell written out."""
    w_ih, w_hh = arrays[f"{prefix}.weight_ih_l{i}"], arrays[f"{prefix}.weight_hh_l{i}"]
    b_ih, b_hh = arrays[f"{prefix}.bias_ih_l{i}"], arrays[f"{prefix}.bias_hh_l{i}"]
    if form == "lstm":
        W, R = g.const(_onnx_gates(w_ih, H)[None]), g.const(_onnx_gates(w_hh, H)[None])
        B = g.const(np.concatenate([_onnx_gates(b_ih, H), _onnx_gates(b_hh, H)])[None])
        g.count += 1
        h_new, c_new = f"lstm{g.count}_h", f"lstm{g.count}_c"
        g.nodes.append(helper.make_node("LSTM", [x, W, R, B, "", h, c], ["", h_new, c_new], hidden_size=H))  # seq_len 1: Y_h is Y
        return h_new, c_new
    gates = g.op("Add", g.op("Add", g.op("MatMul", x, g.const(w_ih.T.astype(np.float32))), g.op("MatMul", h, g.const(w_hh.T.astype(np.float32)))),
                 g.const((b_ih + b_hh).astype(np.float32)))  # fmt: skip
    i_, f_, g_, o_ = g.op("Split", gates, outputs=4, axis=2)  # torch's gate order
    c_new = g.op("Add", g.op("Mul", g.op("Sigmoid", f_), c), g.op("Mul", g.op("Sigmoid", i_), g.op("Tanh", g_)))
    return g.op("Mul", g.op("Sigmoid", o_), g.op("Tanh", c_new)), c_new


def _ints(g: _Graph, *values: int) -> str:
    return g.const(np.array(values, dtype=np.int64))


def state_layers(model: GeneratorWeights, styles: tuple[str, ...] | None = None) -> list[tuple[str, int]]:
    """The rows of the state tensors ``h, c [S, N, H]``: (branch, layer) for the neutral
    branch's layers, then each included style branch's (all, or those of ``styles``)."""
    c = generator_weights(model).config
    branches = [c.styles[s] for s in c.branch_styles if styles is None or c.styles[s] in styles]
    return [(c.neutral_style, i) for i in range(c.neutral_layers)] + [(b, i) for b in branches for i in range(c.style_layers)]


def step_graph(model: GeneratorWeights, form: str = "lstm", styles: tuple[str, ...] | None = None) -> onnx.ModelProto:
    """The step graph in ``form`` (``FORMS``) with the branches of ``styles`` (default every
    style; a graph for the styles a host uses is smaller and faster), checked by
    ``onnx.checker`` (full check).

    Layers work on ``[1, N, .]`` tensors (a sequence of one frame) and every per-layer or
    per-branch step that ONNX can batch is batched, so the graph has few nodes: one state
    tensor per h and c (``state_layers``), split into its layers once and joined once; the
    branch outputs weighted and summed in one pass; one ``Where`` per state keeps the rows of
    branches that do not run."""
    if form not in FORMS:
        raise ValueError(f"unknown ONNX form {form!r}; valid: {', '.join(FORMS)}")
    model = generator_weights(model)
    w, arrays, c = step_weights(model), model.arrays, model.config
    unknown = set(styles or ()) - set(c.styles[s] for s in c.branch_styles)
    if unknown:
        raise StyleERDError(f"no style branch for {', '.join(sorted(unknown))}; the model's: {', '.join(c.styles[s] for s in c.branch_styles)}")
    ks = [k for k, s in enumerate(w.branch_styles) if styles is None or c.styles[s] in styles]  # included branches
    D, nS, nC, H, J = c.feature_dim, len(c.styles), len(c.contents), c.hidden, c.n_joints
    L0, L1 = len(w.neutral), c.style_layers
    S = L0 + len(ks) * L1
    g = _Graph()
    # a stream's first frame starts from the learned initial states (the neutral one by content):
    # content [N, nC] @ table [nC, S*H] -> [S, N, H], the branch rows the same for every content
    first = g.op("Unsqueeze", g.op("Cast", "first_frame", to=TensorProto.BOOL), _ints(g, 0))  # [1, N, 1]
    states = {}
    for name, neutral, branch in (("h", w.neutral_init[0], w.branch_init[0]), ("c", w.neutral_init[1], w.branch_init[1])):
        table = np.concatenate([neutral.reshape(nC, -1), *(np.broadcast_to(branch[k].reshape(1, -1), (nC, L1 * H)) for k in ks)], axis=1)
        start = g.op("Transpose", g.op("Reshape", g.op("MatMul", "content", g.const(table.astype(np.float32))), _ints(g, -1, S, H)), perm=[1, 0, 2])
        states[name] = g.op("Where", first, start, name)
    # encoder
    z = g.op("Concat", "features", "style", "content", axis=1)
    for i, (W, b) in enumerate(w.encoder):
        z = _linear(g, z, W, b, relu=i < len(w.encoder) - 1)
    z = g.op("Unsqueeze", z, _ints(g, 0))  # [1, N, H]
    # the branches, layer by layer
    rows = {name: g.op("Split", states[name], outputs=S, axis=0) if S > 1 else [states[name]] for name in states}
    new_h, new_c, last = [], [], []
    for prefix, layers in [("neutral", L0)] + [(f"branches.{k}", L1) for k in ks]:
        x = z
        for i in range(layers):
            x, c_i = _lstm_layer(g, form, x, rows["h"][len(new_h)], rows["c"][len(new_c)], arrays, prefix, i, H)
            new_h.append(x)
            new_c.append(c_i)
        last.append(x)
    # out = neutral + sum_k w_k branch_k, the weights read off the target by one product
    pick = np.zeros((nS, 1 + len(ks)), np.float32)
    for j, k in enumerate(ks):
        pick[w.branch_styles[k], 1 + j] = 1.0
    weights = g.op("Add", g.op("MatMul", "target", g.const(pick)), g.const(np.eye(1, 1 + len(ks), dtype=np.float32)[0]))  # [N, 1+K]
    weights = g.op("Unsqueeze", g.op("Transpose", weights, perm=[1, 0]), _ints(g, 2))  # [1+K, N, 1]
    stacked = g.op("Concat", *last, axis=0) if len(last) > 1 else last[0]
    out = g.op("ReduceSum", g.op("Mul", stacked, weights), _ints(g, 0), keepdims=0)  # [N, H]
    # a branch's rows advance only for streams that give its style a weight; the neutral rows always
    runs = g.op("Not", g.op("Equal", g.op("Gather", weights, g.const(np.array([0] * L0 + [1 + j for j in range(len(ks)) for _ in range(L1)], np.int64)), axis=0),
                            g.const(np.zeros(1, np.float32))))  # [S, N, 1]  # fmt: skip
    for name, parts in (("h", new_h), ("c", new_c)):
        g.nodes.append(helper.make_node("Where", [runs, g.op("Concat", *parts, axis=0) if S > 1 else parts[0], states[name]], [f"{name}_out"]))
    # decoder
    y = g.op("Concat", out, "target", axis=1)
    for i, (W, b) in enumerate(w.decoder):
        y = _linear(g, y, W, b, relu=i < len(w.decoder) - 1)
    q = g.op("Reshape", g.op("Slice", y, _ints(g, 0), _ints(g, 4 * J), _ints(g, 1)), _ints(g, -1, J, 4))
    norm = g.op("Max", g.op("ReduceL2", q, axes=[2], keepdims=1), g.const(np.array(1e-8, np.float32)))
    g.nodes.append(helper.make_node("Div", [q, norm], ["rotations"]))
    g.nodes.append(helper.make_node("Slice", [y, _ints(g, 4 * J), _ints(g, 7 * J), _ints(g, 1)], ["velocities"]))

    f32 = TensorProto.FLOAT
    inputs = [helper.make_tensor_value_info(name, f32, shape) for name, shape in
              (("features", ["N", D]), ("style", ["N", nS]), ("content", ["N", nC]), ("target", ["N", nS]), ("first_frame", ["N", 1]), ("h", [S, "N", H]), ("c", [S, "N", H]))]  # fmt: skip
    outputs = [helper.make_tensor_value_info(name, f32, shape) for name, shape in
               (("rotations", ["N", J, 4]), ("velocities", ["N", 3 * J]), ("h_out", [S, "N", H]), ("c_out", [S, "N", H]))]  # fmt: skip
    graph = helper.make_graph(g.nodes, f"styleerd_step_{form}", inputs, outputs, g.initializers)
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="styleerd")
    proto.ir_version = 8  # readable by onnxruntime 1.14+, onnxruntime-web and the engines
    onnx.checker.check_model(proto, full_check=True)
    return proto


def sidecar(model: GeneratorWeights, proto: onnx.ModelProto, graph_name: str, form: str = "lstm", styles: tuple[str, ...] | None = None) -> dict:
    """What a host needs around the graph: label orders, the state's rows, the body roles the
    features use, the skeleton and the feature normalisation (docs/ONNX.md)."""
    model = generator_weights(model)
    c, roles, meta = model.config, BodyRoles.of(model.skeleton), model.meta
    layers = state_layers(model, styles)
    return {
        "graph": graph_name,
        "opset": OPSET,
        "form": form,
        "styles": list(c.styles),
        "contents": list(c.contents),
        "neutral_style": c.neutral_style,
        "branch_styles": [b for i, (b, layer) in enumerate(layers) if layer == 0 and i >= c.neutral_layers],
        "state_layers": [list(row) for row in layers],
        "state_shapes": {i.name: [d.dim_param or d.dim_value for d in i.type.tensor_type.shape.dim] for i in proto.graph.input[5:]},
        "feature_layout": "[rotations 4J (w,x,y,z) | positions 3J | velocities 3J | foot contacts 4], see docs/ONNX.md",
        "fps": meta.get("data", {}).get("fps"),
        # who faces where (left and right: hip, shoulder), the contacts' joints (left foot, left
        # toe, right foot, right toe) and the leg length (hip to foot at rest) they are measured in
        "roles": {"left": list(roles.left), "right": list(roles.right), "feet": list(roles.feet), "leg_length": roles.leg_length},
        "contact_speed_leg_lengths": CONTACT_SPEED,
        "skeleton": model.skeleton.to_dict(),
        "stats": model.stats().to_dict(),
    }


def export(model: GeneratorWeights, path: str | Path, form: str = "lstm", styles: tuple[str, ...] | None = None) -> None:
    """Write the step graph (``form``, the branches of ``styles`` or all) to ``path`` (.onnx)
    and its ``sidecar`` beside it (.json), both atomically."""
    path = Path(path)
    proto = step_graph(model, form, styles)
    atomic_write(path, lambda tmp: onnx.save(proto, tmp))
    atomic_write_text(path.with_suffix(".json"), json.dumps(sidecar(model, proto, path.name, form, styles), indent=1) + "\n")
