"""The numpy, numba and onnxruntime step backends against the torch reference: same outputs (<= 1e-5)
over streams that start, switch styles, mix, and restart."""

from dataclasses import replace

import numpy as np
import onnx
import pytest
import torch

from styleerd.errors import StyleERDError
from styleerd.model.checkpoint import load_generator
from styleerd.model.generator import StyleERD
from styleerd.runtime.backends import BACKENDS, make_backend
from styleerd.runtime.onnx_export import FORMS, OPSET, state_layers, state_shape, step_graph


@pytest.fixture(scope="module")
def model():
    return load_generator()[0]


def schedule(model, n_streams=3, frames=12, seed=0):
    """Per frame: normalised features, labels and target weights that change mid-stream."""
    rng = np.random.default_rng(seed)
    c = model.config
    nS, nC = len(c.styles), len(c.contents)
    style = np.eye(nS, dtype=np.float32)[rng.integers(0, nS, n_streams)]
    content = rng.dirichlet(np.ones(nC), n_streams).astype(np.float32)  # probabilities, as inferred labels are
    for t in range(frames):
        target = np.zeros((n_streams, nS), np.float32)
        target[0, (t // 4) % nS] = 1.0  # stream 0 switches style every 4 frames
        target[1, [1, 3]] = [0.3, 0.7]  # stream 1: a mixture
        target[2, c.neutral_index] = 1.0  # stream 2: neutral only, no branch runs
        yield rng.normal(0, 1, (n_streams, c.feature_dim)).astype(np.float32), style, content, target


def pose_change_twin(model, seed: int = 0):
    """``model`` as a ``pose_change`` network (its decoder's rotations a change to the input's own),
    the change's layer perturbed so that every joint turns."""
    twin = StyleERD(replace(model.config, pose_change=True), model.skeleton, model.stats())
    twin.load_state_dict(model.state_dict())
    twin.start_at_no_change()
    noise = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        rows = twin.decoder[-1].weight[: 4 * model.config.n_joints]
        rows += 0.05 * torch.randn(rows.shape, generator=noise)
    return twin.eval()


@pytest.mark.parametrize("pose_change", [False, True], ids=["pose", "change to the input's pose"])
def test_backends_agree_with_the_torch_reference(model, pose_change):
    if pose_change:
        model = pose_change_twin(model)
    backends = {name: make_backend(name, model, 3) for name in BACKENDS}
    for t, (x, s, c, w) in enumerate(schedule(model)):
        if t == 7:
            for b in backends.values():
                b.reset(np.array([1]))  # stream 1 starts over
        ref_rot, ref_vel = backends["torch"].step(x, s, c, w)
        for name in ("numpy", "numba", "onnx", "onnx-plain"):
            rot, vel = backends[name].step(x, s, c, w)
            assert np.abs(rot - ref_rot).max() <= 1e-5, (name, t)
            assert np.abs(vel - ref_vel).max() <= 1e-4, (name, t)


@pytest.mark.parametrize("form", FORMS)
def test_exported_graphs_pass_the_full_check_at_opset_15(model, form):
    proto = step_graph(model, form)
    assert proto.opset_import[0].version == OPSET <= 15
    kinds = {n.op_type for n in proto.graph.node}
    if form == "lstm":  # one LSTM op per layer of every branch (one per layer depth with one style), no cell arithmetic
        assert (
            sum(n.op_type == "LSTM" for n in proto.graph.node) == len(state_layers(model))
            and not {"Sigmoid", "Tanh"} & kinds
        )
        one = step_graph(model, form, ("elderly",))
        assert sum(n.op_type == "LSTM" for n in one.graph.node) == max(
            model.config.neutral_layers, model.config.style_layers
        )
    else:
        assert "LSTM" not in kinds and {"MatMul", "Sigmoid", "Tanh"} <= kinds
    assert [i.name for i in proto.graph.input] == ["features", "style", "content", "target", "first_frame", "h", "c"]
    assert [o.name for o in proto.graph.output] == ["rotations", "velocities", "h_out", "c_out"]
    onnx.checker.check_model(proto, full_check=True)
    # grouped (OnnxBackend's): no first_frame input, none of the Where ops that reset and keep rows
    for styles in (("elderly",), ("elderly", "angry" if "angry" in model.config.styles else "feminine"), ()):
        grouped = step_graph(model, form, styles, grouped=True)
        assert [i.name for i in grouped.graph.input] == ["features", "style", "content", "target", "h", "c"]
        assert "Where" not in {n.op_type for n in grouped.graph.node} and "Where" in {
            n.op_type for n in step_graph(model, form, styles).graph.node
        }
        onnx.checker.check_model(grouped, full_check=True)


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("styles", [("elderly", "youthful"), ("youthful",)])
def test_a_graph_of_some_styles_equals_the_reference_on_them(model, form, styles):
    import onnxruntime as ort

    session = ort.InferenceSession(
        step_graph(model, form, styles).SerializeToString(), providers=["CPUExecutionProvider"]
    )
    reference = make_backend("torch", model, 3)
    c = model.config
    rows, _, width = state_shape(model, form, styles)
    assert (
        rows * width
        == (c.neutral_layers + len(styles) * c.style_layers) * c.hidden
        == len(state_layers(model, styles)) * c.hidden
    )
    h = cc = np.zeros((rows, 3, width), np.float32)
    for t, (x, s, content, _) in enumerate(schedule(model)):
        target = np.zeros((3, len(c.styles)), np.float32)
        target[0, c.styles.index(styles[t // 6 % len(styles)])] = 1.0  # a switch between the two
        target[1, [c.styles.index(styles[0]), c.styles.index(styles[1]) if len(styles) > 1 else c.neutral_index]] = [
            0.4,
            0.6,
        ]  # a mixture, an intensity
        target[2, c.neutral_index if t < 9 else c.styles.index(styles[0])] = 1.0  # its branch starts late
        ref_rot, ref_vel = reference.step(x, s, content, target)
        rot, vel, h, cc = session.run(
            None,
            {
                "features": x,
                "style": s,
                "content": content,
                "target": target,
                "first_frame": np.full((3, 1), float(t == 0), np.float32),
                "h": h,
                "c": cc,
            },
        )
        assert np.abs(rot - ref_rot).max() <= 1e-5 and np.abs(vel - ref_vel).max() <= 1e-4, t
    with pytest.raises(StyleERDError, match="no style branch for angry"):
        step_graph(model, "lstm", ("angry",))


@pytest.mark.parametrize("kind", ["numpy", "compiled"])
def test_numpy_and_compiled_labellers_equal_the_torch_labeller(kind):
    """The labeller's step, numpy (the numpy and onnx backends') and compiled (numba's), against torch's
    over 20 frames of 3 streams, every other frame stepped as rows of the state (2 and 0, then 1)."""
    import torch

    from styleerd.model.checkpoint import load_labeller
    from styleerd.runtime.compiled import CompiledLabeller
    from styleerd.runtime.numpy_step import NumpyLabeller

    labeller, _ = load_labeller()
    x = np.random.default_rng(0).normal(0, 1, (3, 20, labeller.in_dim)).astype(np.float32)
    with torch.no_grad():
        s_logits, c_logits, _ = labeller(torch.from_numpy(x))
    fast = (NumpyLabeller if kind == "numpy" else CompiledLabeller)(labeller, 3)
    for t in range(20):
        for rows in [np.array([2, 0]), np.array([1])] if t % 2 else [None]:
            at = slice(None) if rows is None else rows
            p_style, p_content, fast.h[at] = fast.step(x[at, t], rows)
            assert np.abs(p_style - s_logits[at, t].softmax(-1).numpy()).max() < 1e-5
            assert np.abs(p_content - c_logits[at, t].softmax(-1).numpy()).max() < 1e-5


@pytest.mark.parametrize("n", [8, 300])
def test_numba_backend_switches_paths_by_batch_on_one_state(model, n):
    """One stream runs the compiled step's own products, more its BLAS calls; both on the same
    state, both equal to the numpy backend."""
    c = model.config
    ref, fast = make_backend("numpy", model, n), make_backend("numba", model, n)
    rng = np.random.default_rng(3)
    style = np.eye(len(c.styles), dtype=np.float32)[rng.integers(0, len(c.styles), n)]
    content = np.eye(len(c.contents), dtype=np.float32)[rng.integers(0, len(c.contents), n)]
    target = np.eye(len(c.styles), dtype=np.float32)[rng.integers(0, len(c.styles), n)]
    for t in range(12):
        rows = None if t % 3 == 0 else np.sort(rng.choice(n, size=t % 3, replace=False))  # all streams, then 1, then 2
        sel = slice(None) if rows is None else rows
        x = rng.normal(0, 1, (n if rows is None else len(rows), c.feature_dim)).astype(np.float32)
        want = ref.step(x, style[sel], content[sel], target[sel], rows)
        got = fast.step(x, style[sel], content[sel], target[sel], rows)
        assert np.abs(got[0] - want[0]).max() <= 1e-5 and np.abs(got[1] - want[1]).max() <= 1e-4, t


@pytest.mark.parametrize("name, n, threads", [("numpy", 5, 1), ("numba", 5, 1), ("numba", 300, 2)])
def test_a_paired_step_equals_two_backends_stepped_alike(model, name, n, threads):
    """``step_pair`` (the default pose's target and identity passes on one encoder and neutral
    stack) gives what two backends give, each stepped to one of the targets, over streams that
    start, switch, mix, restart and step some rows at a time (a slice, indices); on 2 threads
    the numba step splits into shards. A backend not made paired refuses it."""
    c = model.config
    nS, nI = len(c.styles), len(c.input_styles)
    paired = make_backend(name, model, n, threads, paired=True)
    to_target, to_second = make_backend(name, model, n, threads), make_backend(name, model, n, threads)
    rng = np.random.default_rng(7)
    for t in range(12):
        if t == 6:
            for b in (paired, to_target, to_second):
                b.reset(np.array([1, 3]))
        rows = (None, slice(1, n - 1), np.array([n - 1, 0, 2]))[t % 3]
        m = n if rows is None else len(np.arange(n)[rows])
        x = rng.normal(0, 1, (m, c.feature_dim)).astype(np.float32)
        style = np.eye(nI, dtype=np.float32)[rng.integers(0, nI, m)]
        content = rng.dirichlet(np.ones(len(c.contents)), m).astype(np.float32)
        target = rng.dirichlet(np.full(nS, 0.3), m).astype(np.float32) * (rng.random((m, nS)) < 0.6)
        second = np.zeros((m, nS), np.float32)
        second[:, :nI] = style  # the identity transfer's target
        rot, vel, rot2 = paired.step_pair(x, style, content, target, second, rows)
        want_rot, want_vel = to_target.step(x, style, content, target, rows)
        want_rot2, _ = to_second.step(x, style, content, second, rows)
        assert np.abs(rot - want_rot).max() <= 1e-5 and np.abs(vel - want_vel).max() <= 1e-4, t
        assert np.abs(rot2 - want_rot2).max() <= 1e-5, t
    with pytest.raises(ValueError, match="paired"):
        to_target.step_pair(x, style, content, target, second, rows)


@pytest.mark.parametrize("threads", [1, 2])
def test_numba_steps_streams_by_index_in_their_rows_of_the_state(model, threads):
    """A server's batch: many streams by index, in no order, over several blocks of the step and a
    mix of targets (each branch run by some streams only), paired and not. The numba step reads and
    writes the streams' rows itself (``state_rows``); it equals the numpy backend, which gathers the
    rows and writes them back, and leaves every other stream's state as it was. Repeated rows and
    rows outside the state are refused."""
    from styleerd.runtime.calibration import EngineSettings, StepChoice
    from styleerd.runtime.compiled import CompiledBackend

    c = model.config
    nS, nI, n = len(c.styles), len(c.input_styles), 300
    settings = EngineSettings((1,), (StepChoice(32, False, 1),), (StepChoice(32, False, threads),), "test")
    fast, single = (CompiledBackend(model, n, threads, settings, paired=p) for p in (True, False))
    ref, ref_single = make_backend("numpy", model, n, paired=True), make_backend("numpy", model, n)
    rng = np.random.default_rng(11)
    for t in range(6):
        rows = rng.permutation(n)[: 150 + 10 * t]  # not sorted, so not a slice
        if t == 3:
            for b in (fast, ref, single, ref_single):
                b.reset(rows[:7])
        m = len(rows)
        x = rng.normal(0, 1, (m, c.feature_dim)).astype(np.float32)
        style = np.eye(nI, dtype=np.float32)[rng.integers(0, nI, m)]
        content = rng.dirichlet(np.ones(len(c.contents)), m).astype(np.float32)
        target = rng.dirichlet(np.full(nS, 0.3), m).astype(np.float32) * (rng.random((m, nS)) < 0.5)
        second = np.zeros((m, nS), np.float32)
        second[:, :nI] = style
        untouched = np.setdiff1d(np.arange(n), rows)
        kept = fast.hb[untouched].copy(), fast.h[untouched].copy()
        got = fast.step_pair(x, style, content, target, second, rows)
        want = ref.step_pair(x, style, content, target, second, rows)
        for a, b in zip(got, want):
            assert np.abs(a - b).max() <= 1e-4, t
        assert (fast.hb[untouched] == kept[0]).all() and (fast.h[untouched] == kept[1]).all()
        for state in ("h", "c", "hb", "cb", "hb2", "cb2"):
            assert np.abs(getattr(fast, state) - getattr(ref, state)).max() <= 1e-4, (t, state)
        assert (fast.first == ref.first).all()
        got, want = single.step(x, style, content, target, rows), ref_single.step(x, style, content, target, rows)
        assert np.abs(got[0] - want[0]).max() <= 1e-5 and np.abs(got[1] - want[1]).max() <= 1e-4, t
    with pytest.raises(ValueError, match="at most once"):
        fast.step(x[:2], style[:2], content[:2], target[:2], np.array([4, 4]))
    with pytest.raises(ValueError, match="outside"):
        fast.step(x[:2], style[:2], content[:2], target[:2], np.array([4, n]))


@pytest.mark.parametrize("name", ["numpy", "numba", "onnx"])
def test_shards_of_streams_stepped_at_once_equal_one_step_of_all(model, name):
    """What StreamStylizer and the bench's network throughput do on two threads: disjoint
    slices of the streams stepped concurrently, in place, give every stream the step of all."""
    from concurrent.futures import ThreadPoolExecutor

    from styleerd.eval.bench import network_throughput

    c, n = model.config, 700
    whole, sharded = make_backend(name, model, n), make_backend(name, model, n)
    rng = np.random.default_rng(5)
    style = np.eye(len(c.input_styles), dtype=np.float32)[rng.integers(0, len(c.input_styles), n)]
    content = np.eye(len(c.contents), dtype=np.float32)[rng.integers(0, len(c.contents), n)]
    target = np.eye(len(c.styles), dtype=np.float32)[rng.integers(0, len(c.styles), n)]
    shards = [slice(0, 350), slice(350, n)]
    with ThreadPoolExecutor(2) as pool:
        for t in range(4):
            x = rng.normal(0, 1, (n, c.feature_dim)).astype(np.float32)
            want = whole.step(x, style, content, target)
            got = list(pool.map(lambda s, x=x: sharded.step(x[s], style[s], content[s], target[s], s), shards))
            # not bit for bit: BLAS may sum a 350-row product in another order than a 700-row one (OpenBLAS's Haswell
            # kernels do)
            assert np.abs(np.concatenate([r for r, _ in got]) - want[0]).max() <= 1e-5, t
    for state in ("h", "c") if name == "onnx" else ("h", "hb"):  # the onnx backend's h, c hold every branch's rows
        assert np.abs(getattr(whole, state) - getattr(sharded, state)).max() <= 1e-5, state
    assert network_throughput(model, name, n_streams=64, seconds=0.01) > 0


def test_the_network_throughput_steps_numba_in_the_callers_thread_as_the_stylizer_does(model, monkeypatch):
    """A pool's hand-off (50-80 us a call on 2 cores) is not part of a numba step: StreamStylizer
    calls it in its own thread, and the bench's small-batch figures once counted the hand-off."""
    import threading

    from styleerd.eval import bench

    callers, make = set(), bench.make_backend

    def spied(*args, **kwargs):
        backend = make(*args, **kwargs)
        step = backend.step
        backend.step = lambda *a: (callers.add(threading.get_ident()), step(*a))[1]
        return backend

    monkeypatch.setattr(bench, "make_backend", spied)
    assert bench.network_throughput(model, "numba", n_streams=4, seconds=0.01) > 0
    assert callers == {threading.get_ident()}


@pytest.mark.parametrize("n, threads", [(3, 1), (100, 1), (100, 2)])
def test_numba_backend_refuses_inputs_that_do_not_fit_its_state(model, n, threads):
    """The compiled step does not check bounds; a call whose rows or widths do not fit is an
    error before it runs, never a write past the state (on 2 threads: before the shards split)."""
    c = model.config
    b = make_backend("numba", model, n, threads)
    x = np.zeros((n, c.feature_dim), np.float32)
    one = lambda k: np.eye(k, dtype=np.float32)[np.zeros(n, int)]
    style, content, target = one(len(c.input_styles)), one(len(c.contents)), one(len(c.styles))
    b.step(x, style, content, target)
    for bad in (
        (x[:-1], style, content, target),
        (x, style, content, target[:-1]),
        (x[:, :-1], style, content, target),
        (x, style, content, target[:, :-1]),
        (x[:2], style[:2], content[:2], target[:2], np.array([0])),
    ):
        with pytest.raises(ValueError, match="do not fit"):
            b.step(*bad)


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_compiled_gemm_reads_blocks_of_columns_in_place(beta):
    """The numba step's BLAS call (``compiled._gemm``) on operands whose rows are strided (a
    block of a state's columns, as the LSTM layers read them), against numpy."""
    from styleerd.runtime.compiled import _gemm

    rng = np.random.default_rng(1)
    state = rng.normal(size=(50, 7 * 32)).astype(np.float32)
    weights = rng.normal(size=(70, 3 * 128)).astype(np.float32)
    out = rng.normal(size=(50, 2 * 128)).astype(np.float32)
    x, W, y = state[:, 64:128], weights[3:67, 128:256], out[:, 128:]
    want = x.astype(np.float64) @ W + beta * y
    before = out.copy()
    _gemm(x, W, y, np.float32(beta))
    assert np.abs(y - want).max() < 1e-4
    assert np.array_equal(out[:, :128], before[:, :128])  # the columns beside the block are untouched


def test_shards_limit_the_blas_the_compiled_step_calls_even_if_made_first():
    """StreamStylizer's shards hold BLAS to one thread each; the numba step's BLAS (scipy's) is
    among those held even when the limits were first taken before that backend was loaded."""
    import subprocess
    import sys

    code = """
from styleerd.runtime.numpy_step import _blas_pools
held = {c.filepath for c in _blas_pools().lib_controllers}
import styleerd.runtime.compiled
from threadpoolctl import threadpool_info
loaded = {i["filepath"] for i in threadpool_info() if i["user_api"] == "blas"}
assert loaded <= held, (loaded, held)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr


def test_tanh_fraction_gives_tanh_and_sigmoid_to_float32_precision():
    """The numba LSTM cell's activations: tanh(v) = p / q and sigmoid(v) = (q + p) / 2q for
    (p, q) = tanh_fraction(v / 2), across and past the range where they saturate."""
    from styleerd.runtime.compiled import tanh_fraction

    v = np.append(np.linspace(-30.0, 30.0, 600_001).astype(np.float32)[::97], np.float32(0.0))
    p, q = np.array([tanh_fraction(a) for a in v]).T
    assert np.abs(p / q - np.tanh(v.astype(np.float64))).max() < 5e-7 and p[-1] == 0.0
    p, q = np.array([tanh_fraction(np.float32(0.5) * a) for a in v]).T
    assert np.abs((q + p) / (2 * q) - 1 / (1 + np.exp(-v.astype(np.float64)))).max() < 5e-7


def test_the_compiled_cells_are_an_lstm_layer_on_their_columns_alone():
    """``compiled._cells`` (what ``engine_cpu.py`` times alone) against an LSTM cell in float64
    (gates i, f, g, o): the state's columns ``a`` to ``a + H`` updated, every other column kept."""
    from styleerd.runtime.compiled import _cells

    rng = np.random.default_rng(3)
    N, H, a = 5, 8, 16
    g, bias = rng.normal(0, 3, (N, 4 * H)).astype(np.float32), rng.normal(0, 1, 4 * H).astype(np.float32)
    hs, cs = rng.normal(0, 1, (N, 40)).astype(np.float32), rng.normal(0, 1, (N, 40)).astype(np.float32)
    h0, c0 = hs.copy(), cs.copy()
    _cells(g, bias, hs, cs, a, H)
    sig = lambda v: 1 / (1 + np.exp(-v))
    v = g.astype(np.float64) + bias
    i, f, cand, o = sig(v[:, :H]), sig(v[:, H : 2 * H]), np.tanh(v[:, 2 * H : 3 * H]), sig(v[:, 3 * H :])
    c = f * c0[:, a : a + H] + i * cand
    np.testing.assert_allclose(cs[:, a : a + H], c, atol=2e-6)
    np.testing.assert_allclose(hs[:, a : a + H], o * np.tanh(c), atol=2e-6)
    outside = np.r_[0:a, a + H : 40]
    assert (hs[:, outside] == h0[:, outside]).all() and (cs[:, outside] == c0[:, outside]).all()


def test_onnx_backend_runs_many_streams_on_a_graph_of_one_op_per_layer(model):
    """A call of many streams (from ``UNFUSED_FROM``) runs the one-style LSTM graph with an op
    per layer (faster there), a few streams the one with an op per depth; same outputs."""
    from styleerd.runtime.backends import UNFUSED_FROM

    c, n = model.config, UNFUSED_FROM + 4
    ref, onnx_ = make_backend("numpy", model, n), make_backend("onnx", model, n)
    rng = np.random.default_rng(2)
    one = lambda k, i: np.eye(k, dtype=np.float32)[np.full(n, i)]
    style, content, target = (
        one(len(c.input_styles), c.neutral_index),
        one(len(c.contents), 4),
        one(len(c.styles), c.styles.index("elderly")),
    )
    for t in range(6):
        rows = np.arange(3) if t % 2 else None  # a few streams, then all
        sel = slice(None) if rows is None else rows
        x = rng.normal(0, 1, (n, c.feature_dim)).astype(np.float32)[sel]
        want, got = (
            ref.step(x, style[sel], content[sel], target[sel], rows),
            onnx_.step(x, style[sel], content[sel], target[sel], rows),
        )
        assert np.abs(got[0] - want[0]).max() <= 1e-5, t
    assert set(onnx_.graphs) == {(("elderly",), None), (("elderly",), False)}
    counts = {
        fuse: sum(node.op_type == "LSTM" for node in step_graph(model, "lstm", ("elderly",), fuse).graph.node)
        for fuse in (True, False)
    }
    assert counts == {True: max(c.neutral_layers, c.style_layers), False: c.neutral_layers + c.style_layers}


def test_a_stylizer_on_threads_runs_onnxruntime_on_them(model):
    """Throughput on N threads means onnxruntime runs on N threads (it once ran on one while the
    table said two): a step of many streams is N shards, each on its own thread and one call of
    a one-thread session."""
    import threading

    from styleerd.runtime.stylizer import StreamStylizer

    J = model.config.n_joints
    for name in ("onnx", "onnx-plain"):
        st = StreamStylizer(model, "normal", "walk", {"elderly": 1.0}, n_streams=300, backend=name, threads=2)
        calls, step = [], st.backend.step
        st.backend.step = lambda *a, calls=calls, step=step: (
            calls.append((threading.current_thread().name, len(a[0]))) or step(*a)
        )
        st.step(np.zeros((300, J, 4)) + [1, 0, 0, 0], np.zeros((300, J, 3)))
        # two threads: the caller's and one of the stylizer's pool
        assert sorted(n for _, n in calls) == [150, 150] and sorted(
            t.startswith("styleerd-shard") for t, _ in calls
        ) == [False, True]
        assert {s.get_session_options().intra_op_num_threads for s, _ in st.backend.graphs.values()} == {1}
    assert make_backend("onnx", model, 1, threads=2).options.intra_op_num_threads == 2


@pytest.mark.parametrize("name", ["onnx", "onnx-plain"])
def test_onnx_backend_runs_each_group_of_streams_on_the_graph_of_its_styles(model, name):
    """Streams that weight different styles run on the graphs of those styles' branches, one
    graph per group; the outputs and the kept state equal the graph of every branch's, and a
    branch that first runs after a stream restarted starts from its learned initial state,
    not from where the stream's earlier life left it. Some frames step some streams only, in
    any order (the numpy backend, checked against torch above, is the reference)."""
    c = model.config
    ref, grouped, every = make_backend("numpy", model, 4), make_backend(name, model, 4), make_backend(name, model, 4)
    every.every_branch = True
    rng = np.random.default_rng(7)
    style = np.eye(len(c.input_styles), dtype=np.float32)[rng.integers(0, len(c.input_styles), 4)]
    content = np.eye(len(c.contents), dtype=np.float32)[rng.integers(0, len(c.contents), 4)]
    elderly, youthful = c.styles.index("elderly"), c.styles.index("youthful")
    for t in range(12):
        target = np.zeros((4, len(c.styles)), np.float32)
        target[0, elderly if t < 4 or t >= 8 else c.neutral_index] = 1.0  # elderly, restart and neutral, elderly again
        target[1, [elderly, youthful]] = [0.5, 0.5]
        target[2, youthful] = 0.3  # an intensity
        target[3, c.neutral_index] = 1.0  # no branch
        if t == 4:
            for b in (ref, grouped, every):
                b.reset(np.array([0]))
        rows = {5: np.array([3, 1, 0]), 9: np.array([2, 1]), 10: np.array([2])}.get(t)
        sel = slice(None) if rows is None else rows
        x = rng.normal(0, 1, (4, c.feature_dim)).astype(np.float32)[sel]
        want = ref.step(x, style[sel], content[sel], target[sel], rows)
        for b in (grouped, every):
            rot, vel = b.step(x, style[sel], content[sel], target[sel], rows)
            assert np.abs(rot - want[0]).max() <= 1e-5 and np.abs(vel - want[1]).max() <= 1e-4, (t, b.every_branch)
    assert {styles for styles, _ in grouped.graphs} == {("elderly",), ("elderly", "youthful"), ("youthful",), ()} and {
        s for s, _ in every.graphs
    } == {None}
    assert np.abs(grouped.h - every.h).max() <= 1e-5 and np.abs(grouped.c - every.c).max() <= 1e-5


def test_onnx_profile_bench_accounts_for_every_node(model, tmp_path):
    """benchmarks/onnx_profile.py: per op type, the node counts are the graph's own and the
    shares add up to the whole kernel time."""
    import json
    import subprocess
    import sys

    out = tmp_path / "profile.json"
    done = subprocess.run(
        [sys.executable, "benchmarks/onnx_profile.py", "--steps", "5", "--streams", "1", "3", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert set(report) == {f"{form}, {n} streams" for form in (*FORMS, "lstm one style") for n in (1, 3)}
    for key, r in report.items():
        form = key.split(",")[0]
        graph = step_graph(
            model,
            form.split()[0],
            (model.config.styles[model.config.branch_styles[0]],) if "one style" in form else None,
        )
        counts = {}
        for node in graph.graph.node:
            counts[node.op_type] = counts.get(node.op_type, 0) + 1
        assert abs(sum(v["share"] for v in r["per_op"].values()) - 1.0) < 0.01 and r["step_p50_us"] > 0
        if key.startswith("lstm"):  # onnxruntime fuses some plain ops (Gemm + Relu), never the LSTM op
            assert (
                r["per_op"]["LSTM"]["nodes"]
                == counts["LSTM"]
                == (
                    max(model.config.neutral_layers, model.config.style_layers)
                    if "one style" in form
                    else len(state_layers(model))
                )
            )


def test_the_products_alone_are_the_numba_steps_own_and_count_its_flops(model):
    """``bench.products_alone``, the ceiling under the step's fraction of peak: the products of
    ``step_products`` are those the step makes (2 x their multiply-adds = the FLOPs per frame the
    bench counts), each ``x @ W`` of the step's own weights (the first, the encoder's first layer,
    checked against numpy)."""
    from styleerd.eval.bench import flops_per_frame, products_alone, step_products
    from styleerd.runtime.compiled import products

    P, calls = step_products(model)
    assert 2 * int((calls[:, 1] * calls[:, 2]).sum()) == flops_per_frame(model)
    # the first call is the encoder's first layer: on the buffer's inputs, x @ W (rows in three blocks)
    N, (w, n_in, n_out) = 2 * 32 + 5, calls[0]
    buffer = np.random.default_rng(0).normal(0, 1, 2 * N * int(calls[:, 1:].max())).astype(np.float32)
    x = buffer[: N * n_in].reshape(N, n_in).copy()
    products(P, calls[:1], N, buffer, 32)
    half = len(buffer) // 2
    assert n_in == model.config.feature_dim + len(model.config.input_styles) + len(model.config.contents)
    assert (
        np.abs(
            buffer[half : half + N * n_out].reshape(N, n_out) - x @ P[w : w + n_in * n_out].reshape(n_in, n_out)
        ).max()
        < 1e-4
    )
    assert products_alone(model, n_streams=64, seconds=0.01) > 0


def test_the_kernel_ab_bench_times_this_checkouts_step_against_another_commits():
    """benchmarks/step_kernel_ab.py compiles another commit's step kernel beside this one's and
    times both on the same arguments (here this commit against itself)."""
    import subprocess
    import sys
    from pathlib import Path

    done = subprocess.run(
        [sys.executable, "benchmarks/step_kernel_ab.py", "--before", "HEAD", "--rounds", "2", "--steps", "5"],
        cwd=Path(__file__).parents[1],
        capture_output=True,
        text=True,
        timeout=600,
        check=True,
    )
    lines = done.stdout.splitlines()
    assert [line.split(":")[0] for line in lines] == ["before (HEAD)", "now"]
    assert all(float(line.split("median ")[1].split(" us")[0]) > 0 for line in lines)


def test_the_labeller_steps_benchmark_prints_both_steps():
    """benchmarks/labeller_steps.py (where ``COMPILED_LABELLER_BELOW`` comes from) runs and prints
    a row per number of streams with both steps' times."""
    import re
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "benchmarks/labeller_steps.py", "--streams", "1", "16", "--rounds", "1"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    rows = re.findall(r"^\| (\d+) \| ([\d.]+) \| ([\d.]+) \|$", done.stdout, re.MULTILINE)
    assert [r[0] for r in rows] == ["1", "16"] and all(float(v) > 0 for r in rows for v in r[1:])
