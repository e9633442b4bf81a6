"""Evaluation metrics on the test split, all with fixed judges (the shipped recognisers,
labeller and FMD extractor).

Quality of a generator's transfers (``evaluate_model``):
- FMD: Fréchet distance between FMD features of transferred windows and of real test windows
  of each target style; pooled (real windows drawn in the transfers' style proportions) and
  per style. The floor is the FMD between two disjoint halves (by clip) of the real test
  windows, so every FMD reads as a multiple of it.
- SRA / CRA: transfers recognised as the target style / the input's content; per target
  style too, CRA beside the content recogniser's accuracy on the transfers' inputs (its
  ceiling). Spreads: standard deviations over bootstrap resamples of the transfers.
- Responsiveness: each test clip streamed from its first frame; SRA and FMD of its first 10
  output frames versus the 24-frame windows after them.
- Jitter: mean jerk (third difference of joint positions) of transfers over that of the real
  input windows. Reconstruction error (target style = input style).

Online behaviour of the runtime (``runtime_report``): label inference after 1/10/30 frames,
foot skate before and after cleanup, and the size of the pop when the target style switches
mid-stream. Its streams are the test clips of at least ``frames`` frames, cut to that length
and run as one batch through StreamStylizer (the per-frame path users run), each into its
transfer target (neutral -> one of the other styles in turn, styled -> neutral).

Transfers as users run them (``runtime_transfers``): whole test clips streamed frame by frame,
styled ones back to neutral and neutral ones into every style, labels given and inferred,
judged as the output plays.
"""

from __future__ import annotations

import numpy as np
import torch
from tqdm import tqdm

from styleerd.data.cache import prepare
from styleerd.data.datasets import data_root, find_clips, load_motion
from styleerd.data.features import motion_features
from styleerd.data.windows import gather_windows, split_takes
from styleerd.model.fmd import MotionAutoencoder, fmd_features
from styleerd.model.generator import StyleERD
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import bvh
from styleerd.motion.kinematics import foot_contacts, forward_positions
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.cleanup import FootLock
from styleerd.runtime.stylizer import StreamStylizer
from styleerd.train.batches import window_rotations
from styleerd.train.config import TrainConfig
from styleerd.train.labeller import stream_accuracy
from styleerd.train.trainer import Setup, setup
from styleerd.train.validation import frechet_distance, proportional_real, transfer_quality

FIRST_FRAMES = 10


@torch.no_grad()
def responsiveness(
    model: StyleERD,
    s: Setup,
    style_rec,
    fmd: MotionAutoencoder,
    window: int = 24,
    split: str = "test",
    start: int = 0,
) -> dict:
    """Each clip of ``split`` streamed from its first frame (or from frame ``start``: a stream
    opened mid-motion, as after a reconnection) into its transfer target(s): SRA and FMD of the
    first ``FIRST_FRAMES`` output frames and of the 24-frame windows after them."""
    model.eval()
    data, fs = s.data, s.fs
    reference = torch.as_tensor(data.stats.reference, dtype=torch.float32)
    neutral = model.config.neutral_index
    first_fake, rest_fake, first_t, rest_t, first_real, rest_real = [], [], [], [], {}, {}
    hit_first = hit_rest = 0
    for c in fs.clips(split):
        sl = fs.frames(c)
        sl = slice(sl.start + start, sl.stop)
        if sl.stop - sl.start < FIRST_FRAMES + window:
            continue
        st, ct = data.styles.index(fs.styles[c]), data.contents.index(fs.contents[c])
        targets = [t for t in range(len(data.styles)) if t != neutral] if st == neutral else [neutral]
        x = data.frames[sl][None].expand(len(targets), -1, -1)
        rot, vel, _ = model(
            x,
            data.onehot_style(np.full(len(targets), st)),
            data.onehot_content(np.full(len(targets), ct)),
            data.onehot_style(np.array(targets)),
        )
        ch = model.motion_channels(rot, vel)
        n_rest = (x.shape[1] - FIRST_FRAMES) // window
        t = np.array(targets)
        hit_first += int((style_rec(ch[:, :FIRST_FRAMES]).argmax(-1).numpy() == t).sum())
        first_fake.append(fmd_features(fmd, rot[:, :FIRST_FRAMES], reference))
        first_t.append(t)
        q_real = window_rotations(data, np.array([sl.start]))  # [1, 24, J, 4]: its first frames
        first_real.setdefault(st, []).append(fmd_features(fmd, q_real[:, :FIRST_FRAMES], reference)[0])
        for k in range(n_rest):
            a = FIRST_FRAMES + k * window
            hit_rest += int((style_rec(ch[:, a : a + window]).argmax(-1).numpy() == t).sum())
            rest_fake.append(fmd_features(fmd, rot[:, a : a + window], reference))
            rest_t.append(t)
            rest_real.setdefault(st, []).append(
                fmd_features(fmd, window_rotations(data, np.array([sl.start + a])), reference)[0]
            )
    ft, rt = np.concatenate(first_t), np.concatenate(rest_t)
    first_real_by = {k: np.stack(v) for k, v in first_real.items()}
    rest_real_by = {k: np.stack(v) for k, v in rest_real.items()}
    return {
        "sra_first_10": round(hit_first / len(ft), 4),
        "sra_rest": round(hit_rest / len(rt), 4),
        "fmd_first_10": round(frechet_distance(np.concatenate(first_fake), proportional_real(first_real_by, ft)), 3),
        "fmd_rest": round(frechet_distance(np.concatenate(rest_fake), proportional_real(rest_real_by, rt)), 3),
    }


def evaluate_model(model: StyleERD, data_dir: str | None = None, split: str = "test", pose: str = "network") -> dict:
    """Every quality figure of one generator on the test split (the ablation table's row), or on
    the validation split (``split="val"``: for choosing between models without the test set).
    ``pose``: the transfers' poses, the network's or the input's plus the style's change
    (``validation.transfers``)."""
    from styleerd.model import checkpoint as ckpt
    from styleerd.train.trainer import windows
    from styleerd.train.validation import realism_margin, validate

    s = setup(TrainConfig(), data_dir, progress=False)
    ws = windows(s.fs, s.data, split, s.data.window)
    style_rec, content_rec, _ = ckpt.load_recognisers()
    fmd, _ = ckpt.load_fmd()
    rec = validate(model, s.data, ws)
    out = {"rec_deg": round(rec["rec_deg"], 3), "rec_cm": round(rec["rec_cm"], 3)}
    out.update(transfer_quality(model, s.data, ws, style_rec, content_rec, fmd, pose=pose))
    out.update(realism_margin(out))
    out.update(responsiveness(model, s, style_rec, fmd, split=split))
    return out


# ---------------------------------------------------------------- online behaviour


def foot_skate(global_positions: np.ndarray, ankles: tuple[int, int], planted: np.ndarray) -> float:
    """Mean horizontal ankle travel per frame (data units) over the frames where a foot is
    planted now and was planted the frame before. ``global_positions [N, T, J, 3]``,
    ``planted [N, T, 2]``."""
    step = np.linalg.norm(np.diff(global_positions[:, :, list(ankles)][..., [0, 2]], axis=1), axis=-1)  # [N, T-1, 2]
    both = planted[:, 1:] & planted[:, :-1]
    return float(step[both].mean()) if both.any() else 0.0


def _streams(model: StyleERD, data_dir: str | None, frames: int):
    """Test clips of >= ``frames`` frames cut to that length: rotations/positions [N, T, J, *],
    their labels and transfer targets."""
    clips = find_clips(data_root(data_dir), "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    motions, styles, contents = [], [], []
    for c in tqdm([c for c in clips if split[c.name] == "test"], desc="test clips", leave=False):
        m = load_motion(c)
        if m.n_frames >= frames:
            motions.append(m[:frames])
            styles.append(c.style)
            contents.append(c.content)
    neutral = model.config.neutral_style
    others = [s for s in model.config.styles if s != neutral]
    targets = [others[i % len(others)] if s == neutral else neutral for i, s in enumerate(styles)]
    rot = np.stack([m.rotations for m in motions], 0)
    pos = np.stack([m.positions for m in motions], 0)
    return rot, pos, styles, contents, targets


def _run(
    model: StyleERD,
    rot,
    pos,
    styles,
    contents,
    targets,
    switch: dict | None = None,
    blend_frames: int = 8,
    cleanup: bool = False,
    root_speed: bool = False,
):
    """Stream every clip at once; returns output local rotations [N, T, J, 4] and positions
    [N, T, J, 3] (the input's, or with ``root_speed`` the root moved)."""
    N, T = rot.shape[:2]
    st = StreamStylizer(
        model,
        styles,
        contents,
        [{t: 1.0} for t in targets],
        n_streams=N,
        blend_frames=blend_frames,
        root_speed=root_speed,
    )
    lock = FootLock(model.skeleton, N) if cleanup else None
    out, out_pos = np.empty_like(rot), np.empty_like(pos)
    for t in range(T):
        if switch and t == switch["frame"]:
            for k, target in enumerate(switch["targets"]):
                st.set_target({target: 1.0}, [k])
        r, out_pos[:, t] = st.step(rot[:, t], pos[:, t])
        if lock:
            r, out_pos[:, t] = lock.step(r, out_pos[:, t], rot[:, t], pos[:, t])
        out[:, t] = r
    return out, out_pos


def _ground_speed(positions: np.ndarray) -> np.ndarray:
    """Per stream, the mean horizontal root speed (units per frame) of positions ``[N, T, J, 3]``."""
    return np.linalg.norm(np.diff(positions[:, :, 0][..., [0, 2]], axis=1), axis=-1).mean(1)


def other_performer_labels(
    model: StyleERD, labeller, data_dir: str | None = None, after: tuple[int, ...] = (1, 10, 30)
) -> dict[str, dict]:
    """The style the stylizer tells the encoder (labeller posterior, unsure ones leaning to
    neutral) for each xia-sample clip, streamed as ``transfer`` streams it (retargeted,
    resampled to 30 fps): after ``after`` frames and at the clip's end."""
    from styleerd.motion.resample import resample
    from styleerd.motion.retarget import to_target
    from styleerd.runtime.offline import map_skeleton

    out = {}
    for path in sorted((data_root(data_dir) / "xia-sample").glob("*.bvh")):
        m = bvh.read(path)
        on_model = resample(to_target(m, map_skeleton(m.skeleton, model, first_pose=m.rotations[0])), 30.0)
        st = StreamStylizer(model, None, None, {model.config.neutral_style: 1.0}, labeller=labeller)
        seen = []
        for t in range(on_model.n_frames):
            st.step(on_model.rotations[t : t + 1], on_model.positions[t : t + 1])
            seen.append(st.inferred_labels()[0][0])
        out[path.stem] = {**{str(n): seen[min(n, len(seen)) - 1] for n in after}, "end": seen[-1]}
    return out


def runtime_report(
    model: StyleERD, labeller, data_dir: str | None = None, frames: int = 90, blend_frames: int = 8
) -> dict:
    s = setup(TrainConfig(), data_dir, progress=False)
    report: dict = {
        "labels": stream_accuracy(labeller, s.fs, s.data, "test", neutral=model.config.neutral_style),
        "labels_raw": stream_accuracy(labeller, s.fs, s.data, "test"),
        "xia_labels": other_performer_labels(model, labeller, data_dir),
    }
    rot, pos, styles, contents, targets = _streams(model, data_dir, frames)
    sk = model.skeleton
    roles = BodyRoles.of(sk)
    ankles = (roles.feet[0], roles.feet[2])

    def world(r, p=pos):
        return forward_positions(r, p, sk.parents)

    g_in = world(rot)
    previous = np.concatenate([g_in[:, :1], g_in[:, :-1]], 1)
    planted = foot_contacts(g_in, previous, ankles, 30.0, 0.25 * roles.leg_length) > 0
    raw, _ = _run(model, rot, pos, styles, contents, targets)
    cleaned, p_cleaned = _run(model, rot, pos, styles, contents, targets, cleanup=True)  # the pelvis may drop
    raw_speed, p_speed = _run(model, rot, pos, styles, contents, targets, root_speed=True)
    pace = _ground_speed(pos)
    moving = pace > 0.05 * roles.leg_length / 30.0
    ratio = _ground_speed(p_speed)[moving] / pace[moving]
    cleaned_speed, p_cleaned_speed = _run(model, rot, pos, styles, contents, targets, cleanup=True, root_speed=True)
    report["foot_skate_cm_per_frame"] = {
        "streams": len(rot),
        "frames": frames,
        "input": round(foot_skate(g_in, ankles, planted), 4),
        "raw_output": round(foot_skate(world(raw), ankles, planted), 4),
        "cleaned_output": round(foot_skate(world(cleaned, p_cleaned), ankles, planted), 4),
        # with the root's speed stylised (``root_speed``): the feet follow the moved root
        "raw_output_root_speed": round(foot_skate(world(raw_speed, p_speed), ankles, planted), 4),
        "cleaned_output_root_speed": round(foot_skate(world(cleaned_speed, p_cleaned_speed), ankles, planted), 4),
        # per stream, the ground its root covers over the input's (moving streams)
        "root_speed_change": round(float(np.abs(np.log(ratio)).mean()), 3),  # mean |log ratio|
        "root_speed_ratio_range": [round(float(ratio.min()), 3), round(float(ratio.max()), 3)],
    }
    # switch every stream to another style halfway, blended and not; compare the largest joint
    # move per frame around the switch with the same frames of the stream that does not switch
    half = frames // 2
    others = [x for x in model.config.styles if x != model.config.neutral_style]
    new = [
        others[(others.index(t) + 1) % len(others)] if t in others else others[i % len(others)]
        for i, t in enumerate(targets)
    ]
    window = slice(half - 1, half + blend_frames)  # moves into frames half .. half + blend_frames

    def largest_move(g):
        return np.linalg.norm(np.diff(g, axis=1), axis=-1).max(-1)  # [N, T-1]

    steady = largest_move(world(raw))
    switch = {
        "frame": half,
        "blend_frames": blend_frames,
        "no_switch_cm": round(float(steady[:, window].max(1).mean()), 3),
    }
    for name, n in (("blended_cm", blend_frames), ("unblended_cm", 1)):
        moved = largest_move(
            world(_run(model, rot, pos, styles, contents, targets, {"frame": half, "targets": new}, n)[0])
        )
        switch[name] = round(float(moved[:, window].max(1).mean()), 3)
    switch["normal_p99_cm"] = round(float(np.percentile(steady, 99)), 3)
    report["style_switch"] = switch
    return report


# ---------------------------------------------------------------- transfers as users run them


def root_speeds(
    dataset: str = "bandai-namco-2", data_dir: str | None = None, split: str = "train"
) -> dict[str, dict[str, float]]:
    """Per content and style, the mean ground speed of the root over the ``split`` clips
    (data units per second): the pace each style moves at."""
    fs = prepare(dataset, data_dir, progress=False)
    speeds: dict[tuple[str, str], list[float]] = {}
    for c in fs.clips(split):
        path = fs.trajectory[fs.frames(c)][:, [0, 2]]
        speeds.setdefault((str(fs.contents[c]), str(fs.styles[c])), []).append(
            float(np.linalg.norm(np.diff(path, axis=0), axis=-1).mean() * fs.params.fps)
        )
    out: dict[str, dict[str, float]] = {}
    for (content, style), v in sorted(speeds.items()):
        out.setdefault(content, {})[style] = round(float(np.mean(v)), 1)
    return out


def played_channels(
    model: StyleERD | GeneratorWeights, rotations: np.ndarray, positions: np.ndarray, fps: float
) -> np.ndarray:
    """Normalised [rotations | positions | velocities] of output frames as they play (the
    stylizer's output rotations and root path), ``[T, 10J]`` float32."""
    feats, _ = motion_features(Motion(model.skeleton, rotations, positions, fps))
    return model.stats().normalize(feats)[:, : 10 * model.config.n_joints].astype(np.float32)


@torch.no_grad()
def runtime_transfers(
    model: StyleERD,
    labeller,
    style_rec,
    content_rec,
    data_dir: str | None = None,
    dataset: str = "bandai-namco-2",
    window: int = 24,
    stride: int = 12,
    split: str = "test",
    root_speed: bool = False,
    pose: str = "input",
) -> dict:
    """Every ``split`` clip streamed frame by frame through ``StreamStylizer`` (what
    ``transfer`` runs): styled clips back to neutral, neutral clips into every other style;
    each with its labels given and with its labels inferred online by ``labeller``. The
    output as it plays is cut into ``window``-frame windows every ``stride`` frames and read
    by the recognisers. Returns, per source style and target style, {"given": {sra, cra},
    "inferred": {sra, cra}, "windows": n, "missed_read_as": {style: windows}} (what the windows
    not read as the target were read as, labels given); also the labeller's style read at each
    clip's end.
    ``root_speed``, ``pose``: the stylizer's options."""
    fs, c = prepare(dataset, data_dir, progress=False), model.config
    neutral = c.neutral_style
    hits: dict[
        tuple[str, str], np.ndarray
    ] = {}  # (source, target) -> [given s, given c, inferred s, inferred c, windows, input's windows read right]
    read_as: dict[str, dict[str, int]] = {}
    misread: dict[
        tuple[str, str], dict[str, int]
    ] = {}  # (source, target) -> what the missed windows read as (labels given)
    for clip in tqdm(fs.clips(split), desc=f"{split} clips streamed", leave=False):
        sl = fs.frames(clip)
        if sl.stop - sl.start < window:
            continue
        motion = fs.motion(clip)
        style, content = str(fs.styles[clip]), str(fs.contents[clip])
        targets = [t for t in c.input_styles if t != neutral] if style == neutral else [neutral]
        n = len(targets)
        st = StreamStylizer(
            model,
            [style] * n + [None] * n,
            [content] * n + [None] * n,
            [{t: 1.0} for t in targets * 2],
            n_streams=2 * n,
            labeller=labeller,
            root_speed=root_speed,
            pose=pose,
        )
        rot = np.empty((2 * n, motion.n_frames, c.n_joints, 4))
        pos = np.empty((2 * n, motion.n_frames, c.n_joints, 3))
        for t in range(motion.n_frames):
            rot[:, t], pos[:, t] = st.step(
                np.broadcast_to(motion.rotations[t], rot[:, t].shape),
                np.broadcast_to(motion.positions[t], pos[:, t].shape),
            )
        label = st.inferred_labels()[n][0]
        seen = read_as.setdefault(style, {})
        seen[label] = seen.get(label, 0) + 1
        starts = np.arange(0, motion.n_frames - window + 1, stride)
        # the ceiling: the content recogniser on the input's own windows, the same ones
        given = torch.from_numpy(
            gather_windows(played_channels(model, motion.rotations, motion.positions, fs.params.fps), starts, window)
        )
        ok_in = int((content_rec(given).argmax(-1).numpy() == c.contents.index(content)).sum())
        for k in range(2 * n):
            ch = played_channels(model, rot[k], pos[k], fs.params.fps)
            w = torch.from_numpy(gather_windows(ch, starts, window))
            target = targets[k % n]
            read = style_rec(w).argmax(-1).numpy()
            ok_s = int((read == c.styles.index(target)).sum())
            if k < n:
                missed = misread.setdefault((style, target), {})
                for r in read[read != c.styles.index(target)]:
                    missed[c.styles[r]] = missed.get(c.styles[r], 0) + 1
            ok_c = int((content_rec(w).argmax(-1).numpy() == c.contents.index(content)).sum())
            h = hits.setdefault((style, target), np.zeros(6, int))
            h[[0, 1] if k < n else [2, 3]] += (ok_s, ok_c)
            h[[4, 5]] += (len(starts), ok_in) if k < n else 0
    out = {}
    for (source, target), h in sorted(hits.items()):
        out.setdefault(source, {})[target] = {
            "given": {"sra": round(h[0] / h[4], 4), "cra": round(h[1] / h[4], 4)},
            "inferred": {"sra": round(h[2] / h[4], 4), "cra": round(h[3] / h[4], 4)},
            "windows": int(h[4]),
            "content_ceiling": round(h[5] / h[4], 4),  # the content recogniser on the inputs' own windows
            "missed_read_as": dict(sorted(misread.get((source, target), {}).items(), key=lambda kv: -kv[1])),
        }
    return {"transfers": out, "labeller_reads_input_as_at_end": read_as}


def played_content_of_ceiling(streamed: dict, neutral: str, how: str = "given") -> dict[str, float]:
    """Per target style, the CRA of ``runtime_transfers``' played windows over the content
    recogniser's ceiling on the same inputs (issue 35's bar: 0.95), labels ``how``: into each style
    from the neutral clips, into ``neutral`` pooled over every other source style."""
    t = streamed["transfers"]
    out = {target: v[how]["cra"] / v["content_ceiling"] for target, v in t[neutral].items()}
    back = [v[neutral] for source, v in t.items() if source != neutral]
    read = sum(b[how]["cra"] * b["windows"] for b in back)
    out[neutral] = read / sum(b["content_ceiling"] * b["windows"] for b in back)
    return {k: round(out[k], 4) for k in sorted(out)}
