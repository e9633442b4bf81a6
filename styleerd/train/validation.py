"""Quality of a generator on held-out windows. ``validate``: the quick signal checked during
training (reconstruction error in degrees and cm, style and content recognition accuracy (SRA,
CRA) of its transfers). ``transfer_quality``: every figure of its transfers, FMD and CRA per
target style among them (the test split's report, and model selection on realism)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import torch

from styleerd.model import torch_quat
from styleerd.model.classifiers import WindowClassifier
from styleerd.model.config import RELEASE, RISE
from styleerd.model.fmd import MotionAutoencoder, fmd_features
from styleerd.model.generator import StyleERD
from styleerd.motion.humanoid import eyes_above_head, limb_ends
from styleerd.motion.skeleton import BodyRoles
from styleerd.train.batches import TrainingData, WindowSet, window_rotations

# Issue 16's bars for a realistic model, per target style: FMD at most 3 x its floor, CRA at
# least 95 % of the content recogniser's ceiling.
FMD_BAR, CRA_BAR = 3.0, 0.95


def transfer_targets(style: np.ndarray, neutral: int, n_styles: int) -> tuple[np.ndarray, np.ndarray]:
    """The paper's transfer tasks for windows of the given styles: a neutral window goes to
    every other style, a styled window goes to neutral. Returns (window index, target)."""
    rows, targets = [], []
    for i, s in enumerate(style):
        for t in [t for t in range(n_styles) if t != neutral] if s == neutral else [neutral]:
            rows.append(i)
            targets.append(t)
    return np.array(rows, dtype=np.int64), np.array(targets, dtype=np.int64)


@torch.no_grad()
def validate(
    model: StyleERD,
    data: TrainingData,
    ws: WindowSet,
    style_recogniser: WindowClassifier | None = None,
    content_recogniser: WindowClassifier | None = None,
    batch: int = 512,
) -> dict[str, float]:
    model.eval()
    L = model.layout
    deg, cm, n = 0.0, 0.0, 0
    for i in range(0, len(ws.starts), batch):
        sl = slice(i, i + batch)
        x = data.gather(ws.starts[sl])
        s, c = data.onehot_style(ws.style[sl]), data.onehot_content(ws.content[sl])
        rot, _vel, _ = model(x, s, c, s)
        target = model.raw_rotations(x)
        d = (rot * target).sum(-1).abs().clamp(max=1.0)
        deg += float(torch.rad2deg(2 * torch.acos(d)).mean(dim=(1, 2)).sum())
        pos = torch_quat.root_relative_positions(rot, model.offsets, model.parents)
        pos_in = (x[..., L.positions] * model.std[L.positions] + model.mean[L.positions]).reshape(pos.shape)
        cm += float((pos - pos_in).norm(dim=-1).mean(dim=(1, 2)).sum())
        n += len(x)
    out = {"rec_deg": deg / n, "rec_cm": cm / n}
    if style_recogniser is None or content_recogniser is None:
        return out
    hit_s = hit_c = n = 0
    for r, t, _, _, ch in transfers(model, data, ws, batch):
        hit_s += int((style_recogniser(ch).argmax(-1).numpy() == t).sum())
        hit_c += int((content_recogniser(ch).argmax(-1).numpy() == ws.content[r]).sum())
        n += len(r)
    out.update(sra=hit_s / n, cra=hit_c / n)
    return out


@torch.no_grad()
def transfers(model: StyleERD, data: TrainingData, ws: WindowSet, batch: int = 512, pose: str = "network"):
    """The transfer tasks of ``ws`` in batches: (window rows, targets, rotations, velocities,
    normalised motion channels). ``pose``: "network", the network's output (what training
    judges); "input", what ``StreamStylizer`` gives users by default (``towards_the_input``)."""
    rows, targets = transfer_targets(ws.style, model.config.neutral_index, len(data.styles))
    for i in range(0, len(rows), batch):
        r, t = rows[i : i + batch], targets[i : i + batch]
        x = data.gather(ws.starts[r])
        style, content = data.onehot_style(ws.style[r]), data.onehot_content(ws.content[r])
        target = data.onehot_style(t)
        rot, vel, _ = model(x, style, content, target)
        if pose == "input":
            rot, vel = towards_the_input(model, x, style, content, target, rot, vel)
        yield r, t, rot, vel, model.motion_channels(rot, vel)


def towards_the_input(
    model: StyleERD,
    x: torch.Tensor,
    style: torch.Tensor,
    content: torch.Tensor,
    target: torch.Tensor,
    rot: torch.Tensor,
    vel: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The network's rotations and velocities ``rot``, ``vel`` of windows ``x [B, T, D]`` into
    ``target`` taken towards the input as ``runtime.stylizer`` does frame by frame (pose "input"):
    as far as the identity transfer is from the input, the input turned by the target's posture
    less its own style's (rotations, then towards the posture's joint offsets where measured), or
    for a model without one by the change from the identity output to the target's. Roots in the
    heading frame, as the features have them."""
    same_rot, same_vel, _ = model(x, style, content, style)
    given = model.raw_rotations(x)
    familiar, unfamiliar = model.familiar
    now = ((torch.rad2deg(torch_quat.angle(same_rot, given)).mean(-1) - familiar) / (unfamiliar - familiar)).clamp(
        0.0, 1.0
    )  # [B, T]
    weight = now.clone()
    for frame in range(1, now.shape[1]):  # down by at most RELEASE and up by at most RISE a frame
        last = weight[:, frame - 1]
        weight[:, frame] = torch.minimum(torch.maximum(now[:, frame], last - RELEASE), last + RISE)
    if model.posture is None:
        turned = torch_quat.add_change(given, same_rot, rot)
    else:
        own = torch.zeros_like(target)
        own[:, : style.shape[1]] = style
        change = torch_quat.from_scaled_angle_axis(torch.einsum("bs,sjc->bjc", target - own, model.posture))
        turned = torch_quat.normalize(torch_quat.mul(torch_quat.normalize(given), change[:, None]))
        if model.posture_offsets is not None:
            L, J = model.layout, model.config.n_joints
            positions = (x[..., L.positions] * model.std[L.positions] + model.mean[L.positions]).unflatten(-1, (J, 3))
            moved = torch.einsum("bs,sjc->bjc", target - own, model.posture_offsets)
            roles, ends = BodyRoles.of(model.skeleton), limb_ends(model.skeleton).tolist()
            if model.posture_frame == "body":  # the offsets along the body's own axes, in the heading frame
                axes = torch_quat.body_axes(positions, roles.hips, roles.head, roles.left, roles.right)
                moved, up = torch.einsum("bjc,btck->btjk", moved, axes.to(moved.dtype)), axes[..., 1, :]
            else:
                moved, up = moved[:, None].expand_as(positions), positions.new_tensor([0.0, 1.0, 0.0])
            moved = torch_quat.ends_below_the_eyes(
                moved, positions, up.to(moved.dtype), roles.head, eyes_above_head(model.skeleton), ends, model.parents
            )
            turned = torch_quat.reach(turned, model.offsets, positions + moved, model.parents, ends)
    rot = torch_quat.slerp(rot, turned, weight[..., None].expand(rot.shape[:-1]))
    return rot, vel + weight[..., None] * (x[..., model.layout.velocities] - same_vel)


def frechet_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Fréchet distance between Gaussians fitted to feature sets ``a [n, d]``, ``b [m, d]``:
    |mu_a - mu_b|^2 + tr(C_a + C_b - 2 (C_a^1/2 C_b C_a^1/2)^1/2), by symmetric eigensolves."""
    mu = a.mean(0) - b.mean(0)
    ca, cb = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    w, v = np.linalg.eigh(ca)
    root_a = (v * np.sqrt(np.clip(w, 0, None))) @ v.T
    cross = np.linalg.eigvalsh(root_a @ cb @ root_a)
    return float(mu @ mu + np.trace(ca) + np.trace(cb) - 2 * np.sqrt(np.clip(cross, 0, None)).sum())


def proportional_real(real: dict[int, np.ndarray], targets: np.ndarray) -> np.ndarray:
    """Real features drawn in the proportions of ``targets`` (cycling through each style's)."""
    seen: dict[int, int] = {}
    rows = []
    for t in targets:
        k = seen.get(int(t), 0)
        rows.append(real[int(t)][k % len(real[int(t)])])
        seen[int(t)] = k + 1
    return np.stack(rows)


def bootstrap_spread(n: int, statistic, resamples: int = 200, seed: int = 0) -> float:
    """Standard deviation of ``statistic(rows)`` over ``resamples`` draws of ``n`` rows with
    replacement (the spread of a figure over resamples of the test windows)."""
    rng = np.random.default_rng(seed)
    return float(np.std([statistic(rng.integers(0, n, n)) for _ in range(resamples)]))


@torch.no_grad()
def transfer_quality(
    model: StyleERD,
    data: TrainingData,
    test: WindowSet,
    style_rec: WindowClassifier,
    content_rec: WindowClassifier,
    fmd: MotionAutoencoder,
    batch: int = 256,
    resamples: int = 200,
    pose: str = "network",
) -> dict:
    """Every quality figure of the transfers of ``test``'s windows (see ``styleerd.eval.metrics``);
    ``resamples`` 0 leaves out the bootstrap spreads (model selection during training)."""
    model.eval()
    reference = torch.as_tensor(data.stats.reference, dtype=torch.float32)
    # the content recogniser on each real window once (a neutral window is the input of several transfers)
    read_in = np.concatenate(
        [
            content_rec(data.gather(test.starts[i : i + batch])).argmax(-1).numpy()
            for i in range(0, len(test.starts), batch)
        ]
    )
    feats, ok_s, read_c, ok_in, jerk_fake, all_targets, given_c = [], [], [], [], [], [], []
    for r, t, rot, _, ch in transfers(model, data, test, batch, pose):
        ok_s.append(style_rec(ch).argmax(-1).numpy() == t)
        read_c.append(content_rec(ch).argmax(-1).numpy())
        given_c.append(test.content[r])
        ok_in.append(read_in[r] == test.content[r])  # the input itself
        feats.append(fmd_features(fmd, rot, reference))
        jerk_fake.append(_jerk(torch_quat.root_relative_positions(rot, model.offsets, model.parents)))
        all_targets.append(t)
    targets, ok_s, read_c, given_c, ok_in = (np.concatenate(a) for a in (all_targets, ok_s, read_c, given_c, ok_in))
    ok_c = read_c == given_c
    fake = np.concatenate(feats)
    real_all = np.concatenate(
        [
            fmd_features(fmd, window_rotations(data, test.starts[i : i + batch]), reference)
            for i in range(0, len(test.starts), batch)
        ]
    )
    real = {k: real_all[test.style == k] for k in range(len(data.styles))}
    styles = np.unique(targets)
    per_style = {data.styles[k]: round(frechet_distance(fake[targets == k], real[k]), 3) for k in styles}
    # floor: two halves of the real windows, split by clip
    half = np.isin(test.clip, np.unique(test.clip)[::2])
    floor_style = {
        data.styles[k]: round(
            frechet_distance(real_all[half & (test.style == k)], real_all[~half & (test.style == k)]), 3
        )
        for k in styles
    }
    pooled_real = proportional_real(real, targets)
    pooled = frechet_distance(fake, pooled_real)
    floor = frechet_distance(real_all[half], real_all[~half])
    real_pos = torch.cat(
        [_real_positions(model, data, test.starts[i : i + batch]) for i in range(0, len(test.starts), batch)]
    )
    # spreads over bootstrap resamples of the transfers (FMD: fake and real rows drawn together)
    spread = (
        {
            "sra": bootstrap_spread(len(ok_s), lambda i: ok_s[i].mean(), resamples),
            "cra": bootstrap_spread(len(ok_c), lambda i: ok_c[i].mean(), resamples),
            "fmd": bootstrap_spread(len(fake), lambda i: frechet_distance(fake[i], pooled_real[i]), resamples),
        }
        if resamples
        else {}
    )
    # a style's CRA over its ceiling, resampled over that style's transfers (how far a 95 % bar is from noise)
    of_ceiling_spread = (
        {
            "cra_of_ceiling_spread_per_style": {
                data.styles[k]: round(
                    bootstrap_spread(
                        int((targets == k).sum()),
                        lambda i, c=ok_c[targets == k], n=ok_in[targets == k]: c[i].mean() / max(n[i].mean(), 1e-9),
                        resamples,
                    ),
                    4,
                )
                for k in styles
            }
        }
        if resamples
        else {}
    )
    return {
        "transfers": len(targets),
        "sra": round(float(ok_s.mean()), 4),
        "cra": round(float(ok_c.mean()), 4),
        "content_ceiling": round(float(ok_in.mean()), 4),  # the content recogniser on the transfers' inputs
        "fmd": round(pooled, 3),
        "fmd_floor": round(floor, 3),
        "fmd_over_floor": round(pooled / floor, 2),
        "spread": {k: round(v, 4) for k, v in spread.items()},
        "fmd_per_style": per_style,
        "fmd_floor_per_style": floor_style,
        "cra_per_style": {data.styles[k]: round(float(ok_c[targets == k].mean()), 4) for k in styles},
        # per target, the content recogniser's accuracy on the transfers' inputs: its ceiling there
        "content_ceiling_per_style": {data.styles[k]: round(float(ok_in[targets == k].mean()), 4) for k in styles},
        **of_ceiling_spread,
        "sra_per_style": {data.styles[k]: round(float(ok_s[targets == k].mean()), 4) for k in styles},
        "content_misread_per_style": {
            data.styles[k]: misread(given_c[targets == k], read_c[targets == k], data.contents) for k in styles
        },
        "jitter_ratio": round(float(np.concatenate(jerk_fake).mean() / _jerk(real_pos).mean()), 3),
    }


def misread(given: np.ndarray, read: np.ndarray, contents: list[str], top: int = 3) -> dict[str, str]:
    """The contents most often read as another (by the content recogniser) among transfers into one
    style, as "given -> read": "k of n transfers of that content" (which content a CRA loses)."""
    wrong = Counter(zip(given[given != read].tolist(), read[given != read].tolist()))
    return {
        f"{contents[a]} -> {contents[b]}": f"{n} of {int((given == a).sum())}" for (a, b), n in wrong.most_common(top)
    }


def _real_positions(model: StyleERD, data: TrainingData, starts: np.ndarray) -> torch.Tensor:
    return torch_quat.root_relative_positions(model.raw_rotations(data.gather(starts)), model.offsets, model.parents)


def _jerk(positions: torch.Tensor) -> np.ndarray:
    """Mean jerk magnitude per window (units per frame^3) of positions ``[B, T, J, 3]``."""
    d3 = positions[:, 3:] - 3 * positions[:, 2:-1] + 3 * positions[:, 1:-2] - positions[:, :-3]
    return d3.norm(dim=-1).mean(dim=(1, 2)).numpy()


def style_ratios(quality: dict) -> tuple[dict[str, float], dict[str, float]]:
    """Per target style, FMD / floor and CRA / ceiling (``transfer_quality``'s output in)."""
    fmd = {
        k: quality["fmd_per_style"][k] / max(quality["fmd_floor_per_style"][k], 1e-9) for k in quality["fmd_per_style"]
    }
    cra = {
        k: quality["cra_per_style"][k] / max(quality["content_ceiling_per_style"][k], 1e-9)
        for k in quality["cra_per_style"]
    }
    return fmd, cra


def realism_margin(quality: dict) -> dict[str, float]:
    """How far inside both realism bars the worst target style is: per style, the smaller of
    FMD_BAR / (FMD / floor) and (CRA / ceiling) / CRA_BAR; >= 1 when every style meets both.
    Also the worst FMD / floor and CRA / ceiling themselves."""
    fmd, cra = style_ratios(quality)
    margin = min(min(FMD_BAR / max(fmd[k], 1e-9), cra[k] / CRA_BAR) for k in fmd)
    return {
        "worst_fmd_over_floor": round(max(fmd.values()), 3),
        "worst_cra_of_ceiling": round(min(cra.values()), 4),
        "realism_margin": round(margin, 4),
    }
