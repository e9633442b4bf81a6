"""A new style from a few clips of it (``styleerd add-style``): one more residual branch, with
its learned initial state and its row of the decoder's target input, trained against a
critic while everything the model already had stays frozen, so every old target's output is
bit-identical (``StyleERD.decode`` keeps added styles' rows apart).

The same losses as training: an FT-Att critic (the new clips are its real windows, neutral
training windows sent to the new style its fakes; the base model's critic is training state
and is not shipped, so a fresh one is trained for the style alone, conditioned on content and
reading the channels the model's own critic read),
the content perceptual loss between each neutral window and its transfer (with the content
cross-entropy of the shipped recipe), and the
reconstruction of the new clips themselves in their style (labelled as the online labeller
reads them, as ``transfer`` does).

The encoder and the neutral branch are frozen, so their outputs for every window are
computed once; a step runs only the new branch, the decoder, forward kinematics and the critic.
"""

from __future__ import annotations

import re
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from styleerd.data.datasets import cache_dir
from styleerd.data.features import motion_features
from styleerd.data.windows import gather_windows
from styleerd.errors import StyleERDError, unknown_name
from styleerd.model import checkpoint as ckpt
from styleerd.model.discriminator import Discriminator
from styleerd.model.generator import StyleERD
from styleerd.model.stored import generator_weights, labeller_stem, toward_neutral
from styleerd.motion.gltf import read_motion
from styleerd.motion.resample import resample
from styleerd.motion.retarget import joint_map, to_target
from styleerd.train import losses
from styleerd.train.config import TrainConfig
from styleerd.train.trainer import _perceptual_classifier, critic_channels, setup

MAX_CLIPS = 20
NAME = re.compile(r"[a-z][a-z0-9_-]{0,31}")


@dataclass(frozen=True)
class AddStyleConfig:
    steps: int = 1200
    max_minutes: float = 8.0  # stop early when training has taken this long
    batch_size: int = 32
    lr_g: float = 5e-4
    lr_d: float = 2e-4
    w_rec: float = 1.0
    w_adv: float = 1.0
    w_per: float = 1.0
    w_cls: float = 0.5  # content cross-entropy of the perceptual classifier on transfers, as the shipped recipe
    w_gp: float = 128.0
    r1_every: int = 4
    stride: int = 2  # between windows of the new clips (few clips: every other frame starts one)
    content_stride: int = 20  # between neutral content windows
    seed: int = 0
    threads: int = 2
    # the critic reads joint rotations too (None: as the model's own recipe did; on the shipped
    # model, docs/RESULTS.md: rotations lower FMD, 0.59 against 0.77 over nine unseen styles)
    critic_rotations: bool | None = None


DEFAULT_CONFIG = AddStyleConfig()


@dataclass
class StyleClips:
    """The new style's clips on the model's skeleton, as windows: normalised features
    ``x [N, T, D]``, and the labels the online labeller reads them as (input style over the
    model's input styles, content probabilities)."""

    x: torch.Tensor
    style: torch.Tensor
    content: torch.Tensor
    names: list[str]
    frames: int


def style_clips(
    paths: list[str | Path],
    model,
    window: int,
    stride: int,
    contents: list[str] | None = None,
    explicit_map: dict[str, str] | None = None,
) -> StyleClips:
    """Read, retarget (as ``transfer`` does) and resample the clips to the model's skeleton and
    rate, then cut them into windows. ``contents``: one content per clip, or one for all
    (default: inferred by the online labeller, as the clip's average)."""
    weights = generator_weights(model)
    c, stats = weights.config, weights.stats()
    fps = float(weights.meta.get("data", {}).get("fps") or 30.0)
    if not 1 <= len(paths) <= MAX_CLIPS:
        raise StyleERDError(f"give from 1 to {MAX_CLIPS} clips of the new style, not {len(paths)}")
    if contents is not None:
        if len(contents) not in (1, len(paths)):
            raise StyleERDError(f"give one --content for every clip ({len(paths)}) or one for all, not {len(contents)}")
        for name in contents:
            if name not in c.contents:
                raise unknown_name("--content", name, c.contents)
        contents = contents * len(paths) if len(contents) == 1 else contents
    labeller, _ = ckpt.load_labeller(labeller_stem(c))
    xs, styles, cont, total = [], [], [], 0
    for i, path in enumerate(paths):
        motion = read_motion(path)
        if not 10 <= motion.fps <= 480:
            raise StyleERDError(f"{path}: {motion.fps:.6g} fps is outside [10, 480]")
        if not np.isfinite(motion.rotations).all() or not np.isfinite(motion.positions).all():
            raise StyleERDError(f"{path}: the motion has NaN or infinite values")
        try:  # as transfer maps a skeleton (runtime.offline.map_skeleton)
            jm = joint_map(weights.skeleton, motion.skeleton, explicit_map, stats.reference, motion.rotations[0])
        except ValueError as e:
            raise StyleERDError(f"{path}: {e}") from None
        on_model = resample(to_target(motion, jm), fps)
        if on_model.n_frames < window:
            raise StyleERDError(f"{path}: {on_model.n_frames} frames at {fps:g} fps; a clip needs at least {window}")
        feats, _ = motion_features(on_model)
        x = stats.normalize(feats).astype(np.float32)
        if np.abs(x).max() > 1e3:
            raise StyleERDError(f"{path}: its values are far outside the model's range (wrong units or a broken file)")
        # the labels the online labeller gives each frame (as the stylizer uses them), averaged
        with torch.no_grad():
            logits_s, logits_c, _ = labeller(torch.from_numpy(x)[None])
        p_s = toward_neutral(logits_s[0].softmax(-1).numpy(), c.neutral_index).mean(0)
        p_c = logits_c[0].softmax(-1).numpy().mean(0)
        if contents is not None:
            p_c = np.eye(len(c.contents), dtype=np.float32)[c.contents.index(contents[i])]
        starts = np.arange(0, len(x) - window + 1, stride)
        xs.append(gather_windows(x, starts, window))
        styles.append(np.repeat(p_s[None], len(starts), 0))
        cont.append(np.repeat(p_c[None], len(starts), 0))
        total += len(x)
    return StyleClips(
        *(torch.from_numpy(np.concatenate(a)) for a in (xs, styles, cont)), [Path(p).name for p in paths], total
    )


def with_added_style(G: StyleERD, name: str, like: str) -> StyleERD:
    """``G`` with one more target style ``name``, whose branch, initial state and decoder row
    start as those of the style ``like``; everything else is ``G``'s, unchanged."""
    c = G.config
    config = replace(c, styles=(*c.styles, name), added_styles=(*c.added_styles, name))
    new = StyleERD(config, G.skeleton, G.stats())
    sd = {k: v.clone() for k, v in G.state_dict().items()}
    k_like, K = c.branch_styles.index(c.styles.index(like)), len(c.branch_styles)
    for key in [k for k in sd if k.startswith(f"branches.{k_like}.")]:
        sd[f"branches.{K}." + key.split(".", 2)[2]] = sd[key].clone()
    for key in ("branch_h0", "branch_c0"):
        sd[key] = torch.cat([sd[key], sd[key][k_like : k_like + 1]])
    nI, s = len(c.input_styles), c.styles.index(like)
    row = sd["decoder.0.weight"][:, c.hidden + s] if s < nI else sd["decoder_added"][s - nI]
    sd["decoder_added"] = torch.cat([sd.get("decoder_added", row.new_zeros(0, len(row))), row[None].clone()])
    new.load_state_dict(sd)
    return new.eval()


@torch.no_grad()
def _encoded(
    G: StyleERD, x: torch.Tensor, style: torch.Tensor, content: torch.Tensor, chunk: int = 512
) -> tuple[torch.Tensor, torch.Tensor]:
    """The frozen encoder's latents and the neutral branch's outputs of windows ``x``."""
    zs, outs = [], []
    for i in range(0, len(x), chunk):
        sl = slice(i, i + chunk)
        z = G.encode(x[sl], style[sl], content[sl])
        out, _ = G.neutral(z, G.initial_state(content[sl]).neutral)
        zs.append(z)
        outs.append(out)
    return torch.cat(zs), torch.cat(outs)


def add_style(
    model_name: str | Path | None,
    name: str,
    clips: list[str | Path],
    out: Path,
    contents: list[str] | None = None,
    like: str | None = None,
    config: AddStyleConfig = DEFAULT_CONFIG,
    data_dir: str | None = None,
    explicit_map: dict[str, str] | None = None,
    progress: bool = True,
) -> dict:
    """Train the style ``name`` from ``clips`` into a copy of the model ``model_name`` and save
    it at ``out`` (a model file usable everywhere a model is). Returns what was done."""
    t_start = time.perf_counter()
    torch.set_num_threads(config.threads)
    G, meta = ckpt.load_generator(model_name)
    c = G.config
    if not NAME.fullmatch(name):
        raise StyleERDError(
            f"style name {name!r}: use 1 to 32 lower-case letters, digits, - or _, starting with a letter"
        )
    if name in c.styles:
        raise StyleERDError(f"the model already has a style {name!r}; its styles: {', '.join(c.styles)}")
    if like is not None and (like not in c.styles or like == c.neutral_style):
        raise StyleERDError(
            f"--like {like!r} must be one of the model's styles other than {c.neutral_style}: "
            f"{', '.join(s for s in c.styles if s != c.neutral_style)}"
        )
    train_config = TrainConfig.from_dict(meta["training"]["config"], where="the model's training config")
    new = style_clips(clips, G, train_config.window, config.stride, contents, explicit_map)
    if like is None:  # start from the trained style the labeller finds closest (not the neutral one)
        p = new.style.mean(0).clone()
        p[c.neutral_index] = -1.0
        like = c.input_styles[int(p.argmax())]

    # neutral training windows of the model's dataset: the content to stylise
    s = setup(replace(train_config, stride=config.content_stride), data_dir, progress)
    if not np.allclose(s.data.stats.mean, G.mean.double().numpy(), atol=1e-5):
        raise StyleERDError(
            f"the cached {train_config.dataset} features are not normalised as the model was trained (another data "
            "version?)"
        )
    neutral_rows = np.nonzero(s.train.style == s.data.styles.index(c.neutral_style))[0]
    xc = s.data.gather(s.train.starts[neutral_rows])
    content_c = s.data.onehot_content(s.train.content[neutral_rows])
    content_ids = torch.from_numpy(s.train.content[neutral_rows]).long()
    style_c = s.data.onehot_style(np.full(len(neutral_rows), s.data.styles.index(c.neutral_style)))
    per = _perceptual_classifier(
        train_config, s, cache_dir() / f"perceptual-{train_config.dataset}-seed{train_config.seed}", progress
    )
    per.requires_grad_(False)

    torch.manual_seed(config.seed)
    G2 = with_added_style(G, name, like)
    G2.requires_grad_(False)
    K = len(G2.branch_styles) - 1
    branch = G2.branches[K]
    # the stacked initial states and added decoder rows learn as whole tensors, but only the new
    # style's entries get a gradient (the others are not used, or weighted 0): Adam's moments
    # and updates of the old entries stay exactly 0, so they keep their values bit for bit
    trainable = [*branch.parameters(), G2.branch_h0, G2.branch_c0, G2.decoder_added]
    for p in trainable:
        p.requires_grad_(True)
    J, L = c.n_joints, G2.layout
    seen = critic_channels(
        train_config
        if config.critic_rotations is None
        else replace(train_config, critic_rotations=config.critic_rotations),
        L,
    )
    D = Discriminator(seen.stop - seen.start, 1, len(c.contents), train_config.window, attention=train_config.attention)
    opt_g = torch.optim.Adam(trainable, lr=config.lr_g, betas=(0.5, 0.999), fused=True)
    opt_d = torch.optim.Adam(D.parameters(), lr=config.lr_d, betas=(0.5, 0.999), fused=True)

    zc, nc = _encoded(G2, xc, style_c, content_c)
    zs, ns = _encoded(G2, new.x, new.style, new.content)
    target = torch.zeros(1, len(G2.config.styles))
    target[0, -1] = 1.0
    rng = np.random.default_rng(config.seed)
    B = config.batch_size
    rot_new = G2.raw_rotations(new.x)

    def stylised(x, z, neutral_out, rows):
        y, _ = branch(z[rows], G2.branch_initial_state(K, len(rows)))
        rot, vel = G2.decode(neutral_out[rows] + y, target.expand(len(rows), -1))
        rot = G2.posed(rot, x[rows])
        return rot, vel, G2.motion_channels(rot, vel)

    log: list[dict] = []
    bar = tqdm(range(config.steps), desc=f"adding {name}", disable=not progress)
    t_train = time.perf_counter()
    for step in bar:
        rc, rs = rng.choice(len(zc), B), rng.choice(len(zs), B)
        _, _, fake = stylised(xc, zc, nc, rc)
        rot_r, _, ch_r = stylised(new.x, zs, ns, rs)
        real_s = new.x[rs][..., : 10 * J]
        ones = torch.ones(B, 1)
        loss_rec = losses.reconstruction_loss(rot_r, rot_new[rs], ch_r, real_s, L)
        D.requires_grad_(False)  # the generator's step needs D's gradient to its input only
        loss_adv = losses.generator_adversarial(D(fake[..., seen], ones, content_c[rc]))
        fake_maps = per.feature_maps(fake)
        loss_per = losses.perceptual(per, xc[rc][..., : 10 * J], fake_maps)
        loss_cls = losses.content_classification(per, fake_maps, content_ids[rc])
        loss_g = config.w_rec * loss_rec + config.w_adv * loss_adv + config.w_per * loss_per + config.w_cls * loss_cls
        opt_g.zero_grad(set_to_none=True)
        loss_g.backward()
        opt_g.step()
        D.requires_grad_(True)
        real_seen = real_s[..., seen]
        loss_d = losses.critic(D(real_seen, ones, new.content[rs]), D(fake.detach()[..., seen], ones, content_c[rc]))
        if config.r1_every and step % config.r1_every == 0:
            loss_d = loss_d + config.w_gp * config.r1_every * losses.r1_penalty(D, real_seen, ones, new.content[rs])
        opt_d.zero_grad(set_to_none=True)
        loss_d.backward()
        opt_d.step()
        row = {
            "step": step + 1,
            "rec": loss_rec.item(),
            "adv": loss_adv.item(),
            "per": loss_per.item(),
            "cls": loss_cls.item(),
            "critic": loss_d.item(),
        }
        log.append(row)
        bar.set_postfix({k: f"{v:.3f}" for k, v in row.items() if k != "step"})
        if config.max_minutes and time.perf_counter() - t_train > config.max_minutes * 60:
            break
    G2.eval()
    minutes = (time.perf_counter() - t_start) / 60
    added = {
        "name": name,
        "clips": new.names,
        "frames": new.frames,
        "windows": len(new.x),
        "started_like": like,
        "contents": contents,
        "steps": len(log),
        "minutes": round(minutes, 2),
        "training_minutes": round((time.perf_counter() - t_train) / 60, 2),
        "config": asdict(config),
        "critic_reads": [
            part
            for part in ("rotations", "positions", "velocities")
            if getattr(L, part).start >= seen.start and getattr(L, part).stop <= seen.stop
        ],
        "last_losses": {
            k: round(float(np.mean([r[k] for r in log[-50:]])), 4) for k in ("rec", "adv", "per", "cls", "critic")
        },
    }
    meta2 = {**meta, "config": G2.config.to_dict(), "added_styles": [*meta.get("added_styles", []), added]}
    ckpt.save_tensors(Path(out), ckpt.prefixed("generator", G2), meta2)
    return added
