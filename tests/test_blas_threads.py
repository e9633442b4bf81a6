"""BLAS inside the engine's parallel loops: the numba step of many streams on 2 threads calls
sgemm from each of numba's OpenMP threads. A pthreads OpenBLAS asked for threads of its own
there prints "OpenBLAS Warning : Detect OpenMP Loop and this application may hang" (11,010
lines in one `styleerd bench` on an AMD machine) and can deadlock. Each thread of the loop holds
BLAS to itself, whoever calls the step (the main thread or a thread of the caller's pool, torch
loaded first or not, the caller's BLAS limit raised or not), and the caller's own BLAS threads
are as they were afterwards."""

import re
import subprocess
import sys

import numba
import pytest

from styleerd.data.parallel import kernel_threads

SCRIPT = r"""
import sys
if sys.argv[1] == "torch":
    import torch  # its own libgomp, loaded before numba's: the order `styleerd bench` has
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from styleerd.model.stored import load_generator_weights
from styleerd.runtime.backends import make_backend
from styleerd.runtime.stylizer import StreamStylizer

model = load_generator_weights()
c, n = model.config, 1000
backend = make_backend("numba", model, n, 2)
x = np.random.default_rng(0).normal(0, 1, (n, c.feature_dim)).astype(np.float32)
one_hot = lambda k, i: np.eye(k, dtype=np.float32)[np.full(n, i)]
inputs = (x, one_hot(len(c.input_styles), c.neutral_index), one_hot(len(c.contents), 0),
          one_hot(len(c.styles), c.styles.index("elderly")))
stylizer = StreamStylizer(model, "normal", "walk", {"elderly": 1.0}, n_streams=n, backend="numba", threads=2)
rotations = np.zeros((n, c.n_joints, 4)) + [1.0, 0.0, 0.0, 0.0]
positions = np.zeros((n, c.n_joints, 3))


def blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def steps() -> list[int]:
    before = blas_threads()
    for _ in range(5):
        backend.step(*inputs, None)
        stylizer.step(rotations, positions)
    assert blas_threads() == before, (before, blas_threads())
    return before


with threadpool_limits(2, user_api="blas"), ThreadPoolExecutor(1) as pool:
    steps()
    pool.submit(steps).result()
print("done")
"""


@pytest.mark.skipif(kernel_threads(2, 1000) == 1, reason="numba's kernels run on one thread here (no parallel loops)")
@pytest.mark.parametrize("first", ["torch", "numba"])
def test_the_many_stream_step_on_2_threads_prints_no_openblas_warning(first):
    assert numba.config.NUMBA_NUM_THREADS >= 2
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, first], capture_output=True, text=True, timeout=600, check=False
    )
    assert done.returncode == 0 and "done" in done.stdout, done.stderr[-3000:]
    assert "OpenBLAS" not in done.stderr, done.stderr.count("\n")


def test_info_system_names_the_cpu_the_blas_libraries_and_the_engines_settings():
    """``styleerd info --system``: the CPU model as /proc/cpuinfo has it, every BLAS and OpenMP
    library threadpoolctl finds loaded, numba's threads and layer, and the engine's settings."""
    import subprocess
    import sys
    from pathlib import Path

    done = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "info", "--system"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    out = done.stdout
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        model = next(
            line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines() if line.startswith("model name")
        )
        assert f"CPU: {model} (" in out
    assert "openblas" in out and "thread pools loaded:" in out and "numba" in out
    assert "numba step, by batch size (calibrated on this machine" in out
    assert re.search(r" 1024 \| BLAS, (blocks of \d+|whole shards), ", out), out
