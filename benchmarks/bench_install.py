"""Installed size and cold start of the two installs, side by side in one run:

    light: pip install styleerd.whl            (numpy, numba, ...; no torch)
    full:  pip install torch==2.13.0 'styleerd.whl[train]'

Each goes into a fresh virtualenv outside the checkout. Cold start: ``styleerd transfer`` of a 10-second walk (30 fps,
generated) run right after the install (numba compiles and caches its kernels in site-packages on that first run), then
the same command again (warm: the cache on disk); the same with ``--backend numba`` (its step kernels compile on their
first use). Sizes are of the whole virtualenv, with a bare virtualenv (pip alone) given for scale. Writes
docs/install.json.

    python benchmarks/bench_install.py
"""

from __future__ import annotations

import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(args: list, **kw) -> subprocess.CompletedProcess:
    done = subprocess.run([str(a) for a in args], capture_output=True, text=True, check=False, **kw)
    if done.returncode:
        sys.exit(f"{args}: {done.stderr[-3000:]}")
    return done


def size_mb(path: Path) -> float:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink()) / 1e6


def timed(args: list, cwd: Path) -> float:
    t = time.perf_counter()
    run(args, cwd=cwd)
    return time.perf_counter() - t


def main() -> None:
    work = Path(tempfile.mkdtemp(prefix="styleerd-install-"))
    run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", work / "wheel", ROOT])
    (wheel,) = (work / "wheel").glob("styleerd-*.whl")
    sys.path.insert(0, str(ROOT))
    from styleerd.motion import bvh, procedural

    clip = work / "walk10s.bvh"
    bvh.write(clip, procedural.walk(seconds=10.0, fps=30.0))
    bare = work / "bare"
    run([sys.executable, "-m", "venv", bare])
    report = {
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "wheel_mb": round(wheel.stat().st_size / 1e6, 2),
        "bare_venv_mb": round(size_mb(bare), 1),
        "clip": "10 s walk, 30 fps, 22 joints (generated)",
        "installs": {},
    }
    for name, requirements in (("light", [wheel]), ("full", ["torch==2.13.0", f"{wheel}[train]"])):
        venv = work / name
        run([sys.executable, "-m", "venv", venv])
        t = time.perf_counter()
        run([venv / "bin/python", "-m", "pip", "install", "--quiet", *requirements])
        install_s = time.perf_counter() - t
        cli = venv / "bin/styleerd"
        transfer = [cli, "transfer", clip, "--style", "elderly", "-o", work / f"out-{name}.bvh"]
        cold, warm = timed(transfer, work), timed(transfer, work)
        numba = [*transfer[:-2], "--backend", "numba", "-o", work / f"out-{name}-numba.bvh"]
        numba_cold, numba_warm = timed(numba, work), timed(numba, work)
        has_torch = (
            subprocess.run([venv / "bin/python", "-c", "import torch"], capture_output=True, check=False).returncode
            == 0
        )
        report["installs"][name] = {
            "requirements": [str(r).replace(str(wheel), "styleerd.whl") for r in requirements],
            "venv_mb": round(size_mb(venv), 1),
            "torch_installed": has_torch,
            "install_s": round(install_s, 1),
            "transfer_cold_s": round(cold, 2),
            "transfer_warm_s": round(warm, 2),
            "transfer_numba_cold_s": round(numba_cold, 2),
            "transfer_numba_warm_s": round(numba_warm, 2),
            "help_s": round(timed([cli, "--help"], work), 2),
        }
    out = ROOT / "docs" / "install.json"
    out.write_text(json.dumps(report, indent=1) + "\n")
    print(
        f"{'install':<7} {'venv MB':>8} {'torch':>6} {'transfer cold s':>16} {'warm s':>7} {'numba cold s':>13} "
        f"{'numba warm s':>13} {'--help s':>9}"
    )
    for name, r in report["installs"].items():
        print(
            f"{name:<7} {r['venv_mb']:>8.0f} {r['torch_installed']!s:>6} {r['transfer_cold_s']:>16.2f} "
            f"{r['transfer_warm_s']:>7.2f} "
            f"{r['transfer_numba_cold_s']:>13.2f} {r['transfer_numba_warm_s']:>13.2f} {r['help_s']:>9.2f}"
        )
    print(f"bare venv {report['bare_venv_mb']:.0f} MB; wheel {report['wheel_mb']} MB; wrote {out}")


if __name__ == "__main__":
    main()
