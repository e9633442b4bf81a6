"""Training data as tensors: normalised frames plus labelled window starts per split."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from styleerd.data.cache import FeatureSet
from styleerd.data.features import FeatureLayout, FeatureStats
from styleerd.data.windows import window_starts
from styleerd.model import torch_quat


@dataclass
class WindowSet:
    starts: np.ndarray  # [N] first row of each window in the frame tensor
    style: np.ndarray  # [N] style index
    content: np.ndarray  # [N] content index
    clip: np.ndarray  # [N] clip index


@dataclass
class TrainingData:
    frames: torch.Tensor  # [rows, D] normalised features, float32
    styles: list[str]
    contents: list[str]
    window: int
    stats: FeatureStats

    def gather(self, starts: np.ndarray) -> torch.Tensor:
        idx = torch.as_tensor(starts[:, None] + np.arange(self.window))
        return self.frames[idx]

    def onehot_style(self, idx: np.ndarray) -> torch.Tensor:
        return torch.nn.functional.one_hot(torch.as_tensor(idx), len(self.styles)).float()

    def onehot_content(self, idx: np.ndarray) -> torch.Tensor:
        return torch.nn.functional.one_hot(torch.as_tensor(idx), len(self.contents)).float()


def training_data(fs: FeatureSet, window: int) -> TrainingData:
    stats = fs.stats("train")
    frames = torch.from_numpy(stats.normalize(fs.features).astype(np.float32))
    return TrainingData(frames, sorted(set(fs.styles.tolist())), sorted(set(fs.contents.tolist())), window, stats)


def windows(fs: FeatureSet, data: TrainingData, split: str, stride: int, max_clips: int = 0) -> WindowSet:
    clips = fs.clips(split)
    if max_clips:
        clips = clips[np.linspace(0, len(clips) - 1, min(max_clips, len(clips))).astype(int)]
    starts = window_starts(fs.clip_start, clips, data.window, stride)
    clip = np.searchsorted(fs.clip_start, starts, side="right") - 1
    style = np.array([data.styles.index(s) for s in fs.styles[clip]])
    content = np.array([data.contents.index(c) for c in fs.contents[clip]])
    return WindowSet(starts, style, content, clip)


def window_rotations(data: TrainingData, starts: np.ndarray) -> torch.Tensor:
    """Unit quaternions ``[B, T, J, 4]`` of real windows (already in the reference hemisphere)."""
    x = data.gather(starts)
    J = len(data.stats.reference)
    rot = FeatureLayout(J).rotations
    q = x[..., rot] * torch.as_tensor(data.stats.std[rot], dtype=torch.float32) + torch.as_tensor(
        data.stats.mean[rot], dtype=torch.float32
    )
    return torch_quat.normalize(q.reshape(*x.shape[:2], J, 4))
