"""Training the OnlineLabeller on real training clips, and how well it labels streams.

Training sequences are ``length``-frame stretches of training clips, each starting from a
fresh state (a stream can begin anywhere in a motion); the loss is the labels' cross-entropy
at every frame, so early frames learn to guess and later ones to be sure. Beside the clips as
recorded, ``copies`` versions of each as another performer on another rig would give it
(``data.augment.other_performer``: proportions, speed, joint offsets, mirroring, in place) keep the
labeller from reading one performer's build or one rig's conventions as a style. Clips of other
performers join them too (``outside_clips``): Bandai-Namco-1's, with its styles in the model's
names and its styles the model does not have taught to read as unsure (the cross-entropy of
their posterior to the uniform one, "outlier exposure", Hendrycks et al. 2019), and
cmu-sample's other subjects as neutral; the clips ``styleerd eval labels`` measures on are kept
out. The trained labeller is then told where its states are like its training streams'
(``fit_familiarity``), so that a stream unlike them is read as unsure. Accuracy is measured on
streams that start at the first frame of each clip of a split, after 1, 10 and 30 frames.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from styleerd.data.augment import other_performer
from styleerd.data.cache import FeatureSet
from styleerd.data.features import motion_features
from styleerd.data.windows import window_starts
from styleerd.errors import StyleERDError
from styleerd.model import checkpoint as ckpt
from styleerd.model.labeller import OnlineLabeller
from styleerd.model.stored import Familiarity, familiarity, toward_neutral
from styleerd.models import LABELLER, MODELS_DIR
from styleerd.train.batches import TrainingData, outside_clips, windows
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import setup

AFTER_FRAMES = (1, 10, 30)
# the frame counts that start a new group of states in ``fit_familiarity`` (a stream's first states
# are unlike its later ones)
FAMILIAR_EDGES = (1, 2, 4, 8, 16)


@torch.no_grad()
def stream_accuracy(
    model: OnlineLabeller,
    fs: FeatureSet,
    data: TrainingData,
    split: str,
    after: tuple[int, ...] = AFTER_FRAMES,
    neutral: str | None = None,
) -> dict[int, dict[str, float]]:
    """{n: {"style": acc, "content": acc, "streams": k}}: labels right after n frames of a
    stream that starts at a clip's first frame (clips shorter than n frames not counted).
    With ``neutral``, unsure style posteriors and unfamiliar states lean to it first, as the
    stylizer does."""
    model.eval()
    clips = fs.clips(split)
    longest = max(after)
    rows = [fs.frames(c) for c in clips]
    out = {}
    style_pred, content_pred, length = [], [], []
    for sl in rows:
        n = min(longest, sl.stop - sl.start)
        y = model.states(data.frames[sl.start : sl.start + n][None])[0]
        p = torch.softmax(model.style(y), -1).numpy()
        if neutral is not None:
            trust = None if model.familiar is None else familiarity(y.numpy(), np.arange(n), model.familiar)
            p = toward_neutral(p, data.styles.index(neutral), trust)
        style_pred.append(p.argmax(-1))
        content_pred.append(model.content(y).argmax(-1).numpy())
        length.append(n)
    true_s = np.array([data.styles.index(s) for s in fs.styles[clips]])
    true_c = np.array([data.contents.index(c) for c in fs.contents[clips]])
    for n in after:
        keep = [i for i, k in enumerate(length) if k >= n]
        out[n] = {
            "style": round(float(np.mean([style_pred[i][n - 1] == true_s[i] for i in keep])), 4),
            "content": round(float(np.mean([content_pred[i][n - 1] == true_c[i] for i in keep])), 4),
            "streams": len(keep),
        }
    return out


@torch.no_grad()
def fit_familiarity(
    model: OnlineLabeller,
    streams: list[tuple[torch.Tensor, int]],
    validation: list[torch.Tensor],
    percentiles: tuple[float, float] = TrainConfig.labeller_familiar,
) -> Familiarity:
    """Where ``model``'s states are like those of the ``streams`` it learnt from (normalised
    frames ``[T, D]`` from a stream's start, style index): per group of frames since the start
    (``FAMILIAR_EDGES``), each style's mean state, and one covariance of the states about their
    means (Mahalanobis distance); a state is familiar up to the first of the ``percentiles`` of
    the ``validation`` streams' distances in its group and unfamiliar from the second. A labeller
    taught to read other performers as unsure still reads some of them with confidence as a style
    they are not; their states are far from its training streams'."""
    edges = np.array(FAMILIAR_EDGES, np.int64)
    groups = len(edges) + 1
    y = [model.states(x[None])[0].double().numpy() for x, _ in streams]
    Y, S = np.concatenate(y), np.concatenate([np.full(len(v), s) for v, (_, s) in zip(y, streams)])
    G = np.searchsorted(edges, np.concatenate([np.arange(len(v)) for v in y]), "right")
    means = np.zeros((groups, model.n_styles, model.hidden))
    for g, s in set(zip(G.tolist(), S.tolist())):
        means[g, s] = Y[(G == g) & (S == s)].mean(0)
    R = Y - means[G, S]
    covariance = R.T @ R / len(R) + 1e-3 * np.eye(model.hidden)  # a state unit that never moves stays invertible
    whiten = np.linalg.cholesky(np.linalg.inv(covariance))
    # near and far placeholders: only the distances are read here
    f = Familiarity(edges, *(a.astype(np.float32) for a in (whiten, means @ whiten, np.zeros(groups), np.ones(groups))))
    frames = np.concatenate([np.arange(len(x)) for x in validation])
    states = np.concatenate([model.states(x[None])[0].numpy() for x in validation])
    distance = np.empty(len(states))
    familiarity(states, frames, f, distance)
    at = np.searchsorted(edges, frames, "right")
    f.near, f.far = (
        np.array([np.percentile(distance[at == g], q) for g in range(groups)], np.float32) for q in percentiles
    )
    return f


def augmented_clips(
    fs: FeatureSet,
    data: TrainingData,
    clips: np.ndarray,
    copies: int,
    reference_pose: np.ndarray,
    seed: int,
    progress: bool = True,
) -> tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
    """``copies`` other-performer versions of every clip: (normalised frames ``[N, D]``, clip
    starts ``[C + 1]``, style and content index per clip)."""
    rng = np.random.default_rng(seed + 1)
    frames, starts, styles, contents = [], [0], [], []
    for c in tqdm(np.repeat(clips, copies), desc="other performers", disable=not progress, leave=False):
        motion, content = other_performer(fs.motion(int(c)), str(fs.contents[c]), reference_pose, rng)
        frames.append(data.stats.normalize(motion_features(motion)[0]).astype(np.float32))
        starts.append(starts[-1] + len(frames[-1]))
        styles.append(data.styles.index(fs.styles[c]))
        contents.append(data.contents.index(content))
    return torch.from_numpy(np.concatenate(frames)), np.array(starts), np.array(styles), np.array(contents)


def _joined(
    windows: tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray],
    clips: tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray],
    length: int,
    stride: int,
    repeats: int = 1,
) -> tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
    """Training windows (frames, window starts, style and content per window) with every
    ``length``-frame window of ``clips`` (frames, clip starts, style and content per clip)
    added, each ``repeats`` times."""
    frames, starts, style, content = windows
    extra, extra_start, extra_style, extra_content = clips
    more = np.tile(window_starts(extra_start, np.arange(len(extra_start) - 1), length, stride), repeats)
    clip = np.searchsorted(extra_start, more, side="right") - 1
    return (
        torch.cat([frames, extra]),
        np.concatenate([starts, more + len(frames)]),
        np.concatenate([style, extra_style[clip]]),
        np.concatenate([content, extra_content[clip]]),
    )


def labeller_loss(
    s_logits: torch.Tensor, c_logits: torch.Tensor, style: torch.Tensor, content: torch.Tensor, unsure: float
) -> torch.Tensor:
    """Cross-entropy of every frame's style and content (``[B, T, n]`` logits, ``[B]`` labels);
    a style of -1 (one the model does not have) is the cross-entropy to the uniform posterior,
    weighing ``unsure``; a content of -1 counts nothing."""
    T = s_logits.shape[1]
    style, content = style.repeat_interleave(T), content.repeat_interleave(T)
    s_logits, c_logits = s_logits.reshape(len(style), -1), c_logits.reshape(len(content), -1)
    known = style >= 0
    loss = F.cross_entropy(s_logits[known], style[known], reduction="sum")
    loss = loss - unsure * F.log_softmax(s_logits[~known], -1).mean(-1).sum()
    told = content >= 0
    return (
        loss + F.cross_entropy(c_logits[told], content[told], reduction="sum") * len(style) / max(1, int(told.sum()))
    ) / len(style)


def train_labeller(
    fs: FeatureSet,
    data: TrainingData,
    epochs: int = 6,
    length: int = 40,
    stride: int = 4,
    batch: int = 64,
    lr: float = 2e-3,
    seed: int = 0,
    max_clips: int = 0,
    progress: bool = True,
    copies: int = 2,
    reference_pose: np.ndarray | None = None,
    outside: tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray] | None = None,
    unsure: float = 0.5,
    outside_repeats: int = 5,
    start: OnlineLabeller | None = None,
    familiar: tuple[float, float] | tuple = TrainConfig.labeller_familiar,
) -> tuple[OnlineLabeller, dict]:
    """Train; keep the epoch whose validation streams are labelled best after 30 frames, and
    measure where its states are familiar (``fit_familiarity`` at the ``familiar`` percentiles,
    on the training streams; ``()``: not measured).
    ``copies`` other-performer versions of each training clip join the clips themselves
    (``reference_pose``: a natural pose of the skeleton, for mirroring; default its average), and
    so do the ``outside`` clips (``outside_clips``, each window ``outside_repeats`` times: they are
    few), those of a style the model does not have weighing ``unsure`` in a loss that makes their
    posterior uniform. With ``start``, its weights start the run (a fine-tuning)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = OnlineLabeller(data.frames.shape[1], len(data.styles), len(data.contents))
    if start is not None:
        model.load_state_dict(start.state_dict())
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    ws = windows(fs, data, "train", stride, max_clips)
    idx = torch.as_tensor(ws.starts[:, None] + np.arange(length))
    ok = (idx[:, -1] < torch.as_tensor(fs.clip_start[ws.clip + 1])).numpy()  # whole stretch inside its clip
    starts, style, content = ws.starts[ok], ws.style[ok], ws.content[ok]
    frames = data.frames
    streams = [(data.frames[fs.frames(c)], data.styles.index(fs.styles[c])) for c in np.unique(ws.clip)]
    if copies:
        reference = data.stats.reference if reference_pose is None else reference_pose
        more = augmented_clips(fs, data, np.unique(ws.clip), copies, reference, seed, progress)
        frames, starts, style, content = _joined((frames, starts, style, content), more, length, stride)
        streams += [(more[0][a:b], int(s)) for a, b, s in zip(more[1][:-1], more[1][1:], more[2])]
    if outside is not None:
        frames, starts, style, content = _joined(
            (frames, starts, style, content), outside, length, stride, outside_repeats
        )
    style, content = torch.as_tensor(style), torch.as_tensor(content)
    best, best_score, history = copy.deepcopy(model), -1.0, []
    for epoch in range(epochs):
        model.train()
        order = rng.permutation(len(starts))
        bar = tqdm(
            range(0, len(order) - batch + 1, batch),
            desc=f"labeller {epoch + 1}/{epochs}",
            disable=not progress,
            leave=False,
        )
        for i in bar:
            b = order[i : i + batch]
            x = frames[torch.as_tensor(starts[b][:, None] + np.arange(length))]
            s_logits, c_logits, _ = model(x)
            loss = labeller_loss(s_logits, c_logits, style[b], content[b], unsure)
            opt.zero_grad()
            loss.backward()
            opt.step()
            bar.set_postfix(loss=f"{loss.item():.3f}")
        val = stream_accuracy(model, fs, data, "val")
        score = val[30]["style"] + val[30]["content"]
        history.append({"epoch": epoch + 1, "val": val})
        if score > best_score:
            best, best_score = copy.deepcopy(model), score
    report = {"history": history, "other_performer_copies": copies}
    if outside is not None:
        report["outside"] = {"clips": len(outside[1]) - 1, "unsure_weight": unsure, "repeats": outside_repeats}
    if familiar:
        validation = [data.frames[fs.frames(c)] for c in fs.clips("val")]
        best.familiar = fit_familiarity(best, streams, validation, familiar)
        report["familiar"] = {
            "percentiles": list(familiar),
            "edges": best.familiar.edges.tolist(),
            **{k: [round(float(v), 3) for v in getattr(best.familiar, k)] for k in ("near", "far")},
        }
    return best.eval(), report


def train_and_save(
    config: TrainConfig, data_dir: str | None = None, out: Path | None = None, progress: bool = True
) -> dict:
    """``styleerd train-labeller``: train on the config's dataset, report stream accuracy on
    the test split, save next to the shipped models (or at ``out``)."""
    p = config.labeller_familiar
    if p and not (len(p) == 2 and all(isinstance(v, (int, float)) for v in p) and 0 < p[0] < p[1] <= 100):
        raise StyleERDError(
            f"labeller_familiar must be two percentiles, the first below the second, or [] for none; got {list(p)}"
        )
    torch.set_num_threads(config.threads)
    s = setup(config, data_dir, progress)
    outside = outside_clips(s.fs, s.data, data_dir, progress) if config.labeller_outside else None
    start, start_meta = ckpt.load_labeller(config.labeller_init_from) if config.labeller_init_from else (None, {})
    model, report = train_labeller(
        s.fs,
        s.data,
        epochs=config.labeller_epochs,
        lr=config.labeller_lr,
        seed=config.seed,
        max_clips=config.max_train_clips,
        progress=progress,
        outside=outside,
        unsure=config.labeller_unsure,
        start=start,
        familiar=config.labeller_familiar,
    )
    if start is not None:
        report["started_from"] = config.labeller_init_from
        if not config.labeller_epochs:  # no epoch (familiarity only): the weights' own training record stays
            report["history"] = start_meta.get("history", [])
    report["test"] = stream_accuracy(model, s.fs, s.data, "test")
    report["test_leaning_neutral"] = stream_accuracy(model, s.fs, s.data, "test", neutral=config.neutral_style)
    meta = {
        "kind": "styleerd-labeller",
        "config": model.config(),
        "styles": s.data.styles,
        "contents": s.data.contents,
        "dataset": config.dataset,
        **report,
    }
    familiar = {} if model.familiar is None else {k: torch.from_numpy(v) for k, v in model.familiar.arrays().items()}
    ckpt.save_tensors(out or MODELS_DIR / LABELLER, {**ckpt.prefixed("labeller", model), **familiar}, meta)
    return report
