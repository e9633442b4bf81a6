"""The generator's step compiled with numba: the numpy backend's arithmetic (same layout, same
gate order) in one compiled, GIL-free call, so a frame pays for its floating-point work and not
for a hundred numpy dispatches; a step of many streams runs one shard of streams per thread in
numba's parallel loops (``compiled_step_on_shards``, ``data.parallel``).
The products are BLAS calls from inside the compiled step (``_gemm``: sgemm reading the
state's columns in place and accumulating into its output, nothing copied), or compiled loops for
a few streams. Many streams go through the whole network a block of streams at a time, so a
block's state and gates stay in cache between layers. Which path, what block and how many threads
at each batch size is measured on the machine (``runtime.calibration``).

The activations use ``tanh_fraction``, a rational approximation that vectorises (np.tanh in a
compiled loop is a scalar libm call). Compiled on first use and cached on disk
(``cache=True``), so later processes start at once.
"""

from __future__ import annotations

import ctypes

import llvmlite.binding as llvm
import numba as nb
import numpy as np
from numba.core import cgutils, types
from numba.extending import get_cython_function_address, intrinsic

from styleerd.data.parallel import kernel_threads
from styleerd.model.stored import GeneratorWeights
from styleerd.runtime.calibration import EngineSettings, engine_settings
from styleerd.runtime.numpy_step import NumpyBackend, NumpyLabeller, StepWeights, one_blas_thread

# BLAS sgemm called by name from compiled code (resolved when the code is linked, so it caches):
# unlike np.dot it takes row-strided operands (a block of a state's columns) and accumulates
# into its output (beta = 1), so the step copies nothing into a product and makes no temporaries.
llvm.add_symbol("styleerd_sgemm", get_cython_function_address("scipy.linalg.cython_blas", "sgemm"))
_sgemm = types.ExternalFunction("styleerd_sgemm", types.void(*[types.voidptr] * 13))


def _blas_threads_here_address() -> int:
    """The address of ``int openblas_set_num_threads_local(int)`` in the BLAS behind scipy's
    sgemm (OpenBLAS 0.3.26 or later: the BLAS threads of the calling thread alone, returning the
    previous number), or of libc's ``abs``, which does nothing, where that BLAS has none."""
    import scipy.linalg.cython_blas

    try:  # dlsym finds a symbol in the libraries a library was linked against too
        found = ctypes.CDLL(scipy.linalg.cython_blas.__file__).openblas_set_num_threads_local
    except (AttributeError, OSError):
        found = ctypes.CDLL(None).abs
    return ctypes.cast(found, ctypes.c_void_p).value


# Each thread of a parallel step holds BLAS to itself: a pthreads OpenBLAS asked for threads of its
# own from inside an OpenMP region warns ("Detect OpenMP Loop ... may hang") and can deadlock, and
# a limit set by the caller's thread (threadpoolctl) does not always reach numba's worker threads.
llvm.add_symbol("styleerd_blas_threads_here", _blas_threads_here_address())
_blas_threads_here = types.ExternalFunction("styleerd_blas_threads_here", types.intc(types.intc))


@intrinsic
def _by_reference(typingctx, value):
    """A pointer to a copy of ``value`` on the caller's stack: BLAS takes its sizes and scalars by
    reference, and three small heap arrays a call cost their allocations and atomic reference
    counts (``perf``, 512 streams: numba's reference counting fell from 3.9 % to 2.5 % of the step)."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(cgutils.alloca_once_value(builder, args[0]), cgutils.voidptr_t)

    return types.voidptr(value), codegen


@nb.njit(cache=True, nogil=True)
def _gemm(x, W, y, beta):
    """``y = x @ W + beta * y`` by BLAS; each operand's rows may be strided (a block of columns of
    a wider array), its elements within a row not. Row-major ``y = x W`` is column-major
    ``y^T = W^T x^T``, which is how BLAS is asked."""
    no_transpose = np.uint8(78)  # "N"
    _sgemm(
        _by_reference(no_transpose),
        _by_reference(no_transpose),
        _by_reference(np.int32(W.shape[1])),
        _by_reference(np.int32(x.shape[0])),
        _by_reference(np.int32(x.shape[1])),
        _by_reference(np.float32(1.0)),
        W.ctypes,
        _by_reference(np.int32(W.strides[0] // 4)),
        x.ctypes,
        _by_reference(np.int32(x.strides[0] // 4)),
        _by_reference(np.float32(beta)),
        y.ctypes,
        _by_reference(np.int32(y.strides[0] // 4)),
    )


# tanh as a rational function (the odd 13/6 polynomial pair Eigen uses for float32), clamped
# where tanh is 1 in float32: plain arithmetic, so loops over it vectorise (error_model="numpy":
# no zero-division checks in the way). Error <= 4e-7.
@nb.njit(cache=True, fastmath=True, error_model="numpy")
def tanh_fraction(v):
    """(p, q) with tanh(v) = p / q: the LSTM cell puts several of them over one division."""
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
    return v * p, q


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _axpy(a, x, y):
    """``y += a * x`` on rows, as a loop: ``y += a * x`` on array views makes a temporary (the
    step made seven per stream; 6 % of the step at 500 streams)."""
    for j in range(len(y)):
        y[j] += a * x[j]


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True, inline="always")
def _put(dst, at, src):
    """``dst[at : at + len(src)] = src`` on rows, as a loop: numba's slice assignment between arrays
    took 3.3x as long (a generic copy a call, its views counted by atomic reference counts)."""
    for k in range(len(src)):
        dst[at + k] = src[k]


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _dense(P, entry, x, y, accumulate, loops_up_to):
    """``y (+)= x @ W (+ b)`` for the matrix ``entry`` of the packed parameters (offset, rows,
    columns, bias offset or -1): BLAS for more than ``loops_up_to`` rows, compiled loops for fewer."""
    if x.shape[0] > loops_up_to:
        _blas(P, entry[0], entry[1], entry[2], entry[3], x, y, accumulate)
    else:
        _loops(P, entry[0], entry[1], entry[2], entry[3], x, y, accumulate)


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _blas(P, w, n_in, n_out, b, x, y, accumulate):
    """``y (+)= x @ W (+ b)``, W ``[n_in, n_out]`` at ``P[w:]``, the bias at ``P[b:]`` (none if
    b < 0), by BLAS."""
    _gemm(x, P[w : w + n_in * n_out].reshape((n_in, n_out)), y, np.float32(1.0 if accumulate else 0.0))
    if b >= 0 and not accumulate:
        for n in range(y.shape[0]):
            _axpy(np.float32(1.0), P[b : b + n_out], y[n])


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _loops(P, w, n_in, n_out, b, x, y, accumulate):
    """``_blas``'s product for a few rows: four rows of W per pass over a row of y (a quarter of
    the loads and stores of one row at a time: 1.5x)."""
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
        yn = y[n]
        for j in range(y.shape[1]):
            yn[j] = max(yn[j], np.float32(0.0))


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _stack(P, table, first_entry, layers, x, hs, cs, at, g, loops_up_to):
    """LSTM layers ``table[first_entry + 2i]`` (input weights and bias), ``+ 2i + 1`` (hidden
    weights, stored right after the input weights) on ``x [N, in]``. Layer i's state is the
    columns ``at + iH`` to ``at + (i + 1)H`` of hs, cs ``[N, S]``, updated in place; the last
    layer's h is the output. From layer 1 on, the layer's input (the h of the layer before) and
    its own h are adjacent columns: one product [x | h] @ [W_input; W_hidden], read in place."""
    N, H = x.shape[0], g.shape[1] // 4
    for i in range(layers):
        e, e_h, a = table[first_entry + 2 * i], table[first_entry + 2 * i + 1], at + i * H
        if N <= loops_up_to:
            _loops(P, e[0], e[1], e[2], -1, x if i == 0 else hs[:, a - H : a], g, False)
            _loops(P, e_h[0], e_h[1], e_h[2], -1, hs[:, a : a + H], g, True)
        elif i == 0:
            _blas(P, e[0], e[1], e[2], -1, x, g, False)
            _blas(P, e_h[0], e_h[1], e_h[2], -1, hs[:, a : a + H], g, True)
        else:
            _blas(P, e[0], 2 * H, e[2], -1, hs[:, a - H : a + H], g, False)
        _cells(g, P[e[3] : e[3] + 4 * H], hs, cs, a, H)


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _cells(g, bias, hs, cs, a, H):
    """One LSTM layer's cells on its gates ``g [N, 4H]`` (before the bias ``[4H]``): its state,
    the columns ``a`` to ``a + H`` of ``hs, cs [N, S]``, updated in place. Row by row through 1-d
    views of the whole rows: loops over a 2-d array at a column offset, or over a row of a 2-d
    view, do not vectorise (6x and 2x slower). One loop over the cells: in the step, 1.17x the
    frames/s of a tanh pass over the row's 4H gates followed by the cell (512 streams, 1 thread)."""
    for n in range(hs.shape[0]):
        gn, hn, cn = g[n], hs[n, a : a + H], cs[n, a : a + H]
        for j in range(H):
            # sigmoid(v) = (q + p) / 2q and tanh(v) = p / q for (p, q) = tanh_fraction(v / 2)
            # and (v): c' = sigmoid_f c + sigmoid_i tanh_g and h' = sigmoid_o tanh(c') each
            # over one division, not five divisions
            pi, qi = tanh_fraction(np.float32(0.5) * (gn[j] + bias[j]))
            pf, qf = tanh_fraction(np.float32(0.5) * (gn[H + j] + bias[H + j]))
            pg, qg = tanh_fraction(gn[2 * H + j] + bias[2 * H + j])
            po, qo = tanh_fraction(np.float32(0.5) * (gn[3 * H + j] + bias[3 * H + j]))
            c = ((qf + pf) * cn[j] * qi * qg + (qi + pi) * pg * qf) / (np.float32(2.0) * qf * qi * qg)
            pc, qc = tanh_fraction(c)
            cn[j], hn[j] = c, (qo + po) * pc / (np.float32(2.0) * qo * qc)


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def compiled_step(
    x,
    style,
    content,
    target,
    P,
    table,
    sizes,
    inits,
    branch_styles,
    h,
    c,
    hb,
    cb,
    first,
    rot,
    vel,
    block_rows,
    loops_up_to,
    state_rows,
):
    """The whole step in one compiled call, on the packed parameters (``pack``). Writes ``rot
    [N, J, 4]``, ``vel [N, 3J]``; updates ``first`` and the states in place, streams first and
    each stream's row flat: h, c ``[N, L0 * H]``, hb, cb ``[N, K * L1 * H]`` (branch, layer).
    ``state_rows``: each stream's row of the state, for streams stepped by index (a server's batch);
    empty: the state's rows are the streams', stepped in place. By index, a block gathers its
    streams' neutral state and the branches it runs alone, not every row of the state before the
    step and after it as numpy's indexing did.
    Steps ``block_rows`` streams at a time through the whole network; products of up to
    ``loops_up_to`` rows are compiled loops, of more BLAS calls. BLAS runs on the calling thread
    alone: threads are the caller's choice (``compiled_step_on_shards``), and OpenBLAS's own, left
    spinning after a product, took a core from the next parallel step (a step of 256 streams now
    and then 3.5x slower on 2 cores)."""
    _refuse_unless_fitting(x, style, content, target, table, sizes, h, c, hb, cb, first, rot, vel, state_rows)
    N = x.shape[0]
    blas = min(N, block_rows) > loops_up_to
    callers = _blas_threads_here(1) if blas else 1
    for s in range(0, N, block_rows):
        e = min(N, s + block_rows)
        lo, hi = (s, e) if len(state_rows) == 0 else (0, h.shape[0])  # by index: the whole state
        _step_block(
            x[s:e],
            style[s:e],
            content[s:e],
            target[s:e],
            P,
            table,
            sizes,
            inits,
            branch_styles,
            h[lo:hi],
            c[lo:hi],
            hb[lo:hi],
            cb[lo:hi],
            first[lo:hi],
            rot[s:e],
            vel[s:e],
            loops_up_to,
            state_rows[s:e],
        )
    if blas:
        _blas_threads_here(callers)


@nb.njit(cache=True, nogil=True, parallel=True)
def compiled_step_on_shards(
    shards,
    x,
    style,
    content,
    target,
    P,
    table,
    sizes,
    inits,
    branch_styles,
    h,
    c,
    hb,
    cb,
    first,
    rot,
    vel,
    block_rows,
    loops_up_to,
    state_rows,
):
    """``compiled_step`` on ``shards`` slices of the streams at once, one per thread, each
    holding BLAS to itself (``_blas_threads_here``). Inputs that do not fit are refused before the split (a shard of
    inputs that fit fits too)."""
    _refuse_unless_fitting(x, style, content, target, table, sizes, h, c, hb, cb, first, rot, vel, state_rows)
    N = x.shape[0]
    callers = _blas_threads_here(1)  # the calling thread's, given back after the loop
    for k in nb.prange(shards):
        s, e = N * k // shards, N * (k + 1) // shards
        lo, hi = (s, e) if len(state_rows) == 0 else (0, h.shape[0])
        _blas_threads_here(1)  # numba's own threads keep it: they run nothing but parallel loops
        _blas_threads_here(1)  # twice: a thread's first setting can be lost to OpenBLAS's own first use of it
        compiled_step(
            x[s:e],
            style[s:e],
            content[s:e],
            target[s:e],
            P,
            table,
            sizes,
            inits,
            branch_styles,
            h[lo:hi],
            c[lo:hi],
            hb[lo:hi],
            cb[lo:hi],
            first[lo:hi],
            rot[s:e],
            vel[s:e],
            block_rows,
            loops_up_to,
            state_rows[s:e],
        )
    _blas_threads_here(callers)


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def compiled_pair_step(
    x,
    style,
    content,
    target,
    second,
    P,
    table,
    sizes,
    inits,
    branch_styles,
    h,
    c,
    hb,
    cb,
    hb2,
    cb2,
    first,
    rot,
    vel,
    rot2,
    vel2,
    block_rows,
    loops_up_to,
    state_rows,
):
    """``compiled_step`` to ``target``, and to ``second`` with the branch states ``hb2``, ``cb2``
    into ``rot2``, ``vel2``, on one encoder and neutral stack: their state depends on the input
    alone, so two steps alike would compute them twice."""
    _refuse_unless_fitting(x, style, content, target, table, sizes, h, c, hb, cb, first, rot, vel, state_rows)
    _refuse_unless_fitting(x, style, content, second, table, sizes, h, c, hb2, cb2, first, rot2, vel2, state_rows)
    N = x.shape[0]
    blas = min(N, block_rows) > loops_up_to
    callers = _blas_threads_here(1) if blas else 1
    for s in range(0, N, block_rows):
        e = min(N, s + block_rows)
        lo, hi = (s, e) if len(state_rows) == 0 else (0, h.shape[0])  # by index: the whole state
        _pair_block(
            x[s:e],
            style[s:e],
            content[s:e],
            target[s:e],
            second[s:e],
            P,
            table,
            sizes,
            inits,
            branch_styles,
            h[lo:hi],
            c[lo:hi],
            hb[lo:hi],
            cb[lo:hi],
            hb2[lo:hi],
            cb2[lo:hi],
            first[lo:hi],
            rot[s:e],
            vel[s:e],
            rot2[s:e],
            vel2[s:e],
            loops_up_to,
            state_rows[s:e],
        )
    if blas:
        _blas_threads_here(callers)


@nb.njit(cache=True, nogil=True, parallel=True)
def compiled_pair_step_on_shards(
    shards,
    x,
    style,
    content,
    target,
    second,
    P,
    table,
    sizes,
    inits,
    branch_styles,
    h,
    c,
    hb,
    cb,
    hb2,
    cb2,
    first,
    rot,
    vel,
    rot2,
    vel2,
    block_rows,
    loops_up_to,
    state_rows,
):
    """``compiled_pair_step`` on ``shards`` slices of the streams at once, as ``compiled_step_on_shards``."""
    _refuse_unless_fitting(x, style, content, target, table, sizes, h, c, hb, cb, first, rot, vel, state_rows)
    _refuse_unless_fitting(x, style, content, second, table, sizes, h, c, hb2, cb2, first, rot2, vel2, state_rows)
    N = x.shape[0]
    callers = _blas_threads_here(1)
    for k in nb.prange(shards):
        s, e = N * k // shards, N * (k + 1) // shards
        lo, hi = (s, e) if len(state_rows) == 0 else (0, h.shape[0])
        _blas_threads_here(1)
        _blas_threads_here(1)
        compiled_pair_step(
            x[s:e],
            style[s:e],
            content[s:e],
            target[s:e],
            second[s:e],
            P,
            table,
            sizes,
            inits,
            branch_styles,
            h[lo:hi],
            c[lo:hi],
            hb[lo:hi],
            cb[lo:hi],
            hb2[lo:hi],
            cb2[lo:hi],
            first[lo:hi],
            rot[s:e],
            vel[s:e],
            rot2[s:e],
            vel2[s:e],
            block_rows,
            loops_up_to,
            state_rows[s:e],
        )
    _blas_threads_here(callers)


@nb.njit(cache=True, nogil=True)
def _refuse_unless_fitting(x, style, content, target, table, sizes, h, c, hb, cb, first, rot, vel, state_rows):
    # no bounds are checked in the step: inputs that do not fit would read or write past them
    N, R = x.shape[0], h.shape[0]
    for r in state_rows:
        if not 0 <= r < R:
            raise ValueError("a stream's row of the state is outside it")
    if not (
        style.shape[0] == N
        and content.shape[0] == N
        and target.shape[0] == N
        and (R == N if len(state_rows) == 0 else len(state_rows) == N)
        and c.shape[0] == R
        and hb.shape[0] == R
        and cb.shape[0] == R
        and first.shape[0] == R
        and rot.shape[0] == N
        and vel.shape[0] == N
        and x.shape[1] + style.shape[1] + content.shape[1] == table[0, 1]
        and target.shape[1] == sizes[6]
    ):
        raise ValueError("the step's inputs do not fit its state (rows: one per stream stepped; widths: the model's)")


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _step_block(
    x,
    style,
    content,
    target,
    P,
    table,
    sizes,
    inits,
    branch_styles,
    h,
    c,
    hb,
    cb,
    first,
    rot,
    vel,
    loops_up_to,
    state_rows,
):
    """``compiled_step`` on one block of rows that fit (``state_rows``: as there)."""
    hk, ck, fk = _rows_at(h, state_rows), _rows_at(c, state_rows), _flags_at(first, state_rows)
    _start_branches(P, inits, fk, hb, cb, state_rows)
    z, out = _trunk(x, style, content, P, table, sizes, inits, hk, ck, fk, loops_up_to)
    _head(z, out, target, P, table, sizes, branch_styles, hb, cb, rot, vel, loops_up_to, state_rows)
    _back_at(h, c, first, state_rows, hk, ck, fk)


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True)
def _pair_block(
    x,
    style,
    content,
    target,
    second,
    P,
    table,
    sizes,
    inits,
    branch_styles,
    h,
    c,
    hb,
    cb,
    hb2,
    cb2,
    first,
    rot,
    vel,
    rot2,
    vel2,
    loops_up_to,
    state_rows,
):
    """``compiled_pair_step`` on one block of rows that fit: one encoder and neutral stack, two heads."""
    hk, ck, fk = _rows_at(h, state_rows), _rows_at(c, state_rows), _flags_at(first, state_rows)
    _start_branches(P, inits, fk, hb, cb, state_rows)
    _start_branches(P, inits, fk, hb2, cb2, state_rows)
    z, out = _trunk(x, style, content, P, table, sizes, inits, hk, ck, fk, loops_up_to)
    _head(z, out.copy(), target, P, table, sizes, branch_styles, hb, cb, rot, vel, loops_up_to, state_rows)
    _head(z, out, second, P, table, sizes, branch_styles, hb2, cb2, rot2, vel2, loops_up_to, state_rows)
    _back_at(h, c, first, state_rows, hk, ck, fk)


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True, inline="always")
def _rows_at(a, state_rows):
    """The rows ``state_rows`` of ``a`` (a copy), or ``a`` itself where none are given."""
    if len(state_rows) == 0:
        return a
    out = np.empty((len(state_rows), a.shape[1]), a.dtype)
    for r in range(len(state_rows)):
        _put(out[r], 0, a[state_rows[r]])
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _flags_at(first, state_rows):
    return first if len(state_rows) == 0 else first[state_rows]


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True, inline="always")
def _back_at(h, c, first, state_rows, hk, ck, fk):
    """The neutral state and first-frame flags of the streams stepped by index written back to their rows."""
    for r in range(len(state_rows)):
        _put(h[state_rows[r]], 0, hk[r])
        _put(c[state_rows[r]], 0, ck[r])
        first[state_rows[r]] = fk[r]


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True, inline="always")
def _start_branches(P, inits, first, hb, cb, state_rows):
    """The style branches' learned initial states for the streams ``first`` (their rows of the state:
    ``state_rows``, or theirs where none are given)."""
    for n in range(len(first)):
        if first[n]:
            row = n if len(state_rows) == 0 else state_rows[n]
            for q in range(hb.shape[1]):
                hb[row, q], cb[row, q] = P[inits[2] + q], P[inits[3] + q]


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True, inline="always")
def _trunk(x, style, content, P, table, sizes, inits, h, c, first, loops_up_to):
    """The encoder and the neutral stack (a stream's first frame from the neutral stack's learned
    initial state by content, its flag cleared): -> (the encoder's output, the stack's)."""
    n_enc, L0 = sizes[0], sizes[1]
    N, H = x.shape[0], h.shape[1] // L0
    nC = content.shape[1]
    for n in range(N):
        if first[n]:
            for q in range(L0 * H):
                sh, sc = np.float32(0.0), np.float32(0.0)
                for label in range(nC):
                    sh += content[n, label] * P[inits[0] + label * L0 * H + q]
                    sc += content[n, label] * P[inits[1] + label * L0 * H + q]
                h[n, q], c[n, q] = sh, sc
            first[n] = False
    D, nS = x.shape[1], style.shape[1]
    z = np.empty((N, D + nS + nC), np.float32)
    for n in range(N):
        _put(z[n], 0, x[n])
        _put(z[n], D, style[n])
        _put(z[n], D + nS, content[n])
    for i in range(n_enc):
        y = np.empty((N, table[i, 2]), np.float32)
        _dense(P, table[i], z, y, False, loops_up_to)
        if i < n_enc - 1:
            _relu(y)
        z = y
    g = np.empty((N, 4 * H), np.float32)
    _stack(P, table, n_enc, L0, z, h, c, 0, g, loops_up_to)
    out = np.empty((N, H), np.float32)
    for n in range(N):
        _put(out[n], 0, h[n, (L0 - 1) * H :])
    return z, out


@nb.njit(cache=True, fastmath=True, error_model="numpy", nogil=True, inline="always")
def _head(z, out, target, P, table, sizes, branch_styles, hb, cb, rot, vel, loops_up_to, state_rows):
    """The style branches ``target`` weights added to the neutral stack's output ``out`` (in place),
    then the decoder into ``rot``, ``vel``. A branch's state is gathered from the streams' rows of
    ``hb``, ``cb`` (``state_rows``, or theirs) unless every stream runs it in its own row."""
    n_enc, L0, L1, n_dec, J = sizes[0], sizes[1], sizes[2], sizes[3], sizes[4]
    N, H, K = z.shape[0], out.shape[1], len(branch_styles)
    g = np.empty((N, 4 * H), np.float32)
    for b in range(K):  # only the branches a stream weights run (and advance)
        s, first_entry, at = branch_styles[b], n_enc + 2 * L0 + 2 * L1 * b, b * L1 * H
        rows = np.nonzero(target[:, s])[0]
        if len(rows) == 0:
            continue
        if len(rows) == N and len(state_rows) == 0:  # every stream, in its own row: in place, no gather
            _stack(P, table, first_entry, L1, z, hb, cb, at, g, loops_up_to)
            for n in range(N):
                _axpy(target[n, s], hb[n, at + (L1 - 1) * H : at + L1 * H], out[n])
            continue
        hk, ck = np.empty((len(rows), L1 * H), np.float32), np.empty((len(rows), L1 * H), np.float32)
        held = rows if len(state_rows) == 0 else state_rows[rows]
        for r in range(len(rows)):
            _put(hk[r], 0, hb[held[r], at : at + L1 * H])
            _put(ck[r], 0, cb[held[r], at : at + L1 * H])
        _stack(P, table, first_entry, L1, z if len(rows) == N else z[rows], hk, ck, 0, g[: len(rows)], loops_up_to)
        for r in range(len(rows)):
            _put(hb[held[r]], at, hk[r])
            _put(cb[held[r]], at, ck[r])
            _axpy(target[rows[r], s], hk[r, (L1 - 1) * H :], out[rows[r]])
    nI = sizes[5]
    y = np.empty((N, H + nI), np.float32)
    for n in range(N):
        _put(y[n], 0, out[n])
        _put(y[n], H, target[n, :nI])
    first_dec = n_enc + 2 * L0 + 2 * L1 * K
    for i in range(n_dec):
        e = table[first_dec + i]
        o = np.empty((N, e[2]), np.float32)
        _dense(P, e, y, o, False, loops_up_to)
        if i == 0 and nI < target.shape[1]:  # the added styles' target rows, apart (see StyleERD.decode)
            _dense(P, table[first_dec + n_dec], target[:, nI:], o, True, loops_up_to)
        if i < n_dec - 1:
            _relu(o)
        y = o
    # unit quaternions: every squared norm of the block, then their inverse square roots in one
    # vectorised pass (a sqrt and a division per joint, one joint at a time, do not vectorise)
    flat, inv = rot.reshape((N, 4 * J)), np.empty(N * J, np.float32)
    for n in range(N):
        yn = y[n]
        for j in range(J):
            inv[n * J + j] = yn[4 * j] ** 2 + yn[4 * j + 1] ** 2 + yn[4 * j + 2] ** 2 + yn[4 * j + 3] ** 2
    for k in range(N * J):
        inv[k] = np.float32(1.0) / max(np.sqrt(inv[k]), np.float32(1e-8))
    for n in range(N):
        yn, rn = y[n], flat[n]
        for j in range(J):
            scale = inv[n * J + j]
            rn[4 * j], rn[4 * j + 1], rn[4 * j + 2], rn[4 * j + 3] = (
                yn[4 * j] * scale,
                yn[4 * j + 1] * scale,
                yn[4 * j + 2] * scale,
                yn[4 * j + 3] * scale,
            )
        _put(vel[n], 0, yn[4 * J :])


@nb.njit(cache=True, nogil=True)
def products(P, calls, N, buffer, block_rows):
    """The products ``calls`` (rows: offset in P, inputs, outputs) on ``N`` rows of ``buffer``
    (its first half the inputs, its second the outputs), ``block_rows`` rows at a time as the
    step makes them, nothing else: what the step's products alone cost (``eval.bench.products_alone``)."""
    half = len(buffer) // 2
    for s in range(0, N, block_rows):
        e = min(N, s + block_rows)
        for k in range(len(calls)):
            w, n_in, n_out = calls[k, 0], calls[k, 1], calls[k, 2]
            x, y = buffer[: N * n_in].reshape((N, n_in)), buffer[half : half + N * n_out].reshape((N, n_out))
            _gemm(x[s:e], P[w : w + n_in * n_out].reshape((n_in, n_out)), y[s:e], np.float32(0.0))


def pack(w: StepWeights) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The step's parameters as one float32 array and a table of its matrices (offset, rows,
    columns, bias offset or -1): the encoder's layers, each LSTM layer's input (with the
    summed biases) and hidden weights, neutral branch first, then the decoder's layers; the
    sizes (encoder layers, L0, L1, decoder layers, J, input styles, target styles) and the initial states'
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
        for (
            w_cat,
            b,
        ) in layers:  # the hidden weights right after the input weights: [W_input; W_hidden] is one matrix too
            inputs, at_w, at_b = len(w_cat) - w.hidden, put(w_cat), put(b)
            table += [
                (at_w, inputs, w_cat.shape[1], at_b),
                (at_w + inputs * w_cat.shape[1], w.hidden, w_cat.shape[1], -1),
            ]
    for W, b in w.decoder:
        matrix(W, b)
    if w.decoder_added is not None:
        matrix(w.decoder_added, None)
    inits = np.array([put(a) for a in (*w.neutral_init, *w.branch_init)], np.int64)
    n_targets = w.input_styles + (0 if w.decoder_added is None else len(w.decoder_added))
    sizes = np.array(
        [
            len(w.encoder),
            len(w.neutral),
            len(w.branches[0]) if w.branches else 0,
            len(w.decoder),
            w.n_joints,
            w.input_styles,
            n_targets,
        ],
        np.int64,
    )
    return np.concatenate(parts), np.array(table, np.int64), sizes, inits


IN_PLACE = np.empty(0, np.int64)  # no ``state_rows``: the state's rows are the streams'


class CompiledBackend(NumpyBackend):
    """The ``numba`` backend: NumpyBackend's state, stepped by the compiled step; a step of
    many streams on up to ``threads`` threads (``data.parallel``), each batch size by the path
    ``settings`` chooses (by default, the one measured fastest on this machine)."""

    def __init__(
        self,
        model: GeneratorWeights,
        n_streams: int,
        threads: int = 1,
        settings: EngineSettings | None = None,
        paired: bool = False,
    ):
        super().__init__(model, n_streams, paired)
        self.threads = threads
        self.use(settings or engine_settings(model))
        self.params, self.table, self.sizes, self.inits = pack(self.w)
        self.branch_styles = np.array(self.w.branch_styles, dtype=np.int64)
        # the whole state, flat, once
        self._whole = (
            self.h,
            *(None if a is None else _rows(a) for a in (self.h, self.c, self.hb, self.cb, self.hb2, self.cb2)),
        )

    def use(self, settings: EngineSettings) -> None:
        """Step by ``settings`` from now on (the state is kept)."""
        self.settings = settings
        self._plans: dict[int, tuple[int, int, int]] = {}  # by streams stepped: block rows, loops up to, threads

    rows_in_place = True  # streams stepped by index: the state's rows given to the step (``state_rows``)

    def _arithmetic(
        self, x, style, content, target, second, h, c, hb, cb, hb2, cb2, first, state_rows=IN_PLACE
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        N = len(x)
        plan = self._plans.get(N)
        if plan is None:  # a dict lookup a step, not the settings' search (1-2 us at batch 1)
            choice = self.settings.choice(N, self.threads)
            plan = self._plans[N] = (choice.block_rows, 2**31 if choice.loops else 0, min(self.threads, choice.threads))
        block_rows, loops_up_to, threads = plan
        J = self.w.n_joints
        rot, vel = np.empty((N, J, 4), np.float32), np.empty((N, 3 * J), np.float32)
        whole = h is self._whole[0]
        flat = self._whole[1:5] if whole else tuple(_rows(a) for a in (h, c, hb, cb))
        head = (x, style, content, target)
        if second is not None:
            rot2, vel2 = np.empty_like(rot), np.empty_like(vel)
            head += (second,)
            flat += self._whole[5:] if whole else tuple(_rows(a) for a in (hb2, cb2))
        params = (self.params, self.table, self.sizes, self.inits, self.branch_styles)
        outputs = (rot, vel) if second is None else (rot, vel, rot2, vel2)
        args = (*head, *params, *flat, first, *outputs, block_rows, loops_up_to, state_rows)
        shards = kernel_threads(threads, N, from_streams=1) if threads > 1 else 1
        one, many = (
            (compiled_step, compiled_step_on_shards)
            if second is None
            else (compiled_pair_step, compiled_pair_step_on_shards)
        )
        if shards == 1:
            one(*args)
        else:
            with one_blas_thread():
                many(shards, *args)
        return rot, vel, None if second is None else rot2


def _rows(state: np.ndarray) -> np.ndarray:
    """A state ``[N, ...]`` as ``[N, S]``, the same memory (a shard's rows are one block)."""
    if not state.flags.c_contiguous:
        raise ValueError("the numba backend steps a state whose streams are contiguous rows")
    return state.reshape(len(state), -1)


# Below this many streams the labeller steps as one compiled call; from it, numpy's (its elementwise
# gates are vectorised, the compiled loop's are not): 1 stream 5.5 us against 22.5, 8 streams 32 against 36,
# 16 streams 50 against 43 (an AMD EPYC, python benchmarks/labeller_steps.py).
COMPILED_LABELLER_BELOW = 12


class CompiledLabeller(NumpyLabeller):
    """The labeller's step (``NumpyLabeller``) as one compiled call for a few streams, where numpy's
    dozen calls a frame cost more than the arithmetic."""

    def step(self, x: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return super().step(x, rows) if len(x) >= COMPILED_LABELLER_BELOW else self._compiled(x, rows)

    def _compiled(self, x: np.ndarray, rows: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h = self.h if rows is None else self.h[rows]
        (w_style, b_style), (w_content, b_content) = self.heads
        return _labeller_step(
            np.ascontiguousarray(x, np.float32),
            np.ascontiguousarray(h),
            *(self.w_in, self.b_in, self.w_ih, self.b_ih, self.w_hh, self.b_hh),
            *(w_style, b_style, w_content, b_content),
        )


@nb.njit(cache=True, nogil=True)
def _softmax_rows(z, b):
    """Softmax of each row of ``z + b``, in place."""
    for n in range(z.shape[0]):
        top = -np.inf
        for k in range(z.shape[1]):
            z[n, k] += b[k]
            top = max(top, z[n, k])
        total = 0.0
        for k in range(z.shape[1]):
            z[n, k] = np.exp(z[n, k] - top)
            total += z[n, k]
        for k in range(z.shape[1]):
            z[n, k] /= total
    return z


@nb.njit(cache=True, nogil=True)
def _labeller_step(x, h, w_in, b_in, w_ih, b_ih, w_hh, b_hh, w_style, b_style, w_content, b_content):
    """``NumpyLabeller.step``: the input layer (ReLU), a GRU cell (torch's gate order r, z, n), the
    style and content heads' probabilities; -> (style, content, new state)."""
    a = np.dot(x, w_in)
    N, H = a.shape
    for n in range(N):
        for k in range(H):
            a[n, k] = max(a[n, k] + b_in[k], 0.0)
    gi, gh = np.dot(a, w_ih), np.dot(h, w_hh)
    out = np.empty((N, H), np.float32)
    for n in range(N):
        for k in range(H):
            r = 0.5 * np.tanh(0.5 * (gi[n, k] + b_ih[k] + gh[n, k] + b_hh[k])) + 0.5
            z = 0.5 * np.tanh(0.5 * (gi[n, H + k] + b_ih[H + k] + gh[n, H + k] + b_hh[H + k])) + 0.5
            c = np.tanh(gi[n, 2 * H + k] + b_ih[2 * H + k] + r * (gh[n, 2 * H + k] + b_hh[2 * H + k]))
            out[n, k] = (1.0 - z) * c + z * h[n, k]
    return _softmax_rows(np.dot(out, w_style), b_style), _softmax_rows(np.dot(out, w_content), b_content), out
