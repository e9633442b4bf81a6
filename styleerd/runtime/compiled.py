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
from numba.typed import List

from styleerd.model.stored import GeneratorWeights
from styleerd.runtime.numpy_step import NumpyBackend, _numpy_step

COMPILED_UP_TO = 32  # streams per step (measured, 1 thread: 32 streams 178 us compiled, 187 us numpy + compiled cell; 48: 258 vs 247)


@nb.njit(cache=True)
def _dense(x, w, b, relu):
    y = x @ w
    for n in range(y.shape[0]):
        for j in range(y.shape[1]):
            v = y[n, j] + b[j]
            y[n, j] = v if (not relu or v > 0.0) else 0.0
    return y


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


@nb.njit(cache=True)
def _lstm_stack(x, w_in, w_hid, bias, first, count, h, c):
    """Layers ``first .. first + count - 1`` of the flat weight lists, one step; h, c [L, N, H]
    updated in place; returns the last layer's output (a copy)."""
    for i in range(count):
        g = x @ w_in[first + i] + np.ascontiguousarray(h[i]) @ w_hid[first + i]
        compiled_cell(g, bias[first + i], h[i], c[i])
        x = np.ascontiguousarray(h[i])
    return x.copy()


@nb.njit(cache=True)
def step_kernel(x, style, content, target, enc_w, enc_b, lstm_in, lstm_hid, lstm_b, neutral_layers, branch_layers, branch_styles,
                dec_w, dec_b, h, c, hb, cb, first, neutral_h0, neutral_c0, branch_h0, branch_c0, n_joints):  # fmt: skip
    N = x.shape[0]
    for n in range(N):  # a stream's first frame: learned initial states
        if first[n]:
            for layer in range(h.shape[0]):
                for k in range(h.shape[2]):
                    sh, sc = 0.0, 0.0
                    for label in range(content.shape[1]):
                        sh += content[n, label] * neutral_h0[label, layer, k]
                        sc += content[n, label] * neutral_c0[label, layer, k]
                    h[layer, n, k], c[layer, n, k] = sh, sc
            hb[:, :, n, :] = branch_h0
            cb[:, :, n, :] = branch_c0
            first[n] = False
    z = np.concatenate((x, style, content), axis=1)
    for i in range(len(enc_w)):
        z = _dense(z, enc_w[i], enc_b[i], i < len(enc_w) - 1)
    out = _lstm_stack(z, lstm_in, lstm_hid, lstm_b, 0, neutral_layers, h, c)
    for k in range(len(branch_styles)):
        s = branch_styles[k]
        rows = np.nonzero(target[:, s])[0]
        if len(rows) == 0:
            continue  # only the branches that are needed run (and advance)
        hk, ck = np.ascontiguousarray(hb[k][:, rows]), np.ascontiguousarray(cb[k][:, rows])
        y = _lstm_stack(np.ascontiguousarray(z[rows]), lstm_in, lstm_hid, lstm_b, neutral_layers + k * branch_layers, branch_layers, hk, ck)
        for r in range(len(rows)):
            hb[k][:, rows[r]] = hk[:, r]
            cb[k][:, rows[r]] = ck[:, r]
            out[rows[r]] += target[rows[r], s] * y[r]
    y = np.concatenate((out, target), axis=1)
    for i in range(len(dec_w)):
        y = _dense(y, dec_w[i], dec_b[i], i < len(dec_w) - 1)
    rot = y[:, : 4 * n_joints].copy().reshape(N, n_joints, 4)
    for n in range(N):
        for j in range(n_joints):
            norm = max(np.sqrt(np.sum(rot[n, j] ** 2)), 1e-8)
            rot[n, j] /= norm
    return rot, y[:, 4 * n_joints :].copy()


class CompiledBackend(NumpyBackend):
    """The ``numba`` backend: NumpyBackend's state, stepped by the compiled kernel for a few
    streams and by numpy's arithmetic for more."""

    def __init__(self, model: GeneratorWeights, n_streams: int):
        super().__init__(model, n_streams)
        w = self.w
        f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
        self.enc_w, self.enc_b = List([f32(a) for a, _ in w.encoder]), List([f32(b) for _, b in w.encoder])
        stacks = [w.neutral, *w.branches]
        self.lstm_in = List([f32(a) for layers in stacks for a, _, _ in layers])
        self.lstm_hid = List([f32(a) for layers in stacks for _, a, _ in layers])
        self.lstm_b = List([f32(b) for layers in stacks for _, _, b in layers])
        self.neutral_layers, self.branch_layers = len(w.neutral), len(w.branches[0]) if w.branches else 0
        self.branch_styles = np.array(w.branch_styles, dtype=np.int64)
        self.dec_w, self.dec_b = List([f32(a) for a, _ in w.decoder]), List([f32(b) for _, b in w.decoder])
        self.inits = [f32(a) for a in (*w.neutral_init, *w.branch_init)]

    def _arithmetic(self, x, style, content, target, h, c, hb, cb, first) -> tuple[np.ndarray, np.ndarray]:
        if len(x) > COMPILED_UP_TO:
            return _numpy_step(self.w, x, style, content, target, h, c, hb, cb, first, compiled_cell)
        return step_kernel(x, style, content, target, self.enc_w, self.enc_b, self.lstm_in, self.lstm_hid, self.lstm_b, self.neutral_layers,
                           self.branch_layers, self.branch_styles, self.dec_w, self.dec_b, h, c, hb, cb, first, *self.inits, self.w.n_joints)  # fmt: skip
