"""Training data as tensors: normalised frames plus labelled window starts per split."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from styleerd.data.augment import STRAIGHT, TRAVELLING, in_place
from styleerd.data.cache import FeatureSet, prepare
from styleerd.data.datasets import BANDAI1_AS_BANDAI2, COMBINED, bandai1_kept_back, data_root, unpack
from styleerd.data.features import FeatureLayout, FeatureStats, motion_features
from styleerd.data.outside import held_out
from styleerd.data.windows import window_starts
from styleerd.model import torch_quat
from styleerd.motion import bvh
from styleerd.motion.resample import resample
from styleerd.motion.retarget import joint_map, to_target


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


@dataclass
class OutsideWindows:
    """Windows of other performers' clips and of training walks in place (``outside_windows``), in
    styles the model has."""

    frames: torch.Tensor  # [rows, D] normalised features
    starts: np.ndarray  # [N] first row of each window
    style: np.ndarray  # [N] style index
    content: np.ndarray  # [N] content index, -1 where the model has no such content

    def gather(self, rows: np.ndarray, length: int) -> torch.Tensor:
        return self.frames[torch.as_tensor(self.starts[rows][:, None] + np.arange(length))]


def in_place_clips(
    fs: FeatureSet, data: TrainingData, every: int = 4, contents: tuple[str, ...] = TRAVELLING
) -> tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
    """Every ``every``-th walk, turn and run (``contents``) of the training split with its root's
    ground path removed, as game and three.js libraries ship them: (normalised frames ``[N, D]``,
    clip starts ``[C + 1]``, style and content index per clip)."""
    frames, starts, styles, told = [], [0], [], []
    for c in [c for c in training_clips(fs) if fs.contents[c] in contents][::every]:
        motion = in_place(fs.motion(int(c)))
        frames.append(data.stats.normalize(motion_features(motion)[0]).astype(np.float32))
        starts.append(starts[-1] + len(frames[-1]))
        styles.append(data.styles.index(fs.styles[c]))
        told.append(data.contents.index(fs.contents[c]))
    return torch.from_numpy(np.concatenate(frames)), np.array(starts), np.array(styles), np.array(told)


def outside_windows(
    fs: FeatureSet,
    data: TrainingData,
    stride: int,
    data_dir: str | None = None,
    progress: bool = True,
    bound: float = 16.0,
    neutral: int | None = None,
    in_place: bool = True,
    turns_in_place: bool = True,
) -> OutsideWindows:
    """Every ``data.window``-frame window, each ``stride`` frames, of the ``outside_clips`` whose style
    the model has (one it lacks has no own style to be rebuilt in) and of the ``in_place_clips``, but
    those with a feature beyond ``bound`` standard deviations: none of Bandai-Namco-2's training
    windows reaches 16, and the 1.3 % of other performers' that do (glitches and flailing of
    cmu-sample's) would otherwise make 40 % of the loss. With ``neutral`` (the neutral style's
    index), other performers' clips in the model's other styles are left out; without ``in_place``,
    the walks in place are; without ``turns_in_place``, only straight walks and runs are put in place
    (every second one, about as many windows)."""
    frames, clip_start, style, content = outside_clips(fs, data, data_dir, progress)
    if neutral is not None:
        style = np.where(style == neutral, style, -1)
    if in_place:
        more, more_start, more_style, more_content = (
            in_place_clips(fs, data) if turns_in_place else in_place_clips(fs, data, 2, STRAIGHT)
        )
        frames, clip_start = torch.cat([frames, more]), np.concatenate([clip_start, clip_start[-1] + more_start[1:]])
        style, content = np.concatenate([style, more_style]), np.concatenate([content, more_content])
    starts = window_starts(clip_start, np.nonzero(style >= 0)[0], data.window, stride)
    clip = np.searchsorted(clip_start, starts, side="right") - 1
    every = OutsideWindows(frames, starts, style[clip], content[clip])
    inside = (every.gather(np.arange(len(starts)), data.window).abs().amax((1, 2)) <= bound).numpy()
    return OutsideWindows(frames, starts[inside], every.style[inside], every.content[inside])


def outside_contents(content: np.ndarray, n_contents: int, known: bool, rng: np.random.Generator) -> np.ndarray:
    """The contents ``[N, n_contents]`` outside windows are told: from one-hot to uniform (Dirichlet
    0.3), or, with ``known``, a window's own (one-hot) where the model has it (``content >= 0``)."""
    told = rng.dirichlet(np.full(n_contents, 0.3), len(content))
    if known:
        mine = content >= 0
        told[mine] = np.eye(n_contents)[content[mine]]
    return told


def training_data(fs: FeatureSet, window: int) -> TrainingData:
    stats = fs.stats("train")
    frames = torch.from_numpy(stats.normalize(fs.features).astype(np.float32))
    return TrainingData(frames, sorted(set(fs.styles.tolist())), sorted(set(fs.contents.tolist())), window, stats)


def training_clips(fs: FeatureSet) -> np.ndarray:
    """The training split's clips less the held-out outside actions (``data.outside.held_out``): Bandai-Namco-1's
    neutral dances, kicks and punches are training clips of ``bandai-namco-1+2`` by its split, and
    ``styleerd eval actions`` reports on them as motion no model has seen."""
    parts = COMBINED.get(fs.dataset, (fs.dataset,))
    return np.array(
        [
            c
            for c in fs.clips("train")
            if not any(held_out(str(fs.names[c]), p, str(fs.contents[c]), str(fs.styles[c])) for p in parts)
        ],
        dtype=np.int64,
    )


def windows(fs: FeatureSet, data: TrainingData, split: str, stride: int, max_clips: int = 0) -> WindowSet:
    clips = training_clips(fs) if split == "train" else fs.clips(split)
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


def outside_clips(
    fs: FeatureSet, data: TrainingData, data_dir: str | None = None, progress: bool = True
) -> tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
    """Other performers' clips that no evaluation uses: Bandai-Namco-1's but its kept-back and
    held-out ones, and cmu-sample's subjects but the held-out ones (retargeted onto ``fs``'s
    skeleton): (normalised frames ``[N, D]``, clip starts ``[C + 1]``, style and content index per
    clip, -1 where the model has no such label: a style to be unsure of, a content not taught)."""
    frames, starts, styles, contents = [], [0], [], []

    def add(features: np.ndarray, style: str, content: str) -> None:
        frames.append(data.stats.normalize(features).astype(np.float32))
        starts.append(starts[-1] + len(features))
        styles.append(data.styles.index(style) if style in data.styles else -1)
        contents.append(data.contents.index(content) if content in data.contents else -1)

    bandai1 = prepare("bandai-namco-1", data_dir, fs.params, progress=progress)
    for c, name in enumerate(bandai1.names):
        style, content = str(bandai1.styles[c]), str(bandai1.contents[c])
        if not (bandai1_kept_back(name, content) or held_out(name, "bandai-namco-1", content, style)):
            add(bandai1.features[bandai1.frames(c)], BANDAI1_AS_BANDAI2.get(style, style), content)
    cmu = unpack(data_root(data_dir) / "cmu-sample.tar.xz") / "cmu-sample"
    paths = [p for folder in ("iclone", "asf-names") for p in sorted((cmu / folder).glob("*.bvh"))]
    for path in tqdm(paths, desc="cmu-sample", disable=not progress, leave=False):
        if held_out(path.stem, "cmu-sample"):
            continue
        motion = resample(bvh.read(path), fs.params.fps)
        jm = joint_map(fs.skeleton, motion.skeleton, None, data.stats.reference, motion.rotations[0])
        add(motion_features(to_target(motion, jm))[0], "normal", "")
    return torch.from_numpy(np.concatenate(frames)), np.array(starts), np.array(styles), np.array(contents)
