"""The network's one-frame step as a plain ONNX graph (opset 17; MatMul, Add, Sigmoid, Tanh,
Mul, Relu, Gather, Concat, ...: the LSTM cells written out, no LSTM op), with the recurrent
state as explicit inputs and outputs, for onnxruntime, Unity Sentis or Unreal NNE.

Inputs (N streams, float32): ``features [N, D]`` (normalised per-frame features),
``style [N, nS]`` and ``content [N, nC]`` (the input's labels, one-hot or probabilities),
``target [N, nS]`` (target style weights), ``first_frame [N, 1]`` (1 on a stream's first
frame: the state inputs are then replaced by the learned initial states), ``h_neutral`` and
``c_neutral [L0, N, H]``, ``h_branches`` and ``c_branches [K, L1, N, H]``.
Outputs: ``rotations [N, J, 4]`` (unit quaternions w, x, y, z; the root's relative to the
heading frame), ``velocities [N, 3J]`` (normalised), and the four new states, same names with
an ``_out`` suffix. A style branch's state only advances where its target weight is non-zero.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from styleerd.atomic import atomic_write, atomic_write_text
from styleerd.model.stored import GeneratorWeights
from styleerd.runtime.numpy_step import step_weights

OPSET = 17


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
    y = g.op("Add", g.op("MatMul", x, g.const(W.astype(np.float32))), g.const(b.astype(np.float32)))
    return g.op("Relu", y) if relu else y


def _lstm_stack(g: _Graph, x: str, h: str, c: str, layers, keep: str | None) -> tuple[str, str, str]:
    """Stacked LSTM cells over states ``h, c [L, N, H]``; with ``keep [N, 1]`` (1 = advance),
    rows with keep 0 keep their old state. Returns (output, new h, new c)."""
    hs, cs = [], []
    for i, (w_in, w_hid, b) in enumerate(layers):
        index = g.const(np.array(i, dtype=np.int64))
        h_i, c_i = g.op("Gather", h, index, axis=0), g.op("Gather", c, index, axis=0)
        gates = g.op("Add", g.op("Add", g.op("MatMul", x, g.const(w_in)), g.op("MatMul", h_i, g.const(w_hid))), g.const(b))
        i_, f_, g_, o_ = g.op("Split", gates, outputs=4, axis=1)
        c_new = g.op("Add", g.op("Mul", g.op("Sigmoid", f_), c_i), g.op("Mul", g.op("Sigmoid", i_), g.op("Tanh", g_)))
        h_new = g.op("Mul", g.op("Sigmoid", o_), g.op("Tanh", c_new))
        x = h_new
        if keep is not None:  # h = h_old + keep * (h_new - h_old): exact for keep in {0, 1}
            h_new = g.op("Where", keep, h_new, h_i)
            c_new = g.op("Where", keep, c_new, c_i)
        axis0 = g.const(np.array([0], dtype=np.int64))
        hs.append(g.op("Unsqueeze", h_new, axis0))
        cs.append(g.op("Unsqueeze", c_new, axis0))
    return x, g.op("Concat", *hs, axis=0), g.op("Concat", *cs, axis=0)


def step_graph(model: GeneratorWeights) -> onnx.ModelProto:
    w = step_weights(model)
    c = model.config
    D, nS, nC, H, J = c.feature_dim, len(c.styles), len(c.contents), c.hidden, c.n_joints
    L0, K, L1 = len(w.neutral), len(w.branches), len(w.branches[0]) if w.branches else 0
    g = _Graph()
    first = g.op("Cast", "first_frame", to=TensorProto.BOOL)  # [N, 1]
    # neutral initial state by content: [N, nC] @ [nC, L0*H] -> [L0, N, H]
    def initial(table: np.ndarray, layers: int) -> str:
        flat = g.op("MatMul", "content", g.const(table.reshape(len(table), -1).astype(np.float32)))
        return g.op("Transpose", g.op("Reshape", flat, g.const(np.array([-1, layers, H], dtype=np.int64))), perm=[1, 0, 2])

    first_lnh = g.op("Unsqueeze", first, g.const(np.array([0], dtype=np.int64)))  # [1, N, 1]
    h = g.op("Where", first_lnh, initial(w.neutral_init[0], L0), "h_neutral")
    cc = g.op("Where", first_lnh, initial(w.neutral_init[1], L0), "c_neutral")
    z = g.op("Concat", "features", "style", "content", axis=1)
    for i, (W, b) in enumerate(w.encoder):
        z = _linear(g, z, W, b, relu=i < len(w.encoder) - 1)
    out, h_out, c_out = _lstm_stack(g, z, h, cc, w.neutral, keep=None)
    hb_out, cb_out = [], []
    first_klnh = g.op("Unsqueeze", first_lnh, g.const(np.array([0], dtype=np.int64)))  # [1, 1, N, 1]
    hb_all = g.op("Where", first_klnh, g.const(w.branch_init[0][:, :, None, :].astype(np.float32)), "h_branches")
    cb_all = g.op("Where", first_klnh, g.const(w.branch_init[1][:, :, None, :].astype(np.float32)), "c_branches")
    for k, s in enumerate(w.branch_styles):
        weight = g.op("Gather", "target", g.const(np.array([s], dtype=np.int64)), axis=1)  # [N, 1]
        keep = g.op("Not", g.op("Equal", weight, g.const(np.zeros(1, np.float32))))
        index = g.const(np.array(k, dtype=np.int64))
        y, hk, ck = _lstm_stack(g, z, g.op("Gather", hb_all, index, axis=0), g.op("Gather", cb_all, index, axis=0), w.branches[k], keep)
        out = g.op("Add", out, g.op("Mul", weight, y))
        axis0 = g.const(np.array([0], dtype=np.int64))
        hb_out.append(g.op("Unsqueeze", hk, axis0))
        cb_out.append(g.op("Unsqueeze", ck, axis0))
    y = g.op("Concat", out, "target", axis=1)
    for i, (W, b) in enumerate(w.decoder):
        y = _linear(g, y, W, b, relu=i < len(w.decoder) - 1)
    q = g.op("Reshape", g.op("Slice", y, g.const(np.array([0], np.int64)), g.const(np.array([4 * J], np.int64)), g.const(np.array([1], np.int64))),
             g.const(np.array([-1, J, 4], dtype=np.int64)))  # fmt: skip
    norm = g.op("Max", g.op("ReduceL2", q, axes=[2], keepdims=1), g.const(np.array(1e-8, np.float32)))
    g.nodes.append(helper.make_node("Div", [q, norm], ["rotations"]))
    g.nodes.append(helper.make_node("Slice", [y, g.const(np.array([4 * J], np.int64)), g.const(np.array([7 * J], np.int64)), g.const(np.array([1], np.int64))], ["velocities"]))
    for name, value in (("h_neutral_out", h_out), ("c_neutral_out", c_out)):
        g.nodes.append(helper.make_node("Identity", [value], [name]))
    for name, parts, whole in (("h_branches_out", hb_out, hb_all), ("c_branches_out", cb_out, cb_all)):
        g.nodes.append(helper.make_node("Concat", parts, [name], axis=0) if parts else helper.make_node("Identity", [whole], [name]))

    f32 = TensorProto.FLOAT
    inputs = [
        helper.make_tensor_value_info("features", f32, ["N", D]),
        helper.make_tensor_value_info("style", f32, ["N", nS]),
        helper.make_tensor_value_info("content", f32, ["N", nC]),
        helper.make_tensor_value_info("target", f32, ["N", nS]),
        helper.make_tensor_value_info("first_frame", f32, ["N", 1]),
        helper.make_tensor_value_info("h_neutral", f32, [L0, "N", H]),
        helper.make_tensor_value_info("c_neutral", f32, [L0, "N", H]),
        helper.make_tensor_value_info("h_branches", f32, [K, L1, "N", H]),
        helper.make_tensor_value_info("c_branches", f32, [K, L1, "N", H]),
    ]
    outputs = [
        helper.make_tensor_value_info("rotations", f32, ["N", J, 4]),
        helper.make_tensor_value_info("velocities", f32, ["N", 3 * J]),
        helper.make_tensor_value_info("h_neutral_out", f32, [L0, "N", H]),
        helper.make_tensor_value_info("c_neutral_out", f32, [L0, "N", H]),
        helper.make_tensor_value_info("h_branches_out", f32, [K, L1, "N", H]),
        helper.make_tensor_value_info("c_branches_out", f32, [K, L1, "N", H]),
    ]
    graph = helper.make_graph(g.nodes, "styleerd_step", inputs, outputs, g.initializers)
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="styleerd")
    proto.ir_version = 8  # readable by runtimes built for opset 17
    onnx.checker.check_model(proto, full_check=True)
    return proto


def export(model: GeneratorWeights, meta: dict, path: str | Path) -> None:
    """Write the step graph to ``path`` (.onnx) and beside it a JSON file with what a runtime
    needs around it: label orders, the skeleton, and the feature normalisation."""
    path = Path(path)
    proto = step_graph(model)
    atomic_write(path, lambda tmp: onnx.save(proto, tmp))
    c = model.config
    sidecar = {
        "graph": path.name,
        "opset": OPSET,
        "styles": list(c.styles),
        "contents": list(c.contents),
        "neutral_style": c.neutral_style,
        "feature_layout": "[rotations 4J (w,x,y,z) | positions 3J | velocities 3J | foot contacts 4], see docs/ONNX.md",
        "fps": meta.get("data", {}).get("fps"),
        "skeleton": meta["skeleton"],
        "stats": meta["stats"],
        "state_shapes": {i.name: [d.dim_param or d.dim_value for d in i.type.tensor_type.shape.dim] for i in proto.graph.input[5:]},
    }
    atomic_write_text(path.with_suffix(".json"), json.dumps(sidecar, indent=1) + "\n")
