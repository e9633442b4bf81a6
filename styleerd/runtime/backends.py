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

import threading

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, generator_weights
from styleerd.runtime.numpy_step import NumpyBackend

# streams per call from which the onnx backend runs a one-style LSTM graph with one op per layer,
# not per depth (1 thread, us per call fused / one op per layer: 8 streams 238 / 303, 32: 573 /
# 481, 500: 7,818 / 6,925)
UNFUSED_FROM = 16

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

    def step(
        self, x: np.ndarray, style: np.ndarray, content: np.ndarray, target: np.ndarray, rows: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        import torch

        if rows is not None:
            raise StyleERDError(
                "the torch backend (the reference) steps all its streams at once; use numpy or onnx to step some"
            )
        with torch.no_grad():
            return self._step(
                *(torch.as_tensor(np.asarray(a), dtype=torch.float32) for a in (x, style, content, target))
            )

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
    """onnxruntime on the exported step graphs (``form``: the LSTM-op graph, or the plain one).

    Each step runs, for each group of streams that weight the same styles, the graph of those
    styles' branches only (``export-onnx --styles``, grouped: ``step_graph``; built on first
    use and kept): the arithmetic of the branches that run, as the numpy backend does, not of
    every branch (at 1,000 streams to one style, 3x the frames/s). ``every_branch``: one graph of every style's
    branches for all streams, what a host that exports one graph runs. The state of every
    branch is kept here, streams first (``h, c [N, S, H]``, rows in ``state_layers`` order); a
    stream's first frame takes the learned initial states of all its rows, so a branch that
    first runs later starts from its own."""

    def __init__(
        self, model: GeneratorWeights, n_streams: int, threads: int = 1, form: str = "lstm", every_branch: bool = False
    ):
        import onnxruntime as ort

        from styleerd.runtime.onnx_export import initial_states, state_layers

        self.options = ort.SessionOptions()
        self.options.intra_op_num_threads, self.options.inter_op_num_threads = threads, 1
        self.options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        c = model.config
        self.model, self.form, self.n, self.every_branch = model, form, n_streams, every_branch
        self.layers = state_layers(model)
        self.styles = np.array([c.styles[s] for s in c.branch_styles])  # a branch per style, the target's column
        self.columns = np.array(c.branch_styles, dtype=np.int64)
        self.initial = initial_states(model).reshape(len(c.contents), 2, len(self.layers), c.hidden)
        self.h = np.zeros((n_streams, len(self.layers), c.hidden), np.float32)
        self.c = np.zeros_like(self.h)
        self.first = np.ones(n_streams, dtype=bool)
        self.graphs: dict = {}  # (styles (None: every style), fuse) -> (session, its state rows among self.layers)
        self.by_pattern: dict = {}  # bytes of a row of target != 0 -> the same
        self.building = threading.Lock()
        self.no_first = np.zeros(
            (n_streams, 1), np.float32
        )  # the graph of every branch: first frames are reset here, not by it

    def reset(self, streams: np.ndarray | None = None) -> None:
        self.first[slice(None) if streams is None else streams] = True

    def graph(self, styles: tuple[str, ...] | None, fuse: bool | None = None):
        """The session of the graph with the branches of ``styles`` (None: every style; ``fuse``:
        see ``step_graph``), and the rows of its state."""
        with self.building:  # shards of streams step concurrently: one build per graph
            if (styles, fuse) not in self.graphs:
                import onnxruntime as ort

                from styleerd.runtime.onnx_export import state_layers, step_graph

                proto = step_graph(self.model, self.form, styles, fuse, grouped=not self.every_branch)
                session = ort.InferenceSession(
                    proto.SerializeToString(), self.options, providers=["CPUExecutionProvider"]
                )
                self.graphs[(styles, fuse)] = (
                    session,
                    np.array([self.layers.index(row) for row in state_layers(self.model, styles)]),
                )
            return self.graphs[(styles, fuse)]

    def _graph_of(self, weighted: np.ndarray, n: int):
        """``graph`` of the styles a row of ``target != 0`` weights for a call of ``n`` streams
        (from ``UNFUSED_FROM``, the LSTM form with one op per layer), looked up by its bytes: the
        per-frame path."""
        unfused = n >= UNFUSED_FROM and self.form == "lstm"
        key = weighted.tobytes() + (b"u" if unfused else b"")
        if key not in self.by_pattern:
            styles = None if self.every_branch else tuple(self.styles[weighted[self.columns]])
            self.by_pattern[key] = self.graph(styles, False if unfused else None)
        return self.by_pattern[key]

    def step(
        self, x: np.ndarray, style: np.ndarray, content: np.ndarray, target: np.ndarray, rows: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        f32 = np.ascontiguousarray
        inputs = (f32(x, np.float32), f32(style, np.float32), f32(content, np.float32), f32(target, np.float32))
        # a slice of streams (every stream, a shard) stays one: its state rows are read and written as views
        streams = (
            slice(None)
            if rows is None
            else slice(*rows.indices(self.n))
            if isinstance(rows, slice)
            else np.arange(self.n)[rows]
        )
        fresh = self.first[streams]
        if fresh.any():
            at = np.arange(self.n)[streams][fresh]
            start = np.einsum("nk,k...->n...", inputs[2][fresh], self.initial)
            self.h[at], self.c[at], self.first[at] = start[:, 0], start[:, 1], False
        weighted = inputs[3] != 0
        if (
            len(weighted) == 1 or self.every_branch or not (weighted != weighted[:1]).any()
        ):  # one group (the usual case)
            return self._run(
                self._graph_of(weighted[0] if len(weighted) else weighted.any(0), len(weighted)), streams, inputs
            )
        # streams grouped by the styles they weight
        patterns, which = np.unique(weighted, axis=0, return_inverse=True)
        ids, c = np.arange(self.n)[streams], self.model.config
        rot, vel = (
            np.empty((len(weighted), c.n_joints, 4), np.float32),
            np.empty((len(weighted), 3 * c.n_joints), np.float32),
        )
        for g, pattern in enumerate(patterns):
            members = np.nonzero(which.ravel() == g)[0]
            at = ids[members]
            rot[members], vel[members] = self._run(
                self._graph_of(pattern, len(members)), at, tuple(a[members] for a in inputs)
            )
        return rot, vel

    def _run(self, graph, at, inputs) -> tuple[np.ndarray, np.ndarray]:
        """One call of ``graph`` (session, state rows) on the streams ``at`` (a slice, or their
        indices), their state rows read and written back here."""
        session, layers = graph
        h, c = self.h[at], self.c[at]
        h, c = h.take(layers, axis=1), c.take(layers, axis=1)  # [n, S', H]
        n = len(h)
        if self.form == "lstm":  # [1, n, S' H]: the rows side by side
            h, c = h.reshape(1, n, -1), c.reshape(1, n, -1)
        else:  # [S', n, H]
            h, c = np.ascontiguousarray(h.transpose(1, 0, 2)), np.ascontiguousarray(c.transpose(1, 0, 2))
        x, style, content, target = inputs
        feeds = {"features": x, "style": style, "content": content, "target": target, "h": h, "c": c}
        if self.every_branch:
            feeds["first_frame"] = self.no_first[:n]
        rot, vel, h, c = session.run(None, feeds)
        h, c = (
            (h.reshape(n, len(layers), -1), c.reshape(n, len(layers), -1))
            if self.form == "lstm"
            else (h.transpose(1, 0, 2), c.transpose(1, 0, 2))
        )
        rows = (at, layers) if isinstance(at, slice) else np.ix_(at, layers)
        self.h[rows], self.c[rows] = h, c
        return rot, vel


def make_backend(name: str, model: GeneratorWeights, n_streams: int, threads: int = 1, paired: bool = False):
    """The step backend ``name`` for ``n_streams`` streams; ``threads``: the numba step's
    threads for many streams (``data.parallel``), onnxruntime's intra-op threads (StreamStylizer
    on N threads splits large onnx and numpy steps into N shards of streams instead, each on
    one); torch uses its global pool. ``paired`` (numpy and numba): with ``step_pair``."""
    if name not in BACKENDS:
        raise StyleERDError(f"unknown backend {name!r}; valid: {', '.join(BACKENDS)}")
    model = generator_weights(model)
    try:
        if name == "numba":
            from styleerd.runtime.compiled import CompiledBackend  # imports numba: only when asked for

            return CompiledBackend(model, n_streams, threads, paired=paired)
        if name in ("onnx", "onnx-plain"):
            return OnnxBackend(model, n_streams, threads, form="plain" if name == "onnx-plain" else "lstm")
        if name == "numpy":
            return NumpyBackend(model, n_streams, paired)
        return TorchBackend(model, n_streams)
    except ImportError as e:  # the light install has numpy and numba; torch and onnxruntime come with styleerd[train]
        raise StyleERDError(f"the {name} backend needs {e.name or e}: pip install 'styleerd[train]'") from None
