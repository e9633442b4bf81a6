"""BVH file -> stylised BVH file with the shipped model, on real clips."""

import subprocess
import sys

import numpy as np
import pytest

from styleerd.data.datasets import find_clips
from styleerd.errors import StyleERDError
from styleerd.model.checkpoint import load_generator
from styleerd.motion import bvh, quat
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.resample import resample
from styleerd.runtime.cleanup import FootLock, clean_feet
from styleerd.runtime.offline import TransferOptions, transfer_file

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def model():
    return load_generator()


def world(m):
    return forward_kinematics(m.rotations, m.positions, m.skeleton.parents)[1]


def moved_by_the_cleanup_at_most(height_out: np.ndarray, height_in: np.ndarray, skeleton) -> bool:
    """An output's root height against the input's: the same, or moved by the foot cleanup's pelvis
    (down where a planted foot needs it, or up or down to the output's own legs), at most its largest
    drop either way."""
    return bool(np.abs(height_in - height_out).max() <= FootLock(skeleton).max_drop + 1e-3)


def test_test_clips_into_every_style_keep_layout_frames_and_trajectory(shared_data, model, tmp_path):
    g, meta = model
    clips = [c for c in find_clips(shared_data, "bandai-namco-2") if c.content in ("walk", "wave-left-hand")]
    picked = {(c.style, c.content): c for c in clips}  # one clip per style x content
    for clip in list(picked.values())[:4]:
        src = bvh.read(clip.path)
        for style in g.config.styles:
            out_path = tmp_path / f"{clip.name}-{style}.bvh"
            transfer_file(
                clip.path,
                out_path,
                g,
                meta["data"]["fps"],
                TransferOptions({style: 1.0}, input_style=clip.style, content=clip.content),
            )
            out = bvh.read(out_path)
            assert out.skeleton == src.skeleton and out.n_frames == src.n_frames and np.isclose(out.fps, src.fps)
            assert np.isfinite(bvh.channel_values(out)).all()
            hips_out, hips_in = world(out)[:, 1], world(src)[:, 1]
            assert np.allclose(hips_out[:, [0, 2]], hips_in[:, [0, 2]], atol=1e-3)  # the Hips follow the input path
            assert moved_by_the_cleanup_at_most(hips_out[:, 1], hips_in[:, 1], src.skeleton)


def test_other_frame_rates_come_back_at_their_rate_and_length(shared_data, model, tmp_path):
    g, meta = model
    clip = find_clips(shared_data, "bandai-namco-2")[0]
    fast = resample(bvh.read(clip.path), 60.0)
    bvh.write(tmp_path / "in60.bvh", fast)
    done = transfer_file(
        tmp_path / "in60.bvh",
        tmp_path / "out60.bvh",
        g,
        meta["data"]["fps"],
        TransferOptions({"elderly": 1.0}, input_style=clip.style, content=clip.content),
    )
    assert done.frames == fast.n_frames == bvh.read(tmp_path / "out60.bvh").n_frames and np.isclose(
        bvh.read(tmp_path / "out60.bvh").fps, 60.0, rtol=1e-6
    )


def test_xia_clips_into_every_style_keep_skeleton_frames_and_root(shared_data, model, tmp_path):
    g, meta = model
    lines = []
    for path in sorted((shared_data / "xia-sample").glob("*.bvh")):
        src = bvh.read(path)
        for style in g.config.styles:
            out_path = tmp_path / f"{path.stem}-{style}.bvh"
            transfer_file(
                path,
                out_path,
                g,
                meta["data"]["fps"],
                TransferOptions({style: 1.0}, input_style="normal", content="walk"),
                report=lines.append,
            )
            out = bvh.read(out_path)
            assert out.skeleton == src.skeleton and out.n_frames == src.n_frames and np.isclose(out.fps, src.fps)
            assert np.isfinite(bvh.channel_values(out)).all()
            assert np.array_equal(out.positions[:, 0, [0, 2]], src.positions[:, 0, [0, 2]])  # root path: the input's
            assert moved_by_the_cleanup_at_most(out.positions[:, 0, 1], src.positions[:, 0, 1], src.skeleton)
            assert not np.allclose(out.rotations, src.rotations, atol=1e-3)  # and the pose did change
    assert "Chest <- Spine1" in lines[0]


def test_renamed_joints_are_found_and_bad_maps_and_labels_fail_cleanly(shared_data, model, tmp_path):
    g, _meta = model
    xia = shared_data / "xia-sample" / "angry_13_000.bvh"
    text = xia.read_text().replace("LeftHand", "Paw").replace("LeftForeArm", "Wrist2")
    (tmp_path / "odd.bvh").write_text(text)
    lines = []
    transfer_file(
        tmp_path / "odd.bvh",
        tmp_path / "x.bvh",
        g,
        30.0,
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
        report=lines.append,
    )
    assert "LowerArm_L <- Wrist2" in lines[0] and "Hand_L <- Paw" in lines[0]  # down the arm from its shoulder
    (tmp_path / "map.json").write_text('{"LowerArm_L": "Wrist3"}')
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "transfer",
            str(tmp_path / "odd.bvh"),
            "--style",
            "elderly",
            "--joint-map",
            str(tmp_path / "map.json"),
            "-o",
            str(tmp_path / "y.bvh"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2 and "'Wrist3' is not a joint of the input skeleton" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "y.bvh").exists()
    clip = find_clips(shared_data, "bandai-namco-2")[0]
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "transfer",
            str(clip.path),
            "--style",
            "oldie",
            "--input-style",
            "normal",
            "--content",
            "walk",
            "-o",
            str(tmp_path / "y.bvh"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2 and "valid: active, elderly" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "y.bvh").exists()


def test_channel_stream_equals_the_file_transfer_on_a_stream_at_model_rate(model, tmp_path):
    from styleerd.motion.procedural import walk
    from styleerd.runtime.channels import ChannelStylizer

    g, _meta = model
    source = walk(2.0, fps=30.0)
    bvh.write(tmp_path / "in.bvh", source)
    src = bvh.read(tmp_path / "in.bvh")
    transfer_file(
        tmp_path / "in.bvh",
        tmp_path / "out.bvh",
        g,
        30.0,
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
    )
    out = bvh.read(tmp_path / "out.bvh")
    stream = ChannelStylizer(g, src.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0)
    values = bvh.channel_values(src)
    streamed = np.stack([stream.step(values[t])[0] for t in range(src.n_frames)])
    assert np.abs(streamed - bvh.channel_values(out)).max() < 1e-5  # degrees; the file went through 9-digit text
    with pytest.raises(StyleERDError, match="is not a finite number"):
        bad = values[0].copy()
        bad[3] = np.nan
        stream.step(bad)


def _transfer_every_style(job):
    """One test clip into every style; returns (clip, problems)."""
    import torch

    torch.set_num_threads(1)
    path, style, content, out_dir = job
    g, meta = load_generator()
    src = bvh.read(path)
    problems = []
    for target in g.config.styles:
        out_path = out_dir / f"{path.stem}-{target}.bvh"
        transfer_file(
            path, out_path, g, meta["data"]["fps"], TransferOptions({target: 1.0}, input_style=style, content=content)
        )
        out = bvh.read(out_path)
        if not (out.skeleton == src.skeleton and out.n_frames == src.n_frames and np.isclose(out.fps, src.fps)):
            problems.append(f"{target}: layout")
        if not np.isfinite(bvh.channel_values(out)).all():
            problems.append(f"{target}: non-finite")
        if not np.array_equal(out.positions[:, 0, [0, 2]], src.positions[:, 0, [0, 2]]):
            problems.append(f"{target}: root path")
        if not moved_by_the_cleanup_at_most(out.positions[:, 0, 1], src.positions[:, 0, 1], src.skeleton):
            problems.append(f"{target}: root height")
        out_path.unlink()
    return path.name, problems


def test_one_test_clip_per_style_and_content_into_every_style(shared_data, tmp_path):
    """Issue 4's acceptance: 70 Bandai-Namco-2 test clips (one per style x content), 7 styles each."""
    from multiprocessing import get_context

    from styleerd.data.windows import split_takes

    clips = find_clips(shared_data, "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    picked = {}
    for c in clips:
        if split[c.name] == "test":
            picked.setdefault((c.style, c.content), c)
    assert len(picked) == 70
    jobs = [(c.path, c.style, c.content, tmp_path) for c in picked.values()]
    with get_context("spawn").Pool(2) as pool:
        results = pool.map(_transfer_every_style, jobs)
    assert [r for r in results if r[1]] == []


@pytest.mark.parametrize("fps", [24.0, 30.0, 60.0, 120.0])
def test_streamed_file_transfer_equals_the_whole_motion_pipeline(model, tmp_path, fps):
    """The chunked transfer against the same steps applied to the whole motion at once."""
    from styleerd.motion.procedural import walk
    from styleerd.motion.retarget import to_source, to_target
    from styleerd.runtime.offline import map_skeleton, run_stream
    from styleerd.runtime.stylizer import StreamStylizer

    g, _ = model
    bvh.write(tmp_path / "in.bvh", walk(1.5, fps=fps))
    src = bvh.read(tmp_path / "in.bvh")
    transfer_file(
        tmp_path / "in.bvh",
        tmp_path / "out.bvh",
        g,
        30.0,
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
        chunk=7,
    )
    jm = map_skeleton(src.skeleton, g, first_pose=src.rotations[0])
    on_model = to_target(src, jm)
    given = resample(on_model, 30.0)
    styled = run_stream(StreamStylizer(g, "normal", "walk", {"elderly": 1.0}, fps=30.0), given)
    change = Motion(jm.target, quat.mul(quat.inv(given.rotations), styled.rotations), given.positions, 30.0)
    change = resample(change, src.fps, n_frames=src.n_frames).rotations
    whole = Motion(jm.target, quat.mul(on_model.rotations, change), on_model.positions, src.fps)
    whole = clean_feet(to_source(whole, jm, src), src)
    streamed = bvh.read(tmp_path / "out.bvh")
    assert streamed.n_frames == src.n_frames
    assert np.abs(bvh.channel_values(streamed) - bvh.channel_values(whole)).max() < 1e-5


@pytest.mark.slow
def test_memory_stays_bounded_however_long_the_file(model, tmp_path):
    """Peak traced memory of a transfer does not grow with the file's length."""
    import tracemalloc

    from styleerd.motion.procedural import walk

    g, _ = model
    peaks = []
    for seconds in (8.0, 32.0):
        bvh.write(tmp_path / "in.bvh", walk(seconds, fps=30.0))
        tracemalloc.start()
        transfer_file(
            tmp_path / "in.bvh",
            tmp_path / "out.bvh",
            g,
            30.0,
            TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
            chunk=64,
        )
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert bvh.read(tmp_path / "out.bvh").n_frames == 960
    assert peaks[1] < 1.15 * peaks[0], peaks  # 4x the frames, the same memory


@pytest.mark.parametrize("case", ["empty", "slow", "fast", "not bvh", "bad output"])
def test_bad_files_fail_with_one_line_and_nothing_written(model, tmp_path, case):
    from styleerd.motion.procedural import walk

    m = walk(1.0, fps=30.0)
    path, out = tmp_path / "in.bvh", tmp_path / "out.bvh"
    expected = {
        "empty": "the motion has no frames",
        "slow": "5 fps is outside [10, 480]",
        "fast": "500 fps is outside [10, 480]",
        "not bvh": "not a text file",
        "bad output": "the output must be .bvh, .glb, .vrma or .fbx",
    }[case]
    if case == "empty":
        bvh.write(path, m[:0])
    elif case in ("slow", "fast"):
        bvh.write(path, Motion(m.skeleton, m.rotations, m.positions, 5.0 if case == "slow" else 500.0))
    elif case == "not bvh":
        path.write_bytes(b"\x89PNG\r\n\x1a\n not a motion")
    else:
        bvh.write(path, m)
        out = tmp_path / "out.txt"
    r = subprocess.run(
        [sys.executable, "-m", "styleerd.cli", "transfer", str(path), "--style", "elderly", "-o", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2 and expected in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["in.bvh"]


def test_a_stream_whose_content_changes_midway(shared_data, model, tmp_path):
    """Two test clips of different contents back to back, labels inferred online."""
    from styleerd.data.datasets import load_motion
    from styleerd.data.windows import split_takes

    g, meta = model
    clips = find_clips(shared_data, "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    walk_clip = next(c for c in clips if split[c.name] == "test" and c.content == "walk" and c.style == "normal")
    wave_clip = next(
        c for c in clips if split[c.name] == "test" and c.content == "wave-both-hands" and c.style == "normal"
    )
    a, b = load_motion(walk_clip), load_motion(wave_clip)
    joined = Motion(
        a.skeleton, np.concatenate([a.rotations, b.rotations]), np.concatenate([a.positions, b.positions]), a.fps
    )
    bvh.write(tmp_path / "joined.bvh", joined)
    lines = []
    done = transfer_file(
        tmp_path / "joined.bvh",
        tmp_path / "out.bvh",
        g,
        meta["data"]["fps"],
        TransferOptions({"elderly": 1.0}),
        report=lines.append,
    )
    out = bvh.read(tmp_path / "out.bvh")
    assert out.n_frames == joined.n_frames and np.isfinite(bvh.channel_values(out)).all()
    assert done.labels == ("normal", "wave-both-hands")  # the labeller followed the change


@pytest.mark.parametrize("backend", ["numpy", "numba", "onnx"])
def test_slots_stepped_apart_equal_independent_streams(model, backend):
    """A server's pool: three slots with their own labels (given or inferred) and targets,
    stepped in changing subsets, one slot reset and given to a new stream midway; each slot
    equals a stylizer of its own."""
    from styleerd.motion.procedural import walk
    from styleerd.runtime.channels import ChannelStylizer

    g, _ = model
    m = walk(2.0, fps=30.0)
    values = bvh.channel_values(m)
    setups = [
        ("normal", "walk", {"feminine": 1.0}),
        (None, None, {"elderly": 0.6, "normal": 0.4}),
        ("exhausted", None, {"normal": 1.0}),
    ]
    pool = ChannelStylizer(g, m.skeleton, {"normal": 1.0}, "normal", "walk", n_streams=3, backend=backend)
    for k, (s, c, t) in enumerate(setups):
        pool.configure([k], s, c, t)
    singles = [ChannelStylizer(g, m.skeleton, t, s, c, backend=backend) for s, c, t in setups]
    frame = [0, 0, 0]
    rng = np.random.default_rng(1)
    for step in range(80):
        if step == 40:
            pool.reset([1])
            pool.configure([1], "normal", "run", {"active": 1.0})
            singles[1], frame[1] = ChannelStylizer(g, m.skeleton, {"active": 1.0}, "normal", "run", backend=backend), 0
        rows = np.nonzero(rng.random(3) < 0.6)[0]
        if not len(rows):
            continue
        out = pool.step(np.stack([values[frame[r]] for r in rows]), rows)
        for i, r in enumerate(rows):
            assert np.abs(out[i] - singles[r].step(values[frame[r]])[0]).max() < 1e-3, (step, r)  # degrees
            frame[r] = (frame[r] + 1) % len(values)


@pytest.mark.parametrize("fps", [30.0, 60.0])
def test_root_speed_gives_an_elderly_walk_the_normal_pace_with_feet_planted(shared_data, model, tmp_path, fps):
    """`transfer --root-speed`: a real elderly test walk taken to normal covers ground at a
    normal walker's pace (elderly performers walk at about 0.7 of it), on the input's heading
    and height, with planted feet kept planted by the cleanup; at the model's rate and at 60 fps."""
    from styleerd.data.windows import split_takes
    from styleerd.eval.metrics import foot_skate
    from styleerd.motion.kinematics import foot_contacts
    from styleerd.motion.skeleton import BodyRoles

    clips = find_clips(shared_data, "bandai-namco-2")
    split = split_takes({c.name: (c.dataset, c.style, c.content) for c in clips})
    clip = next(c for c in clips if split[c.name] == "test" and c.style == "elderly" and c.content == "walk")
    src = resample(bvh.read(clip.path), fps)
    bvh.write(tmp_path / "in.bvh", src)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "transfer",
            tmp_path / "in.bvh",
            "--style",
            "normal",
            "--root-speed",
            "-o",
            tmp_path / "out.bvh",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    out = bvh.read(tmp_path / "out.bvh")
    assert out.n_frames == src.n_frames and out.skeleton == src.skeleton
    g_in, g_out = world(src), world(out)
    hips = 1  # joint 0 is the reference node above the hips
    step_in, step_out = np.diff(g_in[:, hips][:, [0, 2]], axis=0), np.diff(g_out[:, hips][:, [0, 2]], axis=0)
    ratio = np.linalg.norm(step_out, axis=-1).sum() / np.linalg.norm(step_in, axis=-1).sum()
    print(f"{fps} fps: ground covered {ratio:.3f} x the input's")
    assert 1.2 < ratio < 2.0
    moving = np.linalg.norm(step_in, axis=-1) > 1e-3
    cos = (step_in * step_out).sum(-1)[moving] / (np.linalg.norm(step_in, axis=-1) * np.linalg.norm(step_out, axis=-1))[
        moving
    ]
    assert cos.mean() > 0.99  # the input's heading
    assert moved_by_the_cleanup_at_most(g_out[:, hips, 1], g_in[:, hips, 1], src.skeleton)  # and height
    roles = BodyRoles.of(src.skeleton)
    ankles = (roles.feet[0], roles.feet[2])
    previous = np.concatenate([g_in[:1], g_in[:-1]])
    planted = foot_contacts(g_in, previous, ankles, fps, 0.25 * roles.leg_length) > 0
    skate_in, skate_out = foot_skate(g_in[None], ankles, planted[None]), foot_skate(g_out[None], ankles, planted[None])
    print(f"foot skate on planted frames: input {skate_in:.3f}, output {skate_out:.3f} (units per frame)")
    assert skate_out <= 2 * skate_in + 0.05
    if fps == 30:  # the model's rate: a live stream of the file (the server's path) gives the file's frames
        from styleerd.runtime.channels import ChannelStylizer

        live = ChannelStylizer(model[0], src.skeleton, {"normal": 1.0}, fps=fps, root_speed=True)
        values = bvh.channel_values(src)
        streamed = np.stack([live.step(values[t])[0] for t in range(len(values))])
        assert np.abs(streamed - bvh.channel_values(out)).max() < 1e-3


@pytest.mark.parametrize("fps", [30.0, 60.0])
def test_a_rest_pose_before_the_take_is_a_cut_and_the_take_after_it_is_kept(model, tmp_path, fps):
    """Many takes start with a frame of rest pose somewhere else (CMU's retargeted ones do): after
    that cut, the identity transfer's hands and feet are the take's own at once, whatever the rate
    (a 60 fps frame between two of the model's is not half the rest pose) and with the feet
    cleaned (no foot held back where the rest pose stood). Before: 93 cm off at either rate; the
    walk's own identity transfer, without the rest pose, is up to 8 cm off (the network's pose of it)."""
    from styleerd.motion.kinematics import forward_positions
    from styleerd.motion.procedural import walk

    g, _ = model
    m = walk(2.0, fps=fps)
    sk = m.skeleton
    rest = Motion(sk, quat.identity((1, sk.n_joints)), sk.offsets[None].copy(), fps)
    positions = m.positions.copy()
    positions[:, 0, [0, 2]] += 200.0  # the take starts 2 m from the rest pose
    take = Motion(sk, np.concatenate([rest.rotations, m.rotations]), np.concatenate([rest.positions, positions]), fps)
    bvh.write(tmp_path / "in.bvh", take)
    take = bvh.read(tmp_path / "in.bvh")
    transfer_file(
        tmp_path / "in.bvh", tmp_path / "out.bvh", g, 30.0, TransferOptions({"normal": 1.0}, input_style="normal")
    )
    out = bvh.read(tmp_path / "out.bvh")
    ends = [sk.index(n) for n in ("LeftHand", "RightHand", "LeftFoot", "RightFoot")]
    given, styled = (forward_positions(x.rotations, x.positions, sk.parents)[1:8, ends] for x in (take, out))
    assert np.linalg.norm(styled - given, axis=-1).max() < 15.0
