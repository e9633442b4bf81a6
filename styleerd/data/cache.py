"""Preprocess datasets once into a versioned ``.npz`` cache of per-frame features.

The cache file's name carries a key made of ``CODE_VERSION``, the feature parameters and a
fingerprint of the source files (name, size, modification time); change any of them and
the next ``prepare`` rebuilds it, and removes the caches it replaces (the same dataset and
parameters under an older key). Clips are processed in parallel on every core.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import Counter
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from tqdm import tqdm

from styleerd.atomic import atomic_write
from styleerd.data.datasets import (
    COMBINED,
    DATASETS,
    Clip,
    bandai1_kept_back,
    cache_dir,
    data_root,
    find_clips,
    load_motion,
)
from styleerd.data.features import FeatureStats, features_to_motion, motion_features
from styleerd.data.windows import split_takes
from styleerd.errors import StyleERDError
from styleerd.motion.motion import Motion
from styleerd.motion.resample import resample
from styleerd.motion.skeleton import Skeleton

CODE_VERSION = 1  # bump whenever features, adapters or the split change


@dataclass(frozen=True)
class FeatureParams:
    fps: float = 30.0
    contact_speed: float = 0.25  # leg lengths per second


@dataclass
class FeatureSet:
    """One dataset's clips, frames concatenated: clip c is rows ``clip_start[c]:clip_start[c+1]``."""

    dataset: str
    skeleton: Skeleton
    features: np.ndarray  # [N, D] float32
    trajectory: np.ndarray  # [N, 7] root position + heading quaternion
    clip_start: np.ndarray  # [C + 1]
    names: np.ndarray  # [C] str, per clip
    styles: np.ndarray
    contents: np.ndarray
    splits: np.ndarray
    source_frames: np.ndarray  # [C] frame count of the source file
    params: FeatureParams
    path: Path | None = None
    meta: dict = field(default_factory=dict)

    def clips(self, split: str | None = None) -> np.ndarray:
        return np.arange(len(self.names)) if split is None else np.nonzero(self.splits == split)[0]

    def frames(self, clip: int) -> slice:
        return slice(int(self.clip_start[clip]), int(self.clip_start[clip + 1]))

    def motion(self, clip: int) -> Motion:
        """Clip ``clip`` as a motion again (``features_to_motion``)."""
        sl = self.frames(clip)
        return features_to_motion(self.features[sl], self.trajectory[sl], self.skeleton, self.params.fps)

    def stats(self, split: str = "train") -> FeatureStats:
        rows = np.concatenate([np.arange(self.clip_start[c], self.clip_start[c + 1]) for c in self.clips(split)])
        return FeatureStats.fit(self.features[rows], self.skeleton.n_joints)


def _fingerprint(root: Path, dataset: str) -> list:
    if dataset in COMBINED:
        return [f for part in COMBINED[dataset] for f in _fingerprint(root, part)]
    paths = [root / f"{dataset}.tar.xz"] if dataset.startswith("bandai") else sorted((root / dataset).iterdir())
    out = []
    for p in paths:
        if not p.exists():
            raise StyleERDError(f"{p} not found")
        st = p.stat()
        out.append([p.name, st.st_size, st.st_mtime_ns])
    return out


def cache_key(root: Path, dataset: str, params: FeatureParams) -> str:
    blob = json.dumps(
        {"version": CODE_VERSION, "dataset": dataset, "params": asdict(params), "files": _fingerprint(root, dataset)},
        sort_keys=True,
    )
    return hashlib.sha1(blob.encode()).hexdigest()[:16]


def _process(job: tuple[Clip, FeatureParams]) -> tuple[np.ndarray, np.ndarray, int, Skeleton]:
    clip, params = job
    source = load_motion(clip)
    motion = resample(source, params.fps)
    feats, traj = motion_features(motion, contact_speed=params.contact_speed)
    return feats.astype(np.float32), traj, source.n_frames, motion.skeleton


def build(
    root: Path, dataset: str, params: FeatureParams, cache: Path, workers: int | None = None, progress: bool = True
) -> FeatureSet:
    clips = find_clips(root, dataset, cache)
    jobs = [(c, params) for c in clips]
    workers = workers or os.cpu_count() or 1
    bar = tqdm(total=len(jobs), desc=dataset, unit="clip", disable=not progress)
    results = []
    if workers > 1:
        with get_context("spawn").Pool(workers) as pool:
            for r in pool.imap(_process, jobs, chunksize=16):
                results.append(r)
                bar.update()
    else:
        for job in jobs:
            results.append(_process(job))
            bar.update()
    bar.close()
    skeleton = results[0][3]
    for clip, (_, _, _, sk) in zip(clips, results):
        if sk.names != skeleton.names or not np.array_equal(sk.parents, skeleton.parents):
            raise StyleERDError(f"{clip.path}: skeleton differs from the rest of {dataset}")
    lengths = np.array([len(r[0]) for r in results])
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    if dataset in COMBINED:  # Bandai-1's few takes: a fixed set held out (datasets.bandai1_kept_back)
        split.update(
            {
                c.name: "test" if bandai1_kept_back(c.name, c.content) else "train"
                for c in clips
                if c.dataset == "bandai-namco-1"
            }
        )
    return FeatureSet(
        dataset=dataset,
        skeleton=skeleton,
        features=np.concatenate([r[0] for r in results]),
        trajectory=np.concatenate([r[1] for r in results]),
        clip_start=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        names=np.array([c.name for c in clips]),
        styles=np.array([c.style for c in clips]),
        contents=np.array([c.content for c in clips]),
        splits=np.array([split[c.name] for c in clips]),
        source_frames=np.array([r[2] for r in results]),
        params=params,
    )


_ARRAYS = ("features", "trajectory", "clip_start", "names", "styles", "contents", "splits", "source_frames")


def save(fs: FeatureSet, path: Path, meta: dict) -> None:
    """Atomic: written to a temporary file, then renamed into place."""
    meta = dict(meta, dataset=fs.dataset, skeleton=fs.skeleton.to_dict(), params=asdict(fs.params))
    arrays = {name: getattr(fs, name) for name in _ARRAYS} | {"meta": np.array(json.dumps(meta))}
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays), suffix=".tmp.npz")


def load(path: Path) -> FeatureSet:
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        return FeatureSet(
            dataset=meta["dataset"],
            skeleton=Skeleton.from_dict(meta["skeleton"]),
            **{name: z[name] for name in _ARRAYS},
            params=FeatureParams(**meta["params"]),
            path=path,
            meta=meta,
        )


def prepare(
    dataset: str = "bandai-namco-2",
    data: str | os.PathLike | None = None,
    params: FeatureParams = FeatureParams(),
    cache: Path | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> FeatureSet:
    """The feature set of ``dataset`` for ``params``: loaded from the cache when it is current, else built
    (unpacking archives as needed) and cached."""
    root = data_root(data)
    cache = cache or cache_dir()
    if dataset not in DATASETS:
        raise StyleERDError(f"unknown dataset {dataset!r}; known: {', '.join(DATASETS)}")
    key = cache_key(root, dataset, params)
    path = cache / f"features-{dataset}-{key}.npz"
    if path.is_file():
        try:
            fs = load(path)
            if fs.meta.get("version") == CODE_VERSION and fs.meta.get("key") == key:
                return fs
        except (OSError, ValueError, KeyError):
            pass  # unreadable or foreign: rebuild below
    fs = build(root, dataset, params, cache, workers, progress)
    save(fs, path, {"version": CODE_VERSION, "key": key, "data": str(root)})
    fs.path = path
    _drop_stale(cache, fs)
    return fs


def _drop_stale(cache: Path, fs: FeatureSet) -> None:
    """Remove the caches of ``fs``'s dataset and feature parameters under another key: built from
    older source files or code, no ``prepare`` loads them again, and each holds up to a few hundred
    MB (a data folder copied anew changes every file's time, and with it the key)."""
    for old in cache.glob(f"features-{fs.dataset}-*.npz"):
        if old == fs.path:
            continue
        try:
            with np.load(old, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
            if meta.get("dataset") == fs.dataset and meta.get("params") == asdict(fs.params):
                old.unlink()
        except (OSError, ValueError, KeyError):
            continue  # unreadable or foreign: not ours to remove


def summary(fs: FeatureSet) -> str:
    """Clips per content x style, frames per style, and totals, as a text table."""
    styles = sorted(set(fs.styles.tolist()))
    contents = sorted(set(fs.contents.tolist()))
    counts = Counter(zip(fs.styles.tolist(), fs.contents.tolist()))
    frames = Counter()
    for style, n in zip(fs.styles.tolist(), fs.source_frames.tolist()):
        frames[style] += n
    splits = Counter(fs.splits.tolist())
    total = int(fs.source_frames.sum())
    out = [
        (
            f"{fs.dataset}: {len(fs.names):,} clips, {len(styles)} styles x {len(contents)} contents, {total:,} frames "
            f"({len(fs.features):,} at {fs.params.fps:g} fps); split train/val/test = "
            f"{splits['train']}/{splits['val']}/{splits['test']} clips"
        )
    ]
    w = min(10, max(8, *(len(s) for s in styles))) + 1
    cw = max(len(c) for c in contents) + 1
    out.append("clips".ljust(cw) + "".join(f"{s[: w - 1]:>{w}}" for s in styles) + f"{'total':>{w}}")
    for c in contents:
        out.append(
            c.ljust(cw)
            + "".join(f"{counts[s, c] or '-':>{w}}" for s in styles)
            + f"{sum(counts[s, c] for s in styles):>{w}}"
        )
    out.append("frames".ljust(cw) + "".join(f"{frames[s]:>{w},}" for s in styles) + f"{total:>{w},}")
    return "\n".join(out)
