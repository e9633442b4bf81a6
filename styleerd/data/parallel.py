"""Threads inside the compiled kernels (numba's parallel loops): a step of many streams is
split into one shard of streams per thread, each shard running the serial kernel.

Only numba's thread-safe layers (OpenMP, TBB) are used: a server steps streams from several
threads at once, and numba's fallback layer (workqueue) aborts the process on a concurrent
launch. OpenMP's threads spin a moment before they sleep, so a step's few parallel loops start
in microseconds; the handoffs of a Python thread pool (futex wake-ups, the GIL) cost 30-100 us
each on a virtual machine."""

from __future__ import annotations

import importlib
from functools import cache

import numba as nb

# streams per step from which the kernels split over threads: below it a shard is less than a
# block of the step (docs/benchmarks.md, "Tuned constants")
PARALLEL_FROM = 32


@cache
def threadsafe_layer() -> bool:
    """Whether one of numba's thread-safe layers (TBB, OpenMP) loads here; it is then the one used."""
    for layer in ("tbbpool", "omppool"):
        try:
            importlib.import_module(f"numba.np.ufunc.{layer}")
        except Exception:  # noqa: BLE001, S112  a missing or unloadable library, whatever numba raises: not this layer
            continue
        if nb.config.THREADING_LAYER == "default":
            nb.config.THREADING_LAYER = "threadsafe"
        return nb.config.THREADING_LAYER in ("threadsafe", "safe", "tbb", "omp")
    return False


def kernel_threads(threads: int, n_streams: int, from_streams: int | None = None) -> int:
    """The threads a compiled kernel runs ``n_streams`` streams on when asked for ``threads``,
    one shard of streams each: at most numba's threads, and one for steps of fewer than
    ``from_streams`` streams (default ``PARALLEL_FROM``, read at each call) or where no thread-safe
    layer loads. Sets numba's threads for this thread's next parallel loops to it (set inside the
    kernels, the setting would keep them from numba's disk cache)."""
    least = PARALLEL_FROM if from_streams is None else from_streams
    if threads <= 1 or n_streams < least or not threadsafe_layer():
        return 1
    shards = min(threads, nb.config.NUMBA_NUM_THREADS)
    nb.set_num_threads(shards)
    return shards


def on_kernel_threads(threads: int, n_streams: int, serial, on_shards, *args) -> None:
    """``on_shards(shards, *args)`` where ``kernel_threads`` splits ``n_streams`` streams over
    threads, else ``serial(*args)``: a compiled kernel and its parallel twin."""
    shards = kernel_threads(threads, n_streams)
    if shards > 1:
        on_shards(shards, *args)
    else:
        serial(*args)
