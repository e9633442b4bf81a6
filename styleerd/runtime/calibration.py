"""The numba step's settings chosen on this machine: at first use, a short calibration times the
step's possible paths at each batch size (compiled loops or BLAS products, the streams taken through
the whole network at a time, one thread or numba's threads) and keeps the fastest; the choices are
cached by CPU, libraries and the model's shape, so later processes start at once. A calibration
that finds steps on threads far slower than on one (another process held the other core) is kept
for its process only, and a cached one that shows it is made again (``contention``).

Constants tuned on one CPU do not carry to another: blocks of 32 streams were 1.15x the whole
shard on the Intel machine they were tuned on and 0.58-0.72x the best block on an AMD EPYC, where
each sgemm call costs about as much as its arithmetic (docs/benchmarks.md, "The engine on other
CPUs"). ``STYLEERD_CALIBRATE=0`` keeps the fixed settings.
"""

from __future__ import annotations

import bisect
import hashlib
import json
import os
import platform
import threading
import time
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path

import numba as nb
import numpy as np

from styleerd.atomic import atomic_write
from styleerd.data.datasets import cache_dir
from styleerd.data.parallel import PARALLEL_FROM, threadsafe_layer
from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights

STREAMS = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024)  # the batch sizes timed
BLOCKS = (8, 16, 32, 64, 128, 256, 512)  # block sizes tried below a shard's rows (the whole shard too)
LOOPS_UP_TO = 8  # loops are tried for shards of up to this many streams (BLAS wins beyond: docs/benchmarks.md)
ROUNDS = 5  # candidates timed in alternating rounds
MEASURE_S = 0.002  # least time a candidate steps in a round (at least 2 steps), each step timed
# Each candidate's figure is the median of its steps' times: on a virtual machine a step on two
# threads now and then waits ~8 ms for a descheduled vCPU, which a window's mean takes in whole
# (docs/benchmarks.md, "The engine on other CPUs").
FORMAT = 1  # the cache file's layout; a new one recalibrates
# A step on two threads this many times one thread's, and at least CONTENDED_S more, was not the
# machine's: another process held the other core (every two-thread step of a calibration made beside
# a training run took ~8 ms, so it chose one thread for every batch, 3x slower at 1,000 streams).
CONTENDED, CONTENDED_S = 4.0, 0.001


@dataclass(frozen=True)
class StepChoice:
    """One way to run a step: ``block_rows`` streams through the whole network at a time,
    products as compiled loops (``loops``) or BLAS, on ``threads`` threads (one shard of streams
    each; at most what the caller asked for)."""

    block_rows: int
    loops: bool
    threads: int


@dataclass(frozen=True)
class EngineSettings:
    """A choice per batch size: ``one_thread[i]`` for a caller that asked for one thread,
    ``many_threads[i]`` for one that asked for more, from ``streams[i]`` streams on."""

    streams: tuple[int, ...]
    one_thread: tuple[StepChoice, ...]
    many_threads: tuple[StepChoice, ...]
    source: str  # where the choices came from, for a reader of `styleerd info --system`

    def choice(self, n_streams: int, threads: int) -> StepChoice:
        i = max(0, bisect.bisect_right(self.streams, n_streams) - 1)
        return (self.many_threads if threads > 1 else self.one_thread)[i]


def fixed_settings(threads: int | None = None) -> EngineSettings:
    """The settings tuned on the Intel machine of docs/benchmarks.md's "Tuned constants": loops for
    one stream, BLAS in blocks of 32 streams above it, numba's threads from ``PARALLEL_FROM`` streams."""
    threads = threads or nb.config.NUMBA_NUM_THREADS
    one = (StepChoice(32, True, 1), StepChoice(32, False, 1), StepChoice(32, False, 1))
    many = (*one[:2], StepChoice(32, False, threads))
    return EngineSettings((1, 2, PARALLEL_FROM), one, many, "fixed settings, not calibrated on this machine")


def candidates(n_streams: int, threads: int) -> list[StepChoice]:
    """The paths timed at ``n_streams`` streams with up to ``threads`` threads: per thread count,
    each block size below a shard's rows and the whole shard, by BLAS, and by loops for small shards."""
    out = []
    for t in sorted({1, threads}):
        rows = -(-n_streams // t)
        if t > 1 and rows < 4:  # a shard of a few streams does not pay for a thread's start
            continue
        for b in [b for b in BLOCKS if b < rows] + [rows]:
            out.append(StepChoice(b, False, t))
        if rows <= LOOPS_UP_TO:
            out.append(StepChoice(rows, True, t))
    return out


def _timer(model: GeneratorWeights, n_streams: int, threads: int):
    """A function timing one step of ``n_streams`` streams by a given choice (seconds, a step)."""
    from styleerd.runtime.compiled import CompiledBackend

    backend = CompiledBackend(model, n_streams, threads, fixed_settings())
    c = model.config
    one_hot = lambda k, i: np.eye(k, dtype=np.float32)[np.full(n_streams, i)]
    inputs = (  # a step to one style other than the input's, the usual case
        np.random.default_rng(0).normal(0, 1, (n_streams, c.feature_dim)).astype(np.float32),
        one_hot(len(c.input_styles), c.neutral_index),
        one_hot(len(c.contents), 0),
        one_hot(int(backend.sizes[6]), (c.neutral_index + 1) % len(c.input_styles)),
    )

    def time_steps(choice: StepChoice) -> list[float]:
        backend.use(EngineSettings((1,), (choice,), (choice,), "calibrating"))
        backend.step(*inputs)  # untimed: the first call of a path (and a thread pool's start)
        times, t_end = [], time.perf_counter() + MEASURE_S
        while len(times) < 2 or time.perf_counter() < t_end:
            t0 = time.perf_counter()
            backend.step(*inputs)
            times.append(time.perf_counter() - t0)
        return times

    return time_steps


def calibrate(model: GeneratorWeights, threads: int | None = None, progress=None) -> dict:
    """Time every candidate at every batch size (``ROUNDS`` alternating rounds, each candidate's
    median step) and choose the fastest per batch size, for one thread and for up to ``threads``
    (numba's threads; only where a thread-safe layer loads). Returns the cache file's record."""
    threads = threads or nb.config.NUMBA_NUM_THREADS
    if not threadsafe_layer():
        threads = 1
    t_start, rows, contended = time.perf_counter(), [], None
    for n in STREAMS:
        options = candidates(n, 1 if contended else threads)  # contended: the second core's timings are not its own
        time_steps = _timer(model, n, threads)
        steps: list[list[float]] = [[] for _ in options]
        for _ in range(ROUNDS):
            for k, choice in enumerate(options):
                steps[k] += time_steps(choice)
        best = [float(np.median(t)) for t in steps]
        one = min((k for k, c in enumerate(options) if c.threads == 1), key=best.__getitem__)
        many = min(range(len(options)), key=best.__getitem__)
        rows.append(
            {
                "streams": n,
                "one_thread": asdict(options[one]) | {"us_per_step": round(best[one] * 1e6, 1)},
                "many_threads": asdict(options[many]) | {"us_per_step": round(best[many] * 1e6, 1)},
                "timed": [
                    asdict(c) | {"us_per_step": round(s * 1e6, 1), "steps": len(t)}
                    for c, s, t in zip(options, best, steps, strict=True)
                ],
            }
        )
        contended = contended or contention(rows)
        if progress:
            progress(n, rows[-1])
    return {
        "format": FORMAT,
        "key": machine_key(model),
        "threads": threads,
        "seconds": round(time.perf_counter() - t_start, 2),
        "measured": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "choices": rows,
        "contended": contended,
    }


def contention(rows: list[dict]) -> dict | None:
    """The first batch size of a calibration's ``rows`` whose best step on several threads took
    ``CONTENDED`` times its best on one (and ``CONTENDED_S`` more): what another process holding the
    other core makes, not the machine's own speed; None where there is none."""
    for row in rows:
        one = row["one_thread"]["us_per_step"]
        many = [t["us_per_step"] for t in row["timed"] if t["threads"] > 1]
        if many and min(many) > CONTENDED * one and min(many) - one > CONTENDED_S * 1e6:
            return {"streams": row["streams"], "one_thread_us": one, "threads_us": min(many)}
    return None


WHOLE = 2**31  # block rows of a choice that takes a shard whole at any batch size


def settings_from(record: dict, path: Path) -> EngineSettings:
    """The settings of a calibration's record. A choice that took the whole shard where it was
    measured takes it whole at the batch sizes it stands for too: 39 streams by the choice measured
    at 32 (blocks of 32 streams) ran a block of 32 and one of 7, each sgemm call costing about as
    much as its arithmetic (docs/DEPLOY.md, "Whole shards")."""
    rows = record["choices"]

    def pick(r: dict, kind: str) -> StepChoice:
        c = r[kind]
        whole = int(c["block_rows"]) >= -(-int(r["streams"]) // int(c["threads"]))
        return StepChoice(WHOLE if whole else int(c["block_rows"]), bool(c["loops"]), int(c["threads"]))

    busy = record.get("contended")
    return EngineSettings(
        tuple(int(r["streams"]) for r in rows),
        tuple(pick(r, "one_thread") for r in rows),
        tuple(pick(r, "many_threads") for r in rows),
        f"calibrated on this machine in {record['seconds']} s ({path})"
        if not busy
        else f"calibrated in {record['seconds']} s while another process held a core (at {busy['streams']} streams "
        f"a step on threads took {busy['threads_us']} us, on one {busy['one_thread_us']} us): one thread from "
        "there on, for this process only; measured again at the next start",
    )


def machine_key(model: GeneratorWeights) -> dict:
    """What the choices depend on: the CPU, the threads, the libraries that run the step (scipy
    bundles the BLAS its sgemm comes from), the model's shape (not its values)."""
    c = model.config
    shape = {k: getattr(c, k) for k in ("n_joints", "feature_dim", "encoder", "hidden", "decoder")}
    shape |= {"layers": [c.neutral_layers, c.style_layers], "labels": [len(c.input_styles), len(c.contents)]}
    return json.loads(json.dumps(_machine() | {"model_shape": shape}))  # as it reads back from the cache


@cache
def _machine() -> dict:
    import llvmlite
    import scipy

    from styleerd.runtime.system import cpu_flags, cpu_model

    threadsafe_layer()  # numba's layer is the one a parallel step uses
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "vector_sets": cpu_flags(),
        "numba_threads": nb.config.NUMBA_NUM_THREADS,
        "numba_threading_layer": nb.config.THREADING_LAYER,
        "versions": {m.__name__: m.__version__ for m in (np, scipy, nb, llvmlite)}
        | {"python": platform.python_version()},
    }


def cache_path(key: dict) -> Path:
    """The cache file of the choices for ``key`` (``machine_key``)."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    return cache_dir() / "engine" / f"calibration-{digest}.json"


_lock = threading.Lock()
_known: dict[Path, EngineSettings] = {}  # this process's, by cache file


def engine_settings(model: GeneratorWeights, again: bool = False, progress=None) -> EngineSettings:
    """The settings for ``model`` on this machine: from the cache, else (or ``again``) calibrated
    now (a few seconds, once per machine, libraries and model shape) and cached; the fixed ones
    where ``STYLEERD_CALIBRATE=0``. Where the cache cannot be written, the choices hold for this process."""
    if os.environ.get("STYLEERD_CALIBRATE", "1") == "0":
        return fixed_settings()
    key = machine_key(model)
    path = cache_path(key)
    with _lock:  # a server's threads opening streams at once calibrate once
        if path in _known and not again:
            return _known[path]
        record = None if again else _read(path, key)
        if record is None:
            record = calibrate(model, progress=progress)
            try:
                if not record["contended"]:  # one made on a busy machine holds for this process only
                    path.parent.mkdir(parents=True, exist_ok=True)
                    atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(record, indent=1)))
            except (OSError, StyleERDError):
                pass
        _known[path] = settings_from(record, path)
        return _known[path]


def _read(path: Path, key: dict) -> dict | None:
    """The cached record at ``path`` if it is whole and for ``key``, else None (calibrate again)."""
    try:
        record = json.loads(path.read_text())
        settings_from(record, path)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    whole = record.get("format") == FORMAT and record.get("key") == key
    return record if whole and not contention(record["choices"]) else None  # one made on a busy machine: again
