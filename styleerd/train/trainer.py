"""The adversarial training loop: plain PyTorch, resumable, deterministic, optionally
data-parallel over processes (``torchrun``, gloo on CPU).

Every step trains on a batch that is half neutral windows (each sent to a random other
style) and half styled windows (sent to neutral), plus the reconstruction of every window
into its own style; the critic sees the batch's real windows and the transfers.

Resuming: each epoch ends with an atomic checkpoint; every epoch's randomness is derived from
(seed, epoch), so a run killed at any point and restarted with the same command continues
from the last finished epoch and ends with the same weights as an uninterrupted run.
"""

from __future__ import annotations

import copy
import csv
import io
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from tqdm import tqdm

from styleerd.atomic import atomic_write_text
from styleerd.data.cache import CODE_VERSION, FeatureSet, prepare
from styleerd.data.datasets import file_digest
from styleerd.data.features import FeatureLayout
from styleerd.errors import StyleERDError
from styleerd.model import checkpoint as ckpt
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.discriminator import Discriminator
from styleerd.model.fmd import MotionAutoencoder
from styleerd.model.generator import GeneratorConfig, StyleERD
from styleerd.models import MODELS_DIR, RECOGNISERS
from styleerd.train import losses
from styleerd.train.batches import (
    OutsideWindows,
    TrainingData,
    WindowSet,
    outside_contents,
    outside_windows,
    training_data,
    windows,
)
from styleerd.train.classifiers import accuracy, train_classifier
from styleerd.train.config import TrainConfig
from styleerd.train.validation import realism_margin, transfer_quality, transfers, validate

# what --export writes: the best validation epoch by SRA + CRA, the last epoch (a fixed budget),
# or the validation epoch most realistic in its worst target style (train.validation.realism_margin)
KEEP = ("best", "last", "realistic")


@dataclass
class Setup:
    fs: FeatureSet
    data: TrainingData
    train: WindowSet
    val: WindowSet
    outside: OutsideWindows | None = None  # other performers' windows (``outside_batch``)


def setup(config: TrainConfig, data_dir: str | None, progress: bool = True) -> Setup:
    fs = prepare(config.dataset, data_dir, progress=progress)
    data = training_data(fs, config.window)
    if config.neutral_style not in data.styles:
        raise StyleERDError(f"neutral style {config.neutral_style!r} not in {data.styles}")
    train = windows(fs, data, "train", config.stride, config.max_train_clips)
    val = windows(fs, data, "val", config.window, config.max_train_clips)
    keep = np.linspace(0, len(val.starts) - 1, min(config.val_windows, len(val.starts))).astype(int)
    val = WindowSet(val.starts[keep], val.style[keep], val.content[keep], val.clip[keep])
    return Setup(fs, data, train, val)


def make_generator(config: TrainConfig, s: Setup) -> StyleERD:
    gc = GeneratorConfig(
        n_joints=s.fs.skeleton.n_joints,
        styles=tuple(s.data.styles),
        contents=tuple(s.data.contents),
        neutral_style=config.neutral_style,
        encoder=config.encoder,
        hidden=config.hidden,
        neutral_layers=config.neutral_layers,
        style_layers=config.style_layers,
        decoder=config.decoder,
        learned_init=config.learned_init,
        pose_change=config.pose_change,
    )
    return StyleERD(gc, s.fs.skeleton, s.data.stats)


def _resumable(config: dict) -> dict:
    """What must match to resume a run: everything but how long it may go on, on how many
    threads (a run may go on faster once the machine is free), which epoch it exports, and
    where its weights started (the checkpoint holds them once a run has one), and on which device
    (a run started on a GPU may go on on the CPU)."""
    return {
        k: v for k, v in config.items() if k not in ("epochs", "max_minutes", "threads", "device", "keep", "init_from")
    }


def _check_in_sync(model: torch.nn.Module) -> None:
    """Data-parallel processes must hold identical weights after every epoch."""
    if not dist.is_initialized():
        return
    total = torch.stack([p.detach().double().sum() for p in model.parameters()]).sum().reshape(1)
    gathered = [torch.zeros_like(total) for _ in range(dist.get_world_size())]
    dist.all_gather(gathered, total)
    if any(not torch.equal(g, gathered[0]) for g in gathered):
        raise StyleERDError(f"data-parallel processes diverged: weight sums {[g.item() for g in gathered]}")


def _is_main() -> bool:
    return not dist.is_initialized() or dist.get_rank() == 0


def _average_gradients(params: list[torch.nn.Parameter]) -> None:
    """Data parallelism by hand: every process gets the mean gradient (no DDP wrapper, so the
    R1 double backward and branches that sometimes do not run need no special care)."""
    if not dist.is_initialized():
        return
    for p in params:
        if p.grad is None:
            p.grad = torch.zeros_like(p)
    flat = torch.cat([p.grad.reshape(-1) for p in params])  # one message, not one per tensor (each costs a round trip)
    dist.all_reduce(flat)
    flat /= dist.get_world_size()
    for p, mean in zip(params, flat.split([p.numel() for p in params])):
        p.grad.copy_(mean.view_as(p.grad))


def _perceptual_classifier(config: TrainConfig, s: Setup, out: Path, progress: bool) -> WindowClassifier:
    """The InstanceNorm content classifier, trained once per run directory."""
    stem = out / "content_classifier"
    if stem.with_suffix(".safetensors").is_file():
        tensors, meta = ckpt.load_tensors(stem)
        model = ckpt.build_classifier(meta)
        model.load_state_dict(ckpt.unprefixed("classifier", tensors))
        return model.eval().to(config.device)
    cls_train = windows(s.fs, s.data, "train", config.classifier_stride, config.max_train_clips)
    layout = FeatureLayout(s.fs.skeleton.n_joints)
    motion = slice(0, layout.velocities.stop)  # rotations, positions, velocities (paper)
    model, acc = train_classifier(
        s.data,
        cls_train,
        s.val,
        "content",
        True,
        motion,
        config.classifier_epochs,
        config.classifier_lr,
        config.seed,
        progress=progress,
        device=config.device,
    )
    if _is_main():
        ckpt.save_tensors(
            stem, ckpt.prefixed("classifier", model), ckpt.classifier_meta(model, s.data.contents, val_accuracy=acc)
        )
    return model


def _recognisers(s: Setup, stem: Path | None = None) -> tuple[WindowClassifier | None, WindowClassifier | None]:
    """The evaluation recognisers (default: the shipped ones), when they fit this data's labels."""
    try:
        style, content, meta = ckpt.load_recognisers(stem)
    except StyleERDError:
        return None, None
    if meta["style"]["labels"] != s.data.styles or meta["content"]["labels"] != s.data.contents:
        return None, None
    layout = FeatureLayout(s.fs.skeleton.n_joints)
    if meta["style"].get("first_channel", 0) + meta["style"]["in_dim"] > layout.velocities.stop:
        return None, None
    return style, content


def _state(
    G: StyleERD, D: Discriminator, opt_g: torch.optim.Optimizer, opt_d: torch.optim.Optimizer, G_avg: StyleERD | None
) -> dict[str, torch.Tensor]:
    tensors = {**ckpt.prefixed("generator", G), **ckpt.prefixed("discriminator", D)}
    if G_avg is not None:
        tensors.update(ckpt.prefixed("average", G_avg))
    for name, opt in (("opt_g", opt_g), ("opt_d", opt_d)):
        for i, st in opt.state_dict()["state"].items():
            for k, v in st.items():
                tensors[f"{name}.{i}.{k}"] = v if torch.is_tensor(v) else torch.tensor(v)
    return tensors


def _load_state(
    tensors: dict,
    G: StyleERD,
    D: Discriminator,
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer,
    G_avg: StyleERD | None,
) -> None:
    G.load_state_dict(ckpt.unprefixed("generator", tensors))
    D.load_state_dict(ckpt.unprefixed("discriminator", tensors))
    if G_avg is not None:
        G_avg.load_state_dict(ckpt.unprefixed("average", tensors))
    for name, opt in (("opt_g", opt_g), ("opt_d", opt_d)):
        sd = opt.state_dict()
        state: dict[int, dict] = {}
        for key, v in ckpt.unprefixed(name, tensors).items():
            i, k = key.split(".", 1)
            state.setdefault(int(i), {})[k] = v
        sd["state"] = state
        opt.load_state_dict(sd)


def update_average(G_avg: StyleERD, G: StyleERD, decay: float) -> None:
    """An exponential moving average of the generator's weights (``ema``): it smooths the
    step-to-step wander of adversarial training (Yazici et al. 2019)."""
    with torch.no_grad():
        for avg, p in zip(G_avg.parameters(), G.parameters()):
            avg.lerp_(p, 1.0 - decay)


def critic_channels(config: TrainConfig, layout: FeatureLayout) -> slice:
    """The motion channels the critic reads: joint positions and velocities (the paper), and
    with ``critic_rotations`` the joint rotations too."""
    return slice(0 if config.critic_rotations else layout.positions.start, layout.velocities.stop)


def make_critic(config: TrainConfig, s: Setup) -> Discriminator:
    seen = critic_channels(config, FeatureLayout(s.fs.skeleton.n_joints))
    return Discriminator(
        seen.stop - seen.start, len(s.data.styles), len(s.data.contents), config.window, attention=config.attention
    )


def make_optimisers(config: TrainConfig, G: StyleERD, D: Discriminator) -> tuple[torch.optim.Adam, torch.optim.Adam]:
    """Adam for the generator's trainable weights and for the critic's (the fused kernel: one
    pass over every weight, not a dozen small ops per tensor)."""
    return (
        torch.optim.Adam(
            [p for p in G.parameters() if p.requires_grad], lr=config.lr_g, betas=(0.5, 0.999), fused=True
        ),
        torch.optim.Adam(D.parameters(), lr=config.lr_d, betas=(0.5, 0.999), fused=True),
    )


def train_step(
    G: StyleERD,
    D: Discriminator,
    opt_g: torch.optim.Optimizer,
    opt_d: torch.optim.Optimizer,
    per_classifier: WindowClassifier | None,
    config: TrainConfig,
    s: Setup,
    rows: np.ndarray,
    target: np.ndarray,
    step: int,
    tick=lambda part: None,
    outside: tuple[np.ndarray, np.ndarray] | None = None,
    start: StyleERD | None = None,
) -> dict[str, float]:
    """One optimisation step of the generator, then of the critic, on the training windows
    ``rows`` sent to the styles ``target``, and with ``outside`` (rows of ``s.outside``, content
    weights ``[n, C]``) the reconstruction of other performers' windows, and with ``start`` (the
    frozen model a fine-tune started from) the transfers kept near its own; returns the losses it
    computed. ``tick(part)`` is called as each part of the step ends (benchmarks/bench_train_step.py
    times them)."""
    B, J, L, dev = len(rows), G.config.n_joints, G.layout, G.mean.device
    seen = critic_channels(config, L)
    x = s.data.gather(s.train.starts[rows]).to(dev)
    style, content = (
        s.data.onehot_style(s.train.style[rows]).to(dev),
        s.data.onehot_content(s.train.content[rows]).to(dev),
    )
    tgt = s.data.onehot_style(target).to(dev)
    real = x[..., : 10 * J]
    tick("batch gather")

    # ---- generator: reconstruction (own style) and transfer of one batch, its encoding shared
    rot, vel = G.forward_targets(x, style, content, torch.cat([style, tgt]))
    tick("generator forward (B + B)")
    ch = G.motion_channels(rot, vel)
    rot_in = G.raw_rotations(x)
    tick("forward kinematics + channels")
    loss_rec = losses.reconstruction_loss(rot[:B], rot_in, ch[:B], real, L)
    loss_g = config.w_rec * loss_rec
    fake = ch[B:]
    logs = {"rec": loss_rec.item()}
    if config.use_adv:
        D.requires_grad_(False)  # the generator's step needs D's gradient to its input only, not to D's weights
        loss_adv = losses.generator_adversarial(D(fake[..., seen], tgt, content))
        loss_g = loss_g + config.w_adv * loss_adv
        logs["adv"] = loss_adv.item()
    if config.use_per or config.w_cls:
        fake_maps = per_classifier.feature_maps(fake)  # one pass of the frozen classifier for both losses
    if config.use_per:
        loss_per = losses.perceptual(per_classifier, real, fake_maps)
        loss_g = loss_g + config.w_per * loss_per
        logs["per"] = loss_per.item()
    if config.w_cls:
        loss_cls = losses.content_classification(
            per_classifier, fake_maps, torch.from_numpy(s.train.content[rows]).long().to(dev)
        )
        loss_g = loss_g + config.w_cls * loss_cls
        logs["cls"] = loss_cls.item()
    if start is not None:
        with torch.no_grad():
            rot_s, vel_s = start.forward_targets(x, style, content, tgt)
            ch_s = start.motion_channels(rot_s, vel_s)
        loss_keep = losses.reconstruction_loss(rot[B:], rot_s, fake, ch_s, L)
        loss_g = loss_g + config.w_keep * loss_keep
        logs["keep"] = loss_keep.item()
    tick("generator losses")
    if config.w_cyc and step % config.cyc_every == 0:
        # the transfer taken back to the input's style must give the input again:
        # whatever the style branch adds has to leave the content recoverable
        back = torch.cat([fake, x[..., L.contacts]], -1)
        rot_c, vel_c, _ = G(back, tgt, content, style)
        loss_cyc = losses.reconstruction_loss(rot_c, rot_in, G.motion_channels(rot_c, vel_c), real, L)
        loss_g = loss_g + config.w_cyc * config.cyc_every * loss_cyc
        logs["cyc"] = loss_cyc.item()
        tick("cycle pass + loss")
    if outside is not None:
        # actions the data lacks, told a content that is not theirs: rebuilt as they are
        o_rows, o_content = outside
        xo = s.outside.gather(o_rows, config.window).to(dev)
        own = s.data.onehot_style(s.outside.style[o_rows]).to(dev)
        rot_o, vel_o, _ = G(xo, own, torch.from_numpy(o_content).float().to(dev), own)
        loss_o = losses.reconstruction_loss(
            rot_o, G.raw_rotations(xo), G.motion_channels(rot_o, vel_o), xo[..., : 10 * J], L
        )
        loss_g = loss_g + config.w_outside * loss_o
        logs["outside"] = loss_o.item()
        tick("outside reconstruction")
    opt_g.zero_grad(set_to_none=True)
    loss_g.backward()
    _average_gradients([p for p in G.parameters() if p.requires_grad])
    opt_g.step()
    tick("generator backward + Adam")

    # ---- critic
    if config.use_adv:
        D.requires_grad_(True)
        d_real = D(real[..., seen], style, content)
        d_fake = D(fake.detach()[..., seen], tgt, content)
        loss_d = losses.critic(d_real, d_fake)
        logs["critic"] = loss_d.item()
        if config.r1_every and step % config.r1_every == 0:
            r1 = losses.r1_penalty(D, real[..., seen], style, content)
            loss_d = loss_d + config.w_gp * config.r1_every * r1
            logs["r1"] = r1.item()
        opt_d.zero_grad(set_to_none=True)
        loss_d.backward()
        _average_gradients(list(D.parameters()))
        opt_d.step()
        tick("critic step (+ R1 on its steps)")
    return logs


def train(
    config: TrainConfig, out: Path, data_dir: str | None = None, progress: bool = True, export: Path | None = None
) -> dict:
    """Train (or resume) in ``out``; returns the best validation metrics. With ``export``,
    the best generator (``keep`` "last": the final one) is also written there as a
    self-contained model."""
    torch.set_num_threads(config.threads)
    if config.keep not in KEEP:
        raise StyleERDError(f"keep must be one of {KEEP}, got {config.keep!r}")
    if not 0.0 <= config.ema < 1.0:
        raise StyleERDError(f"ema must be a decay in [0, 1), got {config.ema!r}")
    try:
        device = torch.device(config.device)
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as e:
        raise StyleERDError(f"device {config.device!r} cannot be used here: {e}") from None
    grouped = int(os.environ.get("WORLD_SIZE", "1")) > 1 and not dist.is_initialized()
    if grouped:
        dist.init_process_group("gloo")
    try:
        return _train_in_group(config, out, data_dir, progress, export)
    finally:
        if grouped:  # left to the interpreter's exit, Gloo's threads can abort it (SIGABRT after the run)
            dist.destroy_process_group()


def _train_in_group(config: TrainConfig, out: Path, data_dir: str | None, progress: bool, export: Path | None) -> dict:
    rank = dist.get_rank() if dist.is_initialized() else 0
    world = dist.get_world_size() if dist.is_initialized() else 1
    progress = progress and rank == 0
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = setup(config, data_dir, progress)
    if config.outside_batch:
        neutral = s.data.styles.index(config.neutral_style) if config.outside_neutral else None
        s.outside = outside_windows(
            s.fs,
            s.data,
            config.stride,
            data_dir,
            progress,
            neutral=neutral,
            in_place=config.outside_in_place,
            turns_in_place=config.outside_turns_in_place,
        )
    torch.manual_seed(config.seed)
    G = make_generator(config, s).to(config.device)
    D = make_critic(config, s).to(config.device)
    opt_g, opt_d = make_optimisers(config, G, D)
    style_rec, content_rec = _recognisers(s)
    realism = _realism_judges(config, s, style_rec) if config.keep == "realistic" else None
    per_classifier = _perceptual_classifier(config, s, out, progress) if config.use_per or config.w_cls else None
    if per_classifier is not None:
        per_classifier.requires_grad_(False)

    # ---- resume
    state_stem = out / "checkpoint"
    epoch0, elapsed, best = 0, 0.0, None
    resuming = state_stem.with_suffix(".safetensors").is_file()
    if config.init_from and not resuming:  # once a run has a checkpoint, the weights come from it
        _start_from(G, config.init_from)
    start = _frozen_start(config, G) if config.w_keep else None
    G_avg = copy.deepcopy(G).requires_grad_(False) if config.ema else None  # what is validated and exported
    if resuming:
        tensors, meta = ckpt.load_tensors(state_stem)
        if _resumable(TrainConfig.from_dict(meta["config"]).to_dict()) != _resumable(
            config.to_dict()
        ):  # fields added since default
            raise StyleERDError(f"{out} holds a run with another config; use a new --out or delete it")
        _load_state(tensors, G, D, opt_g, opt_d, G_avg)
        epoch0, elapsed, best = meta["epoch"], meta["elapsed_s"], meta.get("best")
        if progress:
            print(f"resuming {out} after epoch {epoch0} ({elapsed / 60:.1f} min trained)")
    G_eval = G_avg if G_avg is not None else G

    neutral = G.config.neutral_index
    n_styles = len(s.data.styles)
    is_neutral = s.train.style == neutral
    neutral_rows, styled_rows = np.nonzero(is_neutral)[0], np.nonzero(~is_neutral)[0]
    B = config.batch_size
    half = B // 2
    steps = len(s.train.starts) // (B * world)
    others = np.array([t for t in range(n_styles) if t != neutral])
    by_style = [rows for rows in (np.nonzero(s.train.style == t)[0] for t in others) if len(rows)]
    metrics_path = out / "metrics.csv"

    done = epoch0  # epochs finished
    for epoch in range(epoch0, config.epochs):
        if config.max_minutes and elapsed >= config.max_minutes * 60:
            break
        t0 = time.perf_counter()
        rng = np.random.default_rng([config.seed, epoch, rank])
        torch.manual_seed(config.seed * 100_003 + epoch * 101 + rank)
        G.train()
        D.train()
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        bar = tqdm(range(steps), desc=f"epoch {epoch + 1}/{config.epochs}", disable=not progress, leave=False)
        for step in bar:
            if config.balance_styles:
                styled = np.array([rng.choice(by_style[k]) for k in rng.integers(0, len(by_style), B - half)])
            else:
                styled = rng.choice(styled_rows, B - half)
            rows = np.concatenate([rng.choice(neutral_rows, half), styled])
            target = np.where(s.train.style[rows] == neutral, rng.choice(others, B), neutral)
            outside = None
            if s.outside is not None:
                o_rows = rng.integers(0, len(s.outside.starts), config.outside_batch)
                outside = (
                    o_rows,
                    outside_contents(
                        s.outside.content[o_rows], len(s.data.contents), config.outside_known_content, rng
                    ),
                )
            logs = train_step(
                G, D, opt_g, opt_d, per_classifier, config, s, rows, target, step, outside=outside, start=start
            )
            if G_avg is not None:
                update_average(G_avg, G, config.ema)
            for k, v in logs.items():  # the mean of each loss over the steps that computed it
                sums[k] = sums.get(k, 0.0) + v
                counts[k] = counts.get(k, 0) + 1
            bar.set_postfix({k: f"{v:.3f}" for k, v in logs.items()})
        elapsed += time.perf_counter() - t0

        # ---- end of epoch: validate, log, checkpoint (main process only)
        row = {"epoch": epoch + 1, "steps": (epoch + 1) * steps, "minutes": round(elapsed / 60, 3)}
        row.update({f"loss_{k}": round(v / counts[k], 5) for k, v in sums.items()})
        if (epoch + 1) % config.val_every == 0 or epoch + 1 == config.epochs:
            judged = copy.deepcopy(G_eval).cpu()  # the judges and the data stay on the CPU
            row.update({k: round(v, 4) for k, v in validate(judged, s.data, s.val, style_rec, content_rec).items()})
            if realism is not None:
                fmd, val_all = realism
                row.update(
                    realism_margin(transfer_quality(judged, s.data, val_all, style_rec, content_rec, fmd, resamples=0))
                )
        if _is_main():
            score = _score(row, config.keep)
            if score is not None and (best is None or score > best["score"]):
                best = {"score": score, **row}
                ckpt.save_tensors(
                    out / "best", ckpt.prefixed("generator", G_eval), _model_meta(G_eval, s, config, best)
                )
            _append_csv(metrics_path, row)
            ckpt.save_tensors(
                state_stem,
                _state(G, D, opt_g, opt_d, G_avg),
                {"config": config.to_dict(), "epoch": epoch + 1, "elapsed_s": elapsed, "best": best},
                sidecar=False,
            )
            if progress:
                print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
        _check_in_sync(G)
        _check_in_sync(D)
        done = epoch + 1

    if _is_main() and export is not None and (config.keep == "last" or (out / "best.json").is_file()):
        if config.keep == "last":
            tensors, meta = ckpt.prefixed("generator", G_eval), _model_meta(G_eval, s, config, best)
            meta["training"]["kept"] = f"the last epoch ({done}), not the best validation epoch" + (
                f"; its weights' moving average (decay {config.ema})" if config.ema else ""
            )
        else:
            tensors, meta = ckpt.load_tensors(out / "best")
            if config.keep == "realistic":
                meta["training"]["kept"] = (
                    f"epoch {meta['training']['best']['epoch']} of {done}: the validation epoch whose worst target "
                    "style is furthest inside the realism bars"
                )
        meta["training"]["wall_minutes"] = round(elapsed / 60, 2)
        meta["training"]["epochs_trained"] = done  # the run's budget (its ablations train as many)
        if config.init_from:  # a fine-tuning stage: the training of the model it started from
            meta["training"]["started_from"] = {
                "model": config.init_from,
                "training": ckpt.load_generator(config.init_from)[1]["training"],
            }
        ckpt.save_tensors(export, tensors, meta)
    return best or {}


def _saved_start(G: StyleERD, stem: str) -> StyleERD:
    """The saved generator a fine-tune of ``G`` starts from, as saved; it must have ``G``'s
    architecture and data, but for one difference: a ``pose_change`` run may start from a model
    without it (not the other way)."""
    start, _ = ckpt.load_generator(stem)
    if {
        **start.config.to_dict(),
        "pose_change": start.config.pose_change or G.config.pose_change,
    } != G.config.to_dict():
        raise StyleERDError(f"init_from {stem}: its generator config differs from this run's")
    return start


def _start_from(G: StyleERD, stem: str) -> None:
    """Fine-tuning: the generator starts from a saved one (``_saved_start``). A ``pose_change``
    run from a model without it: the decoder's last layer then says "no change" for every joint
    (its rotation rows zero, their bias the identity), so the run starts from the input's own pose
    and the rest of the network as it was."""
    start = _saved_start(G, stem)
    G.load_state_dict(start.state_dict())
    if G.config.pose_change and not start.config.pose_change:
        G.start_at_no_change()


def _frozen_start(config: TrainConfig, G: StyleERD) -> StyleERD:
    """``w_keep``'s reference: the model the fine-tune started from, as saved and frozen (a
    resumed run's ``G`` holds the checkpoint's weights, a ``pose_change`` run's decoder no longer
    the start's)."""
    if not config.init_from:
        raise StyleERDError("w_keep keeps a fine-tune near the model it starts from: it needs init_from")
    return _saved_start(G, config.init_from).to(config.device).requires_grad_(False).eval()


def _realism_judges(
    config: TrainConfig, s: Setup, style_rec: WindowClassifier | None
) -> tuple[MotionAutoencoder, WindowSet]:
    """keep "realistic" judges realism per target style with the shipped FMD extractor and
    recognisers, on every validation window of every clip (FMD per style needs more than the
    quick subset, and than a tiny run's ``max_train_clips``)."""
    fmd, _ = ckpt.load_fmd()
    if style_rec is None or fmd.n_joints != s.fs.skeleton.n_joints:
        raise StyleERDError(
            f"keep: realistic needs the shipped recognisers and FMD extractor, which do not fit {config.dataset}"
        )
    return fmd, windows(s.fs, s.data, "val", config.window)


def _score(row: dict, keep: str) -> float | None:
    """Model selection. keep "realistic": the worst target style's margin inside both realism
    bars (``realism_margin``). Otherwise style and content recognition of transfers when
    recognisers exist, else (lower) reconstruction error."""
    if keep == "realistic":
        return row.get("realism_margin")
    if "sra" in row:
        return row["sra"] + row["cra"]
    if "rec_deg" in row:
        return -row["rec_deg"]
    return None


def _model_meta(G: StyleERD, s: Setup, config: TrainConfig, best: dict) -> dict:
    archive = (
        Path(s.fs.meta["data"]) / f"{config.dataset}.tar.xz" if "data" in s.fs.meta else None
    )  # where it was prepared from
    return ckpt.generator_meta(
        G,
        s.fs.skeleton,
        s.data.stats,
        code_version=CODE_VERSION,
        data={
            "dataset": config.dataset,
            "sha256": file_digest(archive) if archive is not None and archive.is_file() else None,
            "fps": s.fs.params.fps,
        },
        training={"config": config.to_dict(), "best": best},
    )


def _append_csv(path: Path, row: dict) -> None:
    """Add (or, after a resume, replace) an epoch's row."""
    rows = []
    if path.is_file():
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f) if int(r["epoch"]) < row["epoch"]]
    rows.append(row)
    buf = io.StringIO()
    w = csv.DictWriter(buf, list(dict.fromkeys(k for r in rows for k in r)))
    w.writeheader()
    w.writerows(rows)
    atomic_write_text(path, buf.getvalue())


def train_recognisers(
    config: TrainConfig, data_dir: str | None = None, out: Path | None = None, progress: bool = True
) -> dict:
    """Train the evaluation style and content recognisers on real training windows, select on
    validation, report accuracy on real test windows (the ceiling of SRA / CRA)."""
    torch.set_num_threads(config.threads)
    s = setup(config, data_dir, progress)
    cls_train = windows(s.fs, s.data, "train", config.classifier_stride, config.max_train_clips)
    test = windows(s.fs, s.data, "test", config.window, config.max_train_clips)
    layout = FeatureLayout(s.fs.skeleton.n_joints)
    visible = slice(layout.positions.start, layout.velocities.stop)  # joint positions + velocities
    report, tensors, meta = {}, {}, {}
    for label, labels in (("style", s.data.styles), ("content", s.data.contents)):
        model, val_acc = train_classifier(
            s.data,
            cls_train,
            s.val,
            label,
            False,
            visible,
            config.classifier_epochs,
            config.classifier_lr,
            config.seed,
            progress=progress,
        )
        test_acc = accuracy(model, s.data, test, label)
        report[label] = {
            "val_accuracy": round(val_acc, 4),
            "test_accuracy": round(test_acc, 4),
            "test_windows": len(test.starts),
        }
        tensors.update(ckpt.prefixed(label, model))
        meta[label] = ckpt.classifier_meta(model, labels, **report[label])
    meta["feature_stats"] = s.data.stats.to_dict()
    meta["dataset"] = config.dataset
    ckpt.save_tensors(out or MODELS_DIR / RECOGNISERS, tensors, meta)
    return report


def evaluate(
    model_stem: Path | None = None,
    data_dir: str | None = None,
    split: str = "test",
    progress: bool = True,
    recognisers: Path | None = None,
) -> dict:
    """The acceptance figures of a generator on real ``split`` windows: reconstruction error,
    SRA and CRA of its transfers, next to the recognisers' accuracy on the real windows."""
    model, meta = ckpt.load_generator(model_stem)
    config = TrainConfig.from_dict(meta["training"]["config"], where=f"training config of {model_stem}")
    s = setup(config, data_dir, progress)
    ws = windows(s.fs, s.data, split, config.window)
    style_rec, content_rec = _recognisers(s, recognisers)
    if style_rec is None:
        raise StyleERDError("evaluation recognisers for this dataset are missing: run `styleerd train-recognisers`")
    result = validate(model, s.data, ws, style_rec, content_rec)
    ceiling = {
        "style": accuracy(style_rec, s.data, ws, "style"),
        "content": accuracy(content_rec, s.data, ws, "content"),
    }
    hits: dict[int, np.ndarray] = {}  # per target style: [style hits, content hits, transfers]
    with torch.no_grad():
        for r, t, _, _, ch in transfers(model, s.data, ws):
            ok_s, ok_c = style_rec(ch).argmax(-1).numpy() == t, content_rec(ch).argmax(-1).numpy() == ws.content[r]
            for k in np.unique(t):
                hits.setdefault(int(k), np.zeros(3))[:] += (ok_s[t == k].sum(), ok_c[t == k].sum(), (t == k).sum())
    return {
        "split": split,
        "windows": len(ws.starts),
        "style_ceiling": round(ceiling["style"], 4),
        "content_ceiling": round(ceiling["content"], 4),
        "sra": round(result["sra"], 4),
        "cra": round(result["cra"], 4),
        "sra_of_ceiling": round(result["sra"] / ceiling["style"], 4),
        "cra_of_ceiling": round(result["cra"] / ceiling["content"], 4),
        "rec_deg": round(result["rec_deg"], 3),
        "rec_cm": round(result["rec_cm"], 3),
        "training_minutes": meta["training"].get("wall_minutes"),
        "config": meta["training"]["config"]["name"],
        "per_target": {
            s.data.styles[k]: {"sra": round(h[0] / h[2], 4), "cra": round(h[1] / h[2], 4), "transfers": int(h[2])}
            for k, h in sorted(hits.items())
        },
    }
