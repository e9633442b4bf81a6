"""What this machine gives the engine: the CPU, the BLAS libraries and threading layers loaded
(threadpoolctl), numba's threads and layer, onnxruntime where installed, and the engine's settings
for it (``styleerd info --system``; ``styleerd bench`` records the same with its figures). A
benchmark read without these cannot be compared with another machine's."""

from __future__ import annotations

import os
import platform
from dataclasses import asdict
from pathlib import Path

import numba as nb
import numpy as np
import scipy
from threadpoolctl import threadpool_info

from styleerd.data.parallel import PARALLEL_FROM, threadsafe_layer
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.runtime.calibration import WHOLE, EngineSettings, engine_settings
from styleerd.runtime.stylizer import SHARD_FROM


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else what Python's platform says)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def cpu_flags() -> list[str]:
    """The vector instruction sets the CPU reports that matter to float32 kernels."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return []
    flags = next((line.split(":", 1)[1].split() for line in text.splitlines() if line.startswith("flags")), [])
    return [f for f in ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512_vnni", "amx_tile") if f in flags]


def system_report(model: GeneratorWeights | None = None) -> dict:
    """The machine and the engine's settings on it for ``model`` (default: the shipped one;
    calibrated now if this machine has not been: ``runtime.calibration``)."""
    scipy.linalg.blas  # noqa: B018  loads scipy's BLAS, which numba's compiled products call
    try:
        import onnxruntime

        onnx = onnxruntime.__version__
    except ImportError:
        onnx = None
    threadsafe_layer()  # picks numba's thread-safe layer, as the first parallel step would
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "vector_sets": cpu_flags(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": nb.__version__,
        "onnxruntime": onnx,
        "numba_threads": nb.config.NUMBA_NUM_THREADS,
        "numba_threading_layer": nb.config.THREADING_LAYER,
        "thread_pools": [
            {k: info.get(k) for k in ("internal_api", "version", "threading_layer", "architecture", "num_threads")}
            | {"library": Path(info["filepath"]).name}
            for info in threadpool_info()
        ],
        "engine": {
            "numba_step": engine_choices(engine_settings(model or load_generator_weights())),
            "kernels_threads_from_streams": PARALLEL_FROM,
            "shards_from_streams": SHARD_FROM,
        },
    }


def engine_choices(settings: EngineSettings) -> dict:
    """The numba step's choice at each batch size, as a report reads it."""
    return {
        "source": settings.source,
        "from_streams": list(settings.streams),
        "one_thread": [asdict(c) for c in settings.one_thread],
        "many_threads": [asdict(c) for c in settings.many_threads],
    }


def describe(report: dict) -> str:
    """``system_report`` as lines for a terminal."""
    lines = [
        f"CPU: {report['cpu']} ({report['cores']} cores; {' '.join(report['vector_sets']) or 'no vector sets read'})",
        (
            f"Python {report['python']}, numpy {report['numpy']}, numba {report['numba']} "
            f"({report['numba_threads']} threads, layer {report['numba_threading_layer']}), "
            f"onnxruntime {report['onnxruntime'] or 'not installed'}"
        ),
        "thread pools loaded:",
    ]
    for pool in report["thread_pools"]:
        about = [pool["library"], f"{pool['num_threads']} threads"]
        about += [f"threading {pool['threading_layer']}"] * bool(pool["threading_layer"])
        about += [f"{pool['architecture']} kernels"] * bool(pool["architecture"])
        lines.append(f"  {pool['internal_api']} {pool['version'] or ''}".rstrip() + f" ({'; '.join(about)})")
    e, step = report["engine"], report["engine"]["numba_step"]
    lines.append(f"numba step, by batch size ({step['source']}):")
    lines.append("  streams from | one thread asked | more threads asked")
    blocks = lambda c: "whole shards" if c["block_rows"] >= WHOLE else f"blocks of {c['block_rows']}"
    path = lambda c: f"{'loops' if c['loops'] else 'BLAS'}, {blocks(c)}, {c['threads']} thread(s)"
    for n, one, many in zip(step["from_streams"], step["one_thread"], step["many_threads"], strict=True):
        lines.append(f"  {n:>12} | {path(one)} | {path(many)}")
    lines.append(
        f"other kernels: numba threads from {e['kernels_threads_from_streams']} streams; numpy/onnx shards from "
        + ", ".join(f"{k} {v}" for k, v in e["shards_from_streams"].items())
        + " streams (fixed settings)"
    )
    return "\n".join(lines)
