"""Many files at once: ``styleerd transfer a.bvh b.fbx folder/ -o OUT_DIR``.

Each file goes through the same transfer as a single one (``transfer_one``: BVH, glTF/GLB/VRM,
FBX through Blender), in a pool of worker processes (one per core by default, each loading the
model once). A file that fails is reported with its reason and skipped; the others are written.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

from tqdm import tqdm

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.motion.gltf import GLTF_INPUTS
from styleerd.runtime.offline import TransferOptions, TransferReport, transfer_file

MOTION_FILES = (".bvh", *GLTF_INPUTS, ".fbx")
OUTPUTS = (".bvh", ".glb", ".vrm", ".fbx")


def transfer_one(source: Path, output: Path, model: GeneratorWeights, options: TransferOptions, report: Callable[[str], None] | None = None) -> TransferReport:
    """One file of any supported kind in, one out; FBX on either side goes through Blender."""
    if Path(output).suffix.lower() not in OUTPUTS:
        raise StyleERDError(f"{output}: the output must be .bvh, .glb or .fbx (or .vrm from a VRM or glTF input)")
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
    pairs = [(src, out.with_suffix(suffix or (".glb" if out.suffix.lower() == ".gltf" else out.suffix))) for src, out in pairs]
    seen: dict[Path, Path] = {}
    for src, out in pairs:
        if out in seen:
            raise StyleERDError(f"{src} and {seen[out]} would both be written to {out}")
        seen[out] = src
    return pairs


_worker_model: GeneratorWeights | None = None


def _start_worker(model_name: str | None) -> None:
    global _worker_model
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _worker_model = load_generator_weights(model_name)


def _work(source: Path, output: Path, options: TransferOptions) -> str:
    output.parent.mkdir(parents=True, exist_ok=True)
    done = transfer_one(source, output, _worker_model, options)
    return f"{done.frames} frames at {done.fps:.6g} fps"


def transfer_batch(pairs: list[tuple[Path, Path]], model_name: str | None, options: TransferOptions, workers: int | None = None) -> list[tuple[Path, str]]:
    """Every (input, output) pair through ``transfer_one`` on a process pool, with a progress
    bar; -> the (input, reason) of the files that failed (the others are written)."""
    workers = max(1, min(workers or os.cpu_count() or 1, len(pairs)))
    failed: list[tuple[Path, str]] = []
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_start_worker, initargs=(model_name,)) as pool:
        futures = {pool.submit(_work, src, out, options): (src, out) for src, out in pairs}
        with tqdm(total=len(pairs), unit="file", desc="transfer") as bar:
            for future in as_completed(futures):
                src, out = futures[future]
                try:
                    bar.write(f"{src} -> {out}: {future.result()}")
                except StyleERDError as e:
                    failed.append((src, str(e)))
                    bar.write(f"{src}: skipped: {e}")
                except Exception as e:  # a worker's unexpected failure costs its file only
                    failed.append((src, f"{type(e).__name__}: {e}"))
                    bar.write(f"{src}: skipped: {type(e).__name__}: {e}")
                bar.update()
    return failed
