"""Backends for the network's per-frame step: ``torch`` (the reference: ``StyleERD.step``; needs torch),
``numpy`` (the same arithmetic fused by hand: ``runtime.numpy_step``), ``numba`` (that
arithmetic compiled: ``runtime.compiled``, the fastest at batch 1), ``onnx`` (onnxruntime on
the exported step graph of ``runtime.onnx_export``, built on the ONNX LSTM op) and
``onnx-plain`` (the same graph with the LSTM cells written out).

Every backend keeps the recurrent state of N streams itself and has the same semantics as the
reference: a stream's first frame starts from the learned initial states (neutral branch by
content label, style branches their own); a style branch runs, and its state advances, only for
streams that give its style a non-zero weight.
"""

from __future__ import annotations

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, generator_weights
from styleerd.runtime.numpy_step import NumpyBackend

BACKENDS = ("torch", "numpy", "numba", "onnx", "onnx-plain")  # onnx: the LSTM-op graph; onnx-plain: cells written out


class TorchBackend:
    """Needs torch (``styleerd[train]``): the reference the other backends are tested against."""

    def __init__(self, model: GeneratorWeights, n_streams: int):
        from styleerd.model.checkpoint import torch_generator  # torch: only when asked for

        self.model, self.n = torch_generator(model), n_streams
        self.state = None
        self.first = np.ones(n_streams, dtype=bool)

    def reset(self, streams: np.ndarray | None = None) -> None:
        self.first[slice(None) if streams is None else streams] = True

    def step(self, x: np.ndarray, style: np.ndarray, content: np.ndarray, target: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        import torch

        if rows is not None:
            raise StyleERDError("the torch backend (the reference) steps all its streams at once; use numpy or onnx to step some")
        with torch.no_grad():
            return self._step(*(torch.as_tensor(np.asarray(a), dtype=torch.float32) for a in (x, style, content, target)))

    def _step(self, x, style, content, target) -> tuple[np.ndarray, np.ndarray]:
        import torch

        if self.first.all():
            self.state = None
        elif self.first.any():  # restart some streams: their rows go back to the initial states
            rows = torch.as_tensor(np.nonzero(self.first)[0])
            init = self.model.initial_state(content[rows])
            h, c = self.state.neutral
            self.state.neutral = (h.index_copy(1, rows, init.neutral[0]), c.index_copy(1, rows, init.neutral[1]))
            for k, (h, c) in self.state.branches.items():
                h0, c0 = self.model.branch_initial_state(k, len(rows))
                self.state.branches[k] = (h.index_copy(1, rows, h0), c.index_copy(1, rows, c0))
        self.first[:] = False
        rot, vel, self.state = self.model.step(x, style, content, target, self.state)
        return rot.numpy(), vel.numpy()


class OnnxBackend:
    """onnxruntime on the exported step graph (``form``: the LSTM-op graph, or the plain one;
    ``styles``: only these styles' branches, for targets that use no others)."""

    def __init__(self, model: GeneratorWeights, n_streams: int, threads: int = 1, form: str = "lstm", styles: tuple[str, ...] | None = None):
        import onnxruntime as ort

        from styleerd.runtime.onnx_export import state_shape, step_graph

        options = ort.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads = threads, 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        self.session = ort.InferenceSession(step_graph(model, form, styles).SerializeToString(), options, providers=["CPUExecutionProvider"])
        rows, _, width = state_shape(model, form, styles)
        self.n = n_streams
        self.state = {name: np.zeros((rows, n_streams, width), np.float32) for name in ("h", "c")}
        self.first = np.ones((n_streams, 1), np.float32)

    def reset(self, streams: np.ndarray | None = None) -> None:
        self.first[slice(None) if streams is None else streams] = 1.0

    def step(self, x: np.ndarray, style: np.ndarray, content: np.ndarray, target: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        sel = slice(None) if rows is None else rows
        feeds = {"features": x, "style": style, "content": content, "target": target, "first_frame": self.first[sel], "h": self.state["h"][:, sel], "c": self.state["c"][:, sel]}
        rot, vel, h, c = self.session.run(None, {k: np.ascontiguousarray(v, np.float32) for k, v in feeds.items()})
        self.state["h"][:, sel], self.state["c"][:, sel] = h, c
        self.first[sel] = 0.0
        return rot, vel


def make_backend(name: str, model: GeneratorWeights, n_streams: int, threads: int = 1):
    """The step backend ``name`` for ``n_streams`` streams; ``threads``: onnxruntime's intra-op
    threads (numpy and numba are split over threads by the stylizer, torch uses its global pool)."""
    if name not in BACKENDS:
        raise StyleERDError(f"unknown backend {name!r}; valid: {', '.join(BACKENDS)}")
    model = generator_weights(model)
    try:
        if name == "numba":
            from styleerd.runtime.compiled import CompiledBackend  # imports numba: only when asked for

            return CompiledBackend(model, n_streams)
        if name in ("onnx", "onnx-plain"):
            return OnnxBackend(model, n_streams, threads, form="plain" if name == "onnx-plain" else "lstm")
        return {"torch": TorchBackend, "numpy": NumpyBackend}[name](model, n_streams)
    except ImportError as e:  # the light install has numpy and numba; torch and onnxruntime come with styleerd[train]
        raise StyleERDError(f"the {name} backend needs {e.name or e}: pip install 'styleerd[train]'") from None
