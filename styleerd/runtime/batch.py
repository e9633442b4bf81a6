"""Many files at once: ``styleerd transfer a.bvh b.fbx folder/ -o OUT_DIR``.

Each file goes through the same transfer as a single one (``transfer_one``: BVH, glTF/GLB/VRM,
FBX through Blender), on worker processes (one per core by default, each loading the model
once). A file that fails, runs too long, needs too much memory or crashes its worker is reported
with its reason and skipped; the others are written.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from multiprocessing import get_context
from pathlib import Path

from tqdm import tqdm

from styleerd.atomic import remove_orphans
from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.motion.gltf import GLTF_INPUTS
from styleerd.runtime.calibration import engine_settings
from styleerd.runtime.offline import TransferOptions, TransferReport, transfer_file

MOTION_FILES = (".bvh", *GLTF_INPUTS, ".fbx")
OUTPUTS = (".bvh", ".glb", ".vrm", ".vrma", ".fbx")


def transfer_one(
    source: Path,
    output: Path,
    model: GeneratorWeights,
    options: TransferOptions,
    report: Callable[[str], None] | None = None,
) -> TransferReport:
    """One file of any supported kind in, one out; FBX on either side goes through Blender."""
    if Path(output).suffix.lower() not in OUTPUTS:
        raise StyleERDError(
            f"{output}: the output must be .bvh, .glb, .vrma or .fbx (or .vrm from a VRM or glTF input; onto a "
            "character of your own: --onto AVATAR)"
        )
    if Path(source).suffix.lower() == ".fbx" or Path(output).suffix.lower() == ".fbx":
        from styleerd.runtime.fbx import transfer_fbx  # imports bpy: only for FBX

        return transfer_fbx(Path(source), Path(output), model, options, report)
    return transfer_file(source, output, model, model.meta["data"]["fps"], options, report)


def batch_pairs(inputs: list[str | Path], output_dir: str | Path, suffix: str | None = None) -> list[tuple[Path, Path]]:
    """(input, output) of every motion file named or inside a named folder (recursively, the
    folder's layout kept under ``output_dir``); outputs keep the input's kind unless ``suffix``
    (.bvh, .glb, ...) is given."""
    pairs: list[tuple[Path, Path]] = []
    for item in map(Path, inputs):
        if item.is_dir():
            found = sorted(p for p in item.rglob("*") if p.suffix.lower() in MOTION_FILES and p.is_file())
            if not found:
                raise StyleERDError(f"{item}: no motion files ({', '.join(MOTION_FILES)}) in this folder")
            pairs += [(p, Path(output_dir) / p.relative_to(item)) for p in found]
        elif item.exists():
            pairs.append((item, Path(output_dir) / item.name))
        else:
            raise StyleERDError(f"{item}: no such file or folder")
    pairs = [
        (src, out.with_suffix(suffix or (".glb" if out.suffix.lower() == ".gltf" else out.suffix)))
        for src, out in pairs
    ]
    seen: dict[Path, Path] = {}
    for src, out in pairs:
        if out in seen:
            raise StyleERDError(f"{src} and {seen[out]} would both be written to {out}")
        seen[out] = src
    return pairs


def inert_options(pairs: list[tuple[Path, Path]], options: TransferOptions, onto: bool = False) -> list[str]:
    """The options given that would change none of these (input, output) pairs, each with what
    it is for: an option that does nothing is refused rather than ignored."""
    kinds = [(src.suffix.lower(), out.suffix.lower()) for src, out in pairs]
    out = []
    if options.mesh and (onto or not any(i in (".bvh", ".fbx") and o == ".glb" for i, o in kinds)):
        out.append("--mesh: a body for a .glb written from a BVH or FBX motion (an avatar of --onto has its own)")
    if options.animation != "all" and not any(i in (*GLTF_INPUTS, ".fbx") for i, _ in kinds):
        out.append("--animation: picks an animation of a glTF, VRM or FBX file (a BVH holds one)")
    keeps = any(i in GLTF_INPUTS and o in (".glb", ".vrm") or i == o == ".fbx" for i, o in kinds)
    if options.keep_original and not (onto or keeps):
        out.append(
            "--keep-original: keeps a glTF/VRM or FBX file's own animations beside the stylised ones, written back "
            "as .glb/.vrm or .fbx"
        )
    return out


def _orphan_guard() -> None:
    """A worker ends itself when the batch's process is gone (killed with -9: no orphan goes on
    writing files)."""
    import threading
    import time

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _serve(conn, model_name: str | None, memory_bytes: int | None) -> None:
    """A worker: load the model once, then transfer each (source, output, options) it is sent,
    answering (ok, message). Memory beyond ``memory_bytes`` fails its file, not the machine."""
    import resource
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the batch decides when its workers stop
    _orphan_guard()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if memory_bytes:
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    model = load_generator_weights(model_name)
    conn.send((True, "ready"))
    while True:
        try:
            source, output, options = conn.recv()
        except EOFError:
            return
        try:
            output.parent.mkdir(parents=True, exist_ok=True)
            done = transfer_one(source, output, model, options)
            conn.send((True, f"{done.frames} frames at {done.fps:.6g} fps"))
        except StyleERDError as e:
            conn.send((False, str(e)))
        except MemoryError:
            conn.send((False, f"more memory than --max-memory {memory_bytes / 2**30:g} GiB"))
        except Exception as e:  # noqa: BLE001  a bug costs its file only
            conn.send((False, f"{type(e).__name__}: {e}"))


class _Worker:
    def __init__(self, ctx, model_name: str | None, memory_bytes: int | None):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(child, model_name, memory_bytes), daemon=True)
        self.process.start()
        child.close()
        self.ready, self.task, self.since = False, None, 0.0

    def stop(self) -> None:
        if self.process.is_alive():
            self.process.kill()
        self.process.join(10)
        self.conn.close()


def transfer_batch(
    pairs: list[tuple[Path, Path]],
    model_name: str | None,
    options: TransferOptions,
    workers: int | None = None,
    timeout: float = 600.0,
    max_memory_gb: float | None = None,
    resume: bool = False,
) -> list[tuple[Path, str]]:
    """Every (input, output) pair through ``transfer_one`` on worker processes, with a progress
    bar; -> the (input, reason) of the files that failed (the others are written). A file that
    takes longer than ``timeout`` seconds, needs more than ``max_memory_gb``, or crashes its worker
    fails alone: its worker is replaced. ``resume``: outputs already there are complete (writes are
    atomic) and skipped. Ctrl-C and SIGTERM stop every worker at once and leave no partial file."""
    import signal
    import time
    from multiprocessing.connection import wait

    if resume:
        pairs = [(src, out) for src, out in pairs if not out.exists()]
    if not pairs:
        return []
    workers = max(1, min(workers or os.cpu_count() or 1, len(pairs)))
    if options.backend == "numba" and workers > 1:
        # the engine's settings measured here once and read back by every worker: each measuring at once, beside the
        # others, took longer and measured their noise
        engine_settings(load_generator_weights(model_name))
    ctx = get_context("spawn")
    memory = int(max_memory_gb * 2**30) if max_memory_gb else None
    todo, failed, pool = list(reversed(pairs)), [], []

    def terminate(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        pool = [_Worker(ctx, model_name, memory) for _ in range(workers)]
        with tqdm(total=len(pairs), unit="file", desc="transfer") as bar:
            while todo or any(w.task for w in pool):
                for w in pool:
                    if w.ready and w.task is None and todo:
                        w.task, w.since = todo.pop(), time.monotonic()
                        w.conn.send((*w.task, options))
                for conn in wait([w.conn for w in pool], timeout=0.2):
                    w = next(w for w in pool if w.conn is conn)
                    try:
                        ok, message = conn.recv()
                    except (EOFError, OSError):  # the worker died: noticed below
                        continue
                    if not w.ready:
                        w.ready = True
                        continue
                    (src, out), w.task = w.task, None
                    bar.write(f"{src} -> {out}: {message}" if ok else f"{src}: skipped: {message}")
                    if not ok:
                        failed.append((src, message))
                    bar.update()
                for k, w in enumerate(pool):
                    late = w.task is not None and time.monotonic() - w.since > timeout
                    if late or not w.process.is_alive():
                        why = (
                            f"took longer than --timeout {timeout:g} s"
                            if late
                            else f"its worker stopped (exit code {w.process.exitcode})"
                        )
                        w.stop()
                        if w.task is not None:
                            src, out = w.task
                            remove_orphans(out)  # the stopped worker's temporary file
                            failed.append((src, why))
                            bar.write(f"{src}: skipped: {why}")
                            bar.update()
                        elif not w.ready:
                            raise StyleERDError(f"a transfer worker could not start ({why})")
                        pool[k] = _Worker(ctx, model_name, memory)
    finally:
        signal.signal(signal.SIGTERM, previous)
        for w in pool:
            w.stop()
            if w.task is not None:
                remove_orphans(w.task[1])
    return failed
