"""The generator's step compiled with numba: the numpy backend's arithmetic (same layout, same
gate order) in one compiled call, so a frame pays for its floating-point work and not for a
hundred numpy dispatches. That wins for a few streams; from ``COMPILED_UP_TO`` streams on, the
step takes numpy's path (BLAS matmuls over all streams) on the same state, with the LSTM cell
update compiled.

Both use ``fast_tanh``, a rational approximation that vectorises (np.tanh in a compiled loop
is a scalar libm call). Compiled on first use and cached on disk (``cache=True``), so later
processes start at once.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from styleerd.model.stored import GeneratorWeights
from styleerd.runtime.numpy_step import NumpyBackend, StepWeights, _numpy_step

COMPILED_UP_TO = 32  # streams per step (measured, 1 thread, side by side: 8 streams 88 us compiled, 175 us numpy + compiled cell; 32: 472 vs 514)


# tanh as a rational function (the odd 13/6 polynomial pair Eigen uses for float32), clamped
# where tanh is 1 in float32: plain arithmetic, so loops over it vectorise (error_model="numpy":
# no zero-division checks in the way). Error <= 4e-7.
@nb.njit(cache=True, fastmath=True, error_model="numpy")
def fast_tanh(v):
    v = min(max(v, np.float32(-7.90531110763549805)), np.float32(7.90531110763549805))
    v2 = v * v
    p = np.float32(-2.76076847742355e-16) * v2 + np.float32(2.00018790482477e-13)
    p = p * v2 + np.float32(-8.60467152213735e-11)
    p = p * v2 + np.float32(5.12229709037114e-08)
    p = p * v2 + np.float32(1.48572235717979e-05)
    p = p * v2 + np.float32(6.37261928875436e-04)
    p = p * v2 + np.float32(4.89352455891786e-03)
    q = np.float32(1.19825839466702e-06) * v2 + np.float32(1.18534705686654e-04)
    q = q * v2 + np.float32(2.26843463243900e-03)
    q = q * v2 + np.float32(4.89352518554385e-03)
    return v * p / q


@nb.njit(cache=True, fastmath=True, error_model="numpy")
def _sigmoid(v):
    return np.float32(0.5) * fast_tanh(np.float32(0.5) * v) + np.float32(0.5)


# Serial and GIL-free: threads come from StreamStylizer's shards of streams (runtime.stylizer.SHARD_FROM).
@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def compiled_cell(g, b, h, c):
    """NumpyBackend's LSTM cell update (``numpy_step._numpy_cell``), one pass per stream."""
    H = h.shape[1]
    for n in range(g.shape[0]):
        for j in range(H):
            gi = _sigmoid(g[n, j] + b[j])
            gf = _sigmoid(g[n, H + j] + b[H + j])
            gg = fast_tanh(g[n, 2 * H + j] + b[2 * H + j])
            go = _sigmoid(g[n, 3 * H + j] + b[3 * H + j])
            c[n, j] = gf * c[n, j] + gi * gg
            h[n, j] = go * fast_tanh(c[n, j])


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _dense(P, entry, x, y, accumulate):
    """``y (+)= x @ W (+ b)`` for the matrix ``entry`` of the packed parameters; four rows of W
    per pass over a row of y (a quarter of the loads and stores of one row at a time: 1.5x)."""
    w, n_in, n_out, b = entry[0], entry[1], entry[2], entry[3]
    if not accumulate:
        for n in range(x.shape[0]):
            for j in range(n_out):
                y[n, j] = P[b + j] if b >= 0 else np.float32(0.0)
    k4 = n_in - n_in % 4
    for n in range(x.shape[0]):
        yn = y[n]
        for k in range(0, k4, 4):
            x0, x1, x2, x3 = x[n, k], x[n, k + 1], x[n, k + 2], x[n, k + 3]
            r0, r1 = P[w + k * n_out : w + (k + 1) * n_out], P[w + (k + 1) * n_out : w + (k + 2) * n_out]
            r2, r3 = P[w + (k + 2) * n_out : w + (k + 3) * n_out], P[w + (k + 3) * n_out : w + (k + 4) * n_out]
            for j in range(n_out):
                yn[j] += x0 * r0[j] + x1 * r1[j] + x2 * r2[j] + x3 * r3[j]
        for k in range(k4, n_in):
            xk, r0 = x[n, k], P[w + k * n_out : w + (k + 1) * n_out]
            for j in range(n_out):
                yn[j] += xk * r0[j]


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _relu(y):
    for n in range(y.shape[0]):
        for j in range(y.shape[1]):
            y[n, j] = max(y[n, j], np.float32(0.0))


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _stack(P, table, first_entry, layers, x, h, c, g):
    """LSTM layers ``table[first_entry + 2i]`` (input weights and bias), ``+ 2i + 1`` (hidden
    weights) on ``x [N, in]``: h, c [L, N, H] updated in place; the last h is the output."""
    for i in range(layers):
        _dense(P, table[first_entry + 2 * i], x, g, False)
        _dense(P, table[first_entry + 2 * i + 1], h[i], g, True)
        H = h.shape[2]
        for n in range(x.shape[0]):
            for j in range(H):
                gi = _sigmoid(g[n, j])
                gf = _sigmoid(g[n, H + j])
                gg = fast_tanh(g[n, 2 * H + j])
                go = _sigmoid(g[n, 3 * H + j])
                c[i, n, j] = gf * c[i, n, j] + gi * gg
                h[i, n, j] = go * fast_tanh(c[i, n, j])
        x = h[i]


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def small_step(x, style, content, target, P, table, sizes, inits, branch_styles, h, c, hb, cb, first, rot, vel):
    """The whole step for a few streams in one compiled call, on the packed parameters
    (``pack``): no allocation per layer, no BLAS call per product. Writes ``rot [N, J, 4]``,
    ``vel [N, 3J]``; updates h, c [L0, N, H], hb, cb [K, L1, N, H] and ``first`` in place."""
    n_enc, L0, L1, n_dec, J = sizes[0], sizes[1], sizes[2], sizes[3], sizes[4]
    N, H, K = x.shape[0], h.shape[2], hb.shape[0]
    nC = content.shape[1]
    for n in range(N):  # a stream's first frame: the learned initial states (the neutral one by content)
        if first[n]:
            for layer in range(L0):
                for k in range(H):
                    sh, sc = np.float32(0.0), np.float32(0.0)
                    for label in range(nC):
                        sh += content[n, label] * P[inits[0] + (label * L0 + layer) * H + k]
                        sc += content[n, label] * P[inits[1] + (label * L0 + layer) * H + k]
                    h[layer, n, k], c[layer, n, k] = sh, sc
            for b in range(K):
                for layer in range(L1):
                    for k in range(H):
                        hb[b, layer, n, k] = P[inits[2] + (b * L1 + layer) * H + k]
                        cb[b, layer, n, k] = P[inits[3] + (b * L1 + layer) * H + k]
            first[n] = False
    z = np.empty((N, x.shape[1] + style.shape[1] + nC), np.float32)
    z[:, : x.shape[1]] = x
    z[:, x.shape[1] : x.shape[1] + style.shape[1]] = style
    z[:, x.shape[1] + style.shape[1] :] = content
    for i in range(n_enc):
        y = np.empty((N, table[i, 2]), np.float32)
        _dense(P, table[i], z, y, False)
        if i < n_enc - 1:
            _relu(y)
        z = y
    g = np.empty((N, 4 * H), np.float32)
    _stack(P, table, n_enc, L0, z, h, c, g)
    out = h[L0 - 1].copy()
    for b in range(K):  # only the branches a stream weights run (and advance)
        s = branch_styles[b]
        rows = np.nonzero(target[:, s])[0]
        if len(rows) == 0:
            continue
        hk, ck = hb[b][:, rows].copy(), cb[b][:, rows].copy()
        _stack(P, table, n_enc + 2 * L0 + 2 * L1 * b, L1, z[rows], hk, ck, g[: len(rows)])
        for r in range(len(rows)):
            hb[b, :, rows[r]] = hk[:, r]
            cb[b, :, rows[r]] = ck[:, r]
            out[rows[r]] += target[rows[r], s] * hk[L1 - 1, r]
    nI = sizes[5]
    y = np.empty((N, H + nI), np.float32)
    y[:, :H] = out
    y[:, H:] = target[:, :nI]
    first_dec = n_enc + 2 * L0 + 2 * L1 * K
    for i in range(n_dec):
        e = table[first_dec + i]
        o = np.empty((N, e[2]), np.float32)
        _dense(P, e, y, o, False)
        if i == 0 and nI < target.shape[1]:  # the added styles' target rows, apart (see StyleERD.decode)
            _dense(P, table[first_dec + n_dec], np.ascontiguousarray(target[:, nI:]), o, True)
        if i < n_dec - 1:
            _relu(o)
        y = o
    for n in range(N):
        for j in range(J):
            norm = np.float32(0.0)
            for a in range(4):
                norm += y[n, 4 * j + a] * y[n, 4 * j + a]
            norm = max(np.sqrt(norm), np.float32(1e-8))
            for a in range(4):
                rot[n, j, a] = y[n, 4 * j + a] / norm
        for j in range(3 * J):
            vel[n, j] = y[n, 4 * J + j]


def pack(w: StepWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The step's parameters as one float32 array and a table of its matrices (offset, rows,
    columns, bias offset or -1): the encoder's layers, each LSTM layer's input (with the
    summed biases) and hidden weights, neutral branch first, then the decoder's layers; the
    sizes (encoder layers, L0, L1, decoder layers, J, input styles) and the initial states'
    offsets. The added styles' decoder rows, if any, are the last matrix."""
    parts, table, at = [], [], 0

    def put(a: np.ndarray) -> int:
        nonlocal at
        parts.append(np.ascontiguousarray(a, np.float32).ravel())
        at += parts[-1].size
        return at - parts[-1].size

    def matrix(W: np.ndarray, b: np.ndarray | None) -> None:
        table.append((put(W), W.shape[0], W.shape[1], -1 if b is None else put(b)))

    for W, b in w.encoder:
        matrix(W, b)
    for layers in [w.neutral, *w.branches]:
        for w_cat, b in layers:
            inputs = len(w_cat) - w.hidden
            matrix(w_cat[:inputs], b)
            matrix(w_cat[inputs:], None)
    for W, b in w.decoder:
        matrix(W, b)
    if w.decoder_added is not None:
        matrix(w.decoder_added, None)
    inits = np.array([put(a) for a in (*w.neutral_init, *w.branch_init)], np.int64)
    sizes = np.array([len(w.encoder), len(w.neutral), len(w.branches[0]) if w.branches else 0, len(w.decoder), w.n_joints, w.input_styles], np.int64)
    return np.concatenate(parts), np.array(table, np.int64), sizes, inits


class CompiledBackend(NumpyBackend):
    """The ``numba`` backend: NumpyBackend's state, stepped by the compiled kernel for a few
    streams and by numpy's arithmetic for more."""

    def __init__(self, model: GeneratorWeights, n_streams: int):
        super().__init__(model, n_streams)
        self.params, self.table, self.sizes, self.inits = pack(self.w)
        self.branch_styles = np.array(self.w.branch_styles, dtype=np.int64)

    def _arithmetic(self, x, style, content, target, h, c, hb, cb, first) -> tuple[np.ndarray, np.ndarray]:
        if len(x) > COMPILED_UP_TO:
            return _numpy_step(self.w, x, style, content, target, h, c, hb, cb, first, compiled_cell)
        rot, vel = np.empty((len(x), self.w.n_joints, 4), np.float32), np.empty((len(x), 3 * self.w.n_joints), np.float32)
        small_step(x, style, content, target, self.params, self.table, self.sizes, self.inits, self.branch_styles, h, c, hb, cb, first, rot, vel)
        return rot, vel
