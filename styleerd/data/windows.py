"""Train/validation/test split by take, and T-frame training windows."""

from __future__ import annotations

import hashlib
from collections import defaultdict

import numpy as np

SPLITS = ("train", "val", "test")


def _rank_key(name: str) -> str:
    return hashlib.sha1(name.encode()).hexdigest()


def split_takes(groups: dict[str, tuple[str, str, str]], fraction: float = 0.1, min_group: int = 5) -> dict[str, str]:
    """Assign each take (file name -> (dataset, style, content)) to "train", "val" or "test".

    A pure function of the names: within every (dataset, style, content) group the takes are
    ranked by a hash of their name; the first ``max(1, round(fraction * n))`` go to test, as
    many again to validation, the rest to training. Groups smaller than ``min_group`` go
    entirely to training. Every take lands in exactly one split, and each group large
    enough has test and validation takes."""
    by_group: dict[tuple, list[str]] = defaultdict(list)
    for name, group in groups.items():
        by_group[group].append(name)
    split = {}
    for names in by_group.values():
        names = sorted(names, key=_rank_key)
        k = max(1, round(fraction * len(names))) if len(names) >= min_group else 0
        for i, name in enumerate(names):
            split[name] = "test" if i < k else "val" if i < 2 * k else "train"
    return split


def window_starts(clip_start: np.ndarray, clips: np.ndarray, length: int = 24, stride: int = 20) -> np.ndarray:
    """Start rows (into the concatenated frames) of every ``length``-frame window inside the
    given clips, every ``stride`` frames. ``clip_start [C+1]`` bounds clip c as rows
    ``clip_start[c]:clip_start[c+1]``. Clips shorter than ``length`` give no window."""
    starts = [np.arange(clip_start[c], clip_start[c + 1] - length + 1, stride) for c in clips]
    return np.concatenate(starts).astype(np.int64) if starts else np.zeros(0, np.int64)


def gather_windows(frames: np.ndarray, starts: np.ndarray, length: int = 24) -> np.ndarray:
    """``frames[N, ...]`` -> windows ``[len(starts), length, ...]``."""
    return frames[starts[:, None] + np.arange(length)]
