"""The compiled step alone (``runtime.compiled.compiled_step``, no backend around it) at batch 1, of this
checkout and of another commit, in one process: both kernels get the same packed parameters and state,
and are timed in alternating rounds (median and best of the rounds, us a step). What a change to the
kernel's code costs, apart from the Python around it and from the machine's drift between processes.

    python benchmarks/step_kernel_ab.py --before COMMIT [--rounds 10] [--steps 3000]
"""

from __future__ import annotations

import argparse
import importlib.util
import inspect
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def module_at(commit: str, path: str, folder: Path):
    """The module ``path`` (a file of the repository) as it was at ``commit``, imported from ``folder``
    (numba compiles its kernels on import or first call)."""
    source = subprocess.run(
        ["git", "show", f"{commit}:{path}"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    name = Path(path).stem + "_before"
    file = folder / f"{name}.py"
    file.write_text(source)
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", required=True)
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--steps", type=int, default=3000)
    args = p.parse_args()

    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime import compiled

    model = load_generator_weights()
    c = model.config
    backend = compiled.CompiledBackend(model, 1, 1)
    target = np.zeros((1, int(backend.sizes[6])), np.float32)
    target[0, (c.neutral_index + 1) % len(c.input_styles)] = 1.0  # a step to one style other than the input's
    rot, vel = np.empty((1, c.n_joints, 4), np.float32), np.empty((1, 3 * c.n_joints), np.float32)
    step_args = (
        np.random.default_rng(0).normal(0, 1, (1, c.feature_dim)).astype(np.float32),
        np.eye(len(c.input_styles), dtype=np.float32)[[c.neutral_index]],
        np.eye(len(c.contents), dtype=np.float32)[[0]],
        target,
        backend.params,
        backend.table,
        backend.sizes,
        backend.inits,
        backend.branch_styles,
        *backend._whole[1:5],
        backend.first,
        rot,
        vel,
        1,  # block rows
        2**31,  # compiled loops for any number of rows: batch 1's path
    )
    with tempfile.TemporaryDirectory() as folder:
        kernels = {
            f"before ({args.before})": module_at(
                args.before, "styleerd/runtime/compiled.py", Path(folder)
            ).compiled_step,
            "now": compiled.compiled_step,
        }
        # each version's arguments: later ones also take the streams' rows of the state (none: in place)
        arguments = {
            name: step_args + ((compiled.IN_PLACE,) if "state_rows" in inspect.signature(k.py_func).parameters else ())
            for name, k in kernels.items()
        }
        for name, kernel in kernels.items():
            for _ in range(200):  # compiled, warm
                kernel(*arguments[name])
        times: dict[str, list[float]] = {k: [] for k in kernels}
        for _ in range(args.rounds):
            for name, kernel in kernels.items():
                t0 = time.perf_counter()
                for _ in range(args.steps):
                    kernel(*arguments[name])
                times[name].append((time.perf_counter() - t0) / args.steps * 1e6)
    for name, t in times.items():
        print(f"{name}: median {np.median(t):.2f} us, best {min(t):.2f} us a step ({args.rounds} rounds)")


if __name__ == "__main__":
    main()
