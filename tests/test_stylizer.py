import numpy as np
import pytest
import torch
from conftest import walking_motion

from styleerd.data.features import FeatureStats, motion_features
from styleerd.errors import StyleERDError
from styleerd.model.generator import GeneratorConfig, StyleERD
from styleerd.model.labeller import OnlineLabeller
from styleerd.motion import quat
from styleerd.motion.humanoid import eyes_above_head, limb_ends
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import BodyRoles
from styleerd.runtime.offline import stylise_motion
from styleerd.runtime.stylizer import POSES, StreamStylizer, target_weights

STYLES = ("angry", "normal", "old")
CONTENTS = ("walk", "run")


@pytest.fixture(scope="module")
def model():
    m = walking_motion(100)
    f, _ = motion_features(m)
    torch.manual_seed(0)
    g = StyleERD(
        GeneratorConfig(m.skeleton.n_joints, STYLES, CONTENTS, neutral_layers=2, style_layers=2),
        m.skeleton,
        FeatureStats.fit(f, m.skeleton.n_joints),
    )
    for p in g.parameters():
        p.data += 0.05 * torch.randn_like(p)
    return g.eval()


def test_offline_equals_streaming_and_keeps_the_root_trajectory(model):
    m = walking_motion(40)
    out = stylise_motion(model, m, "normal", "walk", {"old": 1.0})
    s = StreamStylizer(model, "normal", "walk", {"old": 1.0})
    for t in range(40):
        r, _p = s.step(m.rotations[t], m.positions[t])
        assert np.abs(r[0] - out.rotations[t]).max() <= 1e-6
    _, g_in = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
    _, g_out = forward_kinematics(out.rotations, out.positions, m.skeleton.parents)
    assert np.array_equal(out.positions[:, 0], m.positions[:, 0])
    assert not np.allclose(g_in[:, 1:], g_out[:, 1:], atol=1e-3)


def unfamiliar_weights(now: np.ndarray) -> np.ndarray:
    """The blend's weights over frames from each frame's unfamiliarity ``now``, as the rule says: the
    first frame's at once, then ``now`` but down by at most RELEASE and up by at most RISE a frame."""
    from styleerd.model.config import RELEASE, RISE

    weight = now.copy()
    for t in range(1, len(now)):
        weight[t] = min(max(now[t], weight[t - 1] - RELEASE), weight[t - 1] + RISE)
    return weight


def test_unfamiliarity_moves_by_at_most_rise_or_release_a_frame(model):
    """A stream whose unfamiliarity swings every few frames (a wave at the edge of what the network
    knows): the stylizer's weights are ``unfamiliar_weights`` frame by frame (the measured
    unfamiliarity replaced by the swings), each frame's move within RISE up and RELEASE down, where
    it rose at once before."""
    from styleerd.model.config import RELEASE, RISE

    now = np.clip(0.6 + 0.5 * np.sin(np.arange(60) * 1.1), 0.0, 1.0)
    weight = unfamiliar_weights(now)
    assert np.diff(weight).max() == pytest.approx(RISE) and np.diff(weight).min() == pytest.approx(-RELEASE)
    assert np.diff(now).max() > 2 * RISE
    s = StreamStylizer(model, "normal", "walk", {"old": 1.0}, n_streams=1, pose="input")
    shown = []
    for u in now:  # the stylizer's bookkeeping, with the kernel's clamp of the measured unfamiliarity
        least, most = s._unfamiliar_bounds(slice(None))[0]
        s.unfamiliar[0] = min(max(u, least), most)
        s.started[0] = True
        shown.append(s.unfamiliar[0])
    np.testing.assert_allclose(shown, weight, atol=1e-12)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("pose", ["network", "input", "input with posture", "input with posture offsets"])
def test_stream_equals_the_generator_forward_on_whole_clip_features(model, backend, pose, monkeypatch):
    """The compiled streaming path (features, normalisation, root put back on its heading)
    against the training-side path: motion_features + FeatureStats.normalize, the torch
    generator over the whole window, quat.mul for the root. Pose "input", composed here by
    scipy: the generator's identity output (target = the input's style) against the input gives
    each frame's unfamiliarity (mean joint angle, as ``unfamiliar_weights`` lets it rise and fall), which
    slerps from the styled output to the input's rotations turned by the change from the identity
    output to the styled one (a model with postures: turned by the target's posture less the input
    style's, scipy's rotation vectors; with posture offsets too, then turned so that the joints go
    where the input's are moved by the offsets, ``torch_quat.reach``, tested against scipy below);
    the thresholds are put inside this random network's range, so the frames span the blend."""
    from scipy.spatial.transform import Rotation, Slerp

    from styleerd.model import torch_quat
    from styleerd.motion.kinematics import facing_directions, heading_rotations
    from styleerd.motion.skeleton import BodyRoles

    m = walking_motion(30)
    f, traj = motion_features(m)
    x = torch.as_tensor(model.stats().normalize(f), dtype=torch.float32)[None]
    eye_s, eye_c = torch.eye(len(STYLES)), torch.eye(len(CONTENTS))

    def generator(target: torch.Tensor) -> np.ndarray:
        with torch.no_grad():
            rot, _, _ = model(x, eye_s[[1]], eye_c[[0]], target[None])
        out = rot[0].double().numpy()
        out[:, 0] = quat.mul(traj[:, 3:7], out[:, 0])
        return quat.normalize(out)

    mix = torch.tensor([0.3, 0.0, 0.7])  # a mixture: 0.3 angry, 0.7 old
    want = generator(mix)
    posture = np.random.default_rng(5).normal(0.0, 0.4, (len(STYLES), m.skeleton.n_joints, 3))
    offsets = np.random.default_rng(6).normal(0.0, 5.0, (len(STYLES), m.skeleton.n_joints, 3))
    monkeypatch.setattr(model, "posture", torch.tensor(posture) if "posture" in pose else None)
    monkeypatch.setattr(model, "posture_offsets", torch.tensor(offsets) if "offsets" in pose else None)
    if pose != "network":
        scipy = lambda q: Rotation.from_quat(q.reshape(-1, 4), scalar_first=True)
        same = generator(eye_s[1])
        angles = np.degrees((scipy(same).inv() * scipy(m.rotations)).magnitude()).reshape(30, -1).mean(-1)
        low, high = np.percentile(angles, [30, 70])
        monkeypatch.setattr(model, "familiar", (low, high))
        weight = unfamiliar_weights(np.clip((angles - low) / (high - low), 0, 1))
        assert 0 < weight.mean() < 1 and ((weight > 0) & (weight < 1)).any()
        change = (
            scipy(same).inv() * scipy(want)
            if model.posture is None
            else Rotation.from_rotvec(np.tile(0.3 * posture[0] + 0.7 * posture[2] - posture[1], (30, 1)))
        )
        turned = (scipy(m.rotations) * change).as_quat(scalar_first=True).reshape(want.shape)
        if model.posture_offsets is not None:
            _, given = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
            roles = BodyRoles.of(m.skeleton)
            heading = heading_rotations(facing_directions(given, roles.left, roles.right))
            moved = quat.mul_vec(heading[:, None], 0.3 * offsets[0] + 0.7 * offsets[2] - offsets[1])
            turned = torch_quat.reach(
                torch.from_numpy(turned),
                torch.from_numpy(m.skeleton.offsets),
                torch.from_numpy(given - given[:, :1] + moved),
                [int(p) for p in m.skeleton.parents],
                limb_ends(m.skeleton).tolist(),
            ).numpy()
        want = np.stack(
            [
                np.stack(
                    [
                        Slerp([0, 1], scipy(np.stack([want[t, j], turned[t, j]])))(weight[t]).as_quat(scalar_first=True)
                        for j in range(want.shape[1])
                    ]
                )
                for t in range(30)
            ]
        )
    s = StreamStylizer(model, "normal", "walk", {"old": 0.7, "angry": 0.3}, backend=backend, pose=pose.split()[0])
    assert (s.model.posture_offsets is None) == ("offsets" not in pose)
    got = np.stack([s.step(m.rotations[t], m.positions[t])[0][0] for t in range(30)])
    if pose == "network":
        assert np.abs(got - want).max() <= 1e-5
    else:  # the same float32 outputs (within 1e-5 a component) composed three at a time: within 1e-4 rad
        assert np.abs(quat.angle_between(got, want)).max() <= 1e-4


@pytest.mark.parametrize("backend", ["numpy", "numba", "onnx"])
def test_fast_backends_give_the_reference_output(model, backend):
    m = walking_motion(30)
    ref = stylise_motion(model, m, "normal", "walk", {"old": 0.6, "angry": 0.4}, backend="torch")
    out = stylise_motion(model, m, "normal", "walk", {"old": 0.6, "angry": 0.4}, backend=backend)
    assert np.abs(out.rotations - ref.rotations).max() <= 1e-5


def test_streaming_is_causal(model):
    m = walking_motion(30)
    a = stylise_motion(model, m, "normal", "walk", {"angry": 1.0})
    rot = m.rotations.copy()
    rot[20:] = rot[20:][:, :, [0, 2, 1, 3]]
    b = stylise_motion(model, Motion(m.skeleton, rot, m.positions, m.fps), "normal", "walk", {"angry": 1.0})
    assert np.array_equal(a.rotations[:20], b.rotations[:20])


def test_batched_streams_equal_single_streams(model):
    m1, m2 = walking_motion(20, seed=1), walking_motion(20, seed=2)
    batch = StreamStylizer(model, "normal", "walk", {"old": 1.0}, n_streams=2)
    singles = [StreamStylizer(model, "normal", "walk", {"old": 1.0}) for _ in range(2)]
    for t in range(20):
        r, _ = batch.step(np.stack([m1.rotations[t], m2.rotations[t]]), np.stack([m1.positions[t], m2.positions[t]]))
        for k, m in enumerate((m1, m2)):
            assert np.allclose(r[k], singles[k].step(m.rotations[t], m.positions[t])[0][0], atol=1e-5)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_rows_in_order_step_as_views_and_equal_the_same_streams_in_any_order(model, backend, monkeypatch):
    """A server steps the streams whose frames came: in order and consecutive (all of them, a
    connection's crowd) they are a slice, every per-stream array a view; in any other order,
    indices. Both give each stream the same frames, and streams not stepped keep their state."""
    from styleerd.runtime import stylizer

    assert stylizer.as_rows([3, 4, 5]) == slice(3, 6) and stylizer.as_rows([7]) == slice(7, 8)
    assert list(stylizer.as_rows([5, 4, 3])) == [5, 4, 3] and list(stylizer.as_rows([1, 3])) == [1, 3]
    ms = [walking_motion(12, seed=k) for k in range(5)]
    targets = [{"old": 1.0}, {"angry": 1.0}, {"normal": 1.0}, {"old": 0.5, "angry": 0.5}, {"old": 1.0}]
    make = lambda: StreamStylizer(model, "normal", "walk", targets, n_streams=5, backend=backend)
    in_order, shuffled = make(), make()
    seen = []
    real = stylizer.StreamStylizer._advance
    monkeypatch.setattr(
        stylizer.StreamStylizer, "_advance", lambda self, sel, *a: seen.append(sel) or real(self, sel, *a)
    )
    frame = lambda t, rows: (np.stack([ms[k].rotations[t] for k in rows]), np.stack([ms[k].positions[t] for k in rows]))
    for t in range(12):
        a = in_order.step(*frame(t, [1, 2, 3]), [1, 2, 3])[0]
        b = shuffled.step(*frame(t, [3, 1, 2]), [3, 1, 2])[0]
        assert np.abs(a - b[[1, 2, 0]]).max() <= 1e-6, t
    assert seen[0] == slice(1, 4) and isinstance(seen[1], np.ndarray)
    assert not in_order.started[[0, 4]].any() and not shuffled.started[[0, 4]].any()


@pytest.mark.parametrize("backend", ["numpy", "numba", "onnx"])
def test_steps_split_over_threads_equal_one_thread_and_reject_as_a_whole(model, backend, monkeypatch):
    from styleerd.data import parallel
    from styleerd.runtime import stylizer

    # split even this small batch (two shards of 3): numpy's and onnx's on the stylizer's pool,
    # numba's inside its kernels
    monkeypatch.setattr(stylizer, "SHARD_FROM", {backend: 4})
    monkeypatch.setattr(parallel, "PARALLEL_FROM", 4)
    ms = [walking_motion(12, seed=k) for k in range(6)]
    targets = [{"old": 1.0}, {"angry": 0.5, "old": 0.5}, {"normal": 1.0}] * 2
    torch.manual_seed(1)
    labeller = OnlineLabeller(model.config.feature_dim, len(STYLES), len(CONTENTS), hidden=8).eval()
    one = StreamStylizer(model, None, None, targets, n_streams=6, backend=backend, labeller=labeller)
    two = StreamStylizer(model, None, None, targets, n_streams=6, backend=backend, labeller=labeller, threads=2)
    for t in range(12):
        rot, pos = np.stack([m.rotations[t] for m in ms]), np.stack([m.positions[t] for m in ms])
        if t == 6:
            absurd = pos.copy()
            absurd[4, 0] = 1e30  # a stream of the second shard: the whole frame is refused
            with pytest.raises(StyleERDError, match="stream 4: its values are too large"):
                two.step(rot, absurd)
            two.set_target({"angry": 1.0}, streams=[1, 5])
            one.set_target({"angry": 1.0}, streams=[1, 5])
        assert np.abs(two.step(rot, pos)[0] - one.step(rot, pos)[0]).max() <= 1e-5
    assert two.inferred_labels() == one.inferred_labels()


def test_numba_kernels_on_threads_from_two_callers_at_once_equal_one_thread(model, monkeypatch):
    """The numba stylizer on 2 threads splits its compiled kernels over them (numba's parallel
    loops); two such stylizers stepped from two Python threads at once (a server's callers)
    launch those loops concurrently. Every output equals the one-thread stylizer's."""
    from concurrent.futures import ThreadPoolExecutor

    import numba

    from styleerd.runtime import compiled

    monkeypatch.setenv("STYLEERD_CALIBRATE", "0")  # the fixed settings: the network on threads from 32 streams
    n, frames = 40, 10  # at least data.parallel.PARALLEL_FROM streams
    ms = [walking_motion(frames, seed=k) for k in range(n)]
    targets = [{"old": 1.0}, {"angry": 0.5, "old": 0.5}, {"normal": 1.0}, {"angry": 1.0}] * (n // 4)
    splits, on_shards = [], compiled.compiled_pair_step_on_shards

    def counted(shards, *args):
        splits.append(shards)
        return on_shards(shards, *args)

    monkeypatch.setattr(compiled, "compiled_pair_step_on_shards", counted)

    def run(threads: int) -> np.ndarray:
        st = StreamStylizer(model, "normal", "walk", targets, n_streams=n, backend="numba", threads=threads)
        return np.stack(
            [
                st.step(np.stack([m.rotations[t] for m in ms]), np.stack([m.positions[t] for m in ms]))[0]
                for t in range(frames)
            ]
        )

    want = run(1)
    assert splits == []
    with ThreadPoolExecutor(2) as pool:
        got = list(pool.map(run, [2, 2]))
    threads = min(2, numba.config.NUMBA_NUM_THREADS)  # NUMBA_NUM_THREADS=1: the kernels stay on the calling thread
    assert splits == (
        [threads] * (2 * frames) if threads > 1 else []
    )  # two stylizers, one pass a step (the target's and the identity's on one encoder and neutral stack)
    for out in got:
        assert np.abs(out - want).max() <= 1e-5


def test_a_failing_shard_releases_the_others(model, monkeypatch):
    """A sharded step's shards meet at a barrier before any state changes: a shard that fails
    before it releases the others (its error is raised, no stream advanced, nothing hangs)."""
    import threading

    from styleerd.runtime import stylizer

    monkeypatch.setattr(stylizer, "SHARD_FROM", {"numpy": 3})
    ms = [walking_motion(8, seed=k) for k in range(6)]
    one = StreamStylizer(model, "normal", "walk", {"old": 1.0}, n_streams=6, backend="numpy")
    three = StreamStylizer(model, "normal", "walk", {"old": 1.0}, n_streams=6, backend="numpy", threads=3)
    frame = lambda t: (np.stack([m.rotations[t] for m in ms]), np.stack([m.positions[t] for m in ms]))
    features, raised = three._features, []

    def fails_on_the_last_shard(rotations, positions, sel):
        if sel.start == 4:
            raise MemoryError("out of memory")
        return features(rotations, positions, sel)

    def step():
        try:
            three.step(*frame(0))
        except MemoryError as e:
            raised.append(e)

    three._features = fails_on_the_last_shard
    stepper = threading.Thread(target=step, daemon=True)
    stepper.start()
    stepper.join(timeout=60)
    assert not stepper.is_alive() and len(raised) == 1
    three._features = features
    assert not three.started.any()
    for t in range(3):
        assert np.abs(three.step(*frame(t))[0] - one.step(*frame(t))[0]).max() <= 1e-5


def test_style_switch_blends_without_a_pop(model):
    m = walking_motion(60)
    s = StreamStylizer(model, "normal", "walk", {"normal": 1.0}, blend_frames=10)
    poses = []
    for t in range(60):
        if t == 30:
            s.set_target(target_weights(model, "angry"))
        r, p = s.step(m.rotations[t], m.positions[t])
        poses.append(forward_kinematics(r[0], p[0], m.skeleton.parents)[1])
    jumps = np.abs(np.diff(np.array(poses), axis=0)).max(axis=(1, 2))
    assert jumps[29:40].max() <= 3 * np.median(jumps[5:29]) + 1e-9


def test_bad_frame_is_rejected_and_state_kept(model):
    m = walking_motion(5)
    s = StreamStylizer(model, "normal", "walk", {"old": 1.0})
    ref = StreamStylizer(model, "normal", "walk", {"old": 1.0})
    s.step(m.rotations[0], m.positions[0])
    ref.step(m.rotations[0], m.positions[0])
    bad = m.positions[1].copy()
    bad[3, 1] = np.nan
    with pytest.raises(StyleERDError, match="joint 'Head'"):
        s.step(m.rotations[1], bad)
    absurd = m.positions[1].copy()
    absurd[0] = 1e30  # finite, but the network would overflow
    with pytest.raises(StyleERDError, match="too large to stylise"):
        s.step(m.rotations[1], absurd)
    assert np.array_equal(s.step(m.rotations[1], m.positions[1])[0], ref.step(m.rotations[1], m.positions[1])[0])


def test_target_weights_validate():
    class M:
        class config:
            neutral_style = "normal"

    assert target_weights(M, "old", 0.3) == {"old": 0.3, "normal": 0.7}
    assert target_weights(M, mix={"old": 1, "angry": 3}) == {"old": 0.25, "angry": 0.75}
    assert target_weights(M, intensity=0.5, mix={"old": 1, "angry": 1}) == {"old": 0.25, "angry": 0.25, "normal": 0.5}
    with pytest.raises(StyleERDError):
        target_weights(M, "old", 5.0)


def test_labels_not_given_are_inferred_causally_and_given_labels_win(model):
    torch.manual_seed(1)
    labeller = OnlineLabeller(model.config.feature_dim, len(STYLES), len(CONTENTS), hidden=8).eval()
    m = walking_motion(30)
    runs = []
    for rot in (m.rotations, np.concatenate([m.rotations[:20], m.rotations[20:][:, :, [0, 2, 1, 3]]])):
        s = StreamStylizer(model, None, None, {"old": 1.0}, labeller=labeller)
        out = [s.step(rot[t], m.positions[t])[0][0] for t in range(30)]
        runs.append(np.array(out))
        style, content = s.labels
        assert np.allclose(style.sum(-1), 1.0) and np.allclose(content.sum(-1), 1.0)
        assert s.inferred_labels()[0][0] in STYLES
    assert np.array_equal(runs[0][:20], runs[1][:20])  # causal with the labeller in the loop
    assert not np.allclose(runs[0][20:], runs[1][20:])
    given = StreamStylizer(model, "normal", None, {"old": 1.0}, labeller=labeller)
    given.step(m.rotations[0], m.positions[0])
    assert given.labels[0].tolist() == [[0.0, 1.0, 0.0]]  # the given style, one-hot
    with pytest.raises(StyleERDError, match="labeller does not fit"):
        StreamStylizer(model, None, None, {"old": 1.0}, labeller=OnlineLabeller(5, 3, 2))


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_labeller_state_unlike_its_training_streams_tells_the_neutral_style(model, backend):
    """``Familiarity`` on the stylizer's inferred labels: wholly familiar states change nothing,
    unfamiliar ones tell the neutral style on every frame, whatever the posterior."""
    from styleerd.model.stored import Familiarity

    torch.manual_seed(1)
    labeller = OnlineLabeller(model.config.feature_dim, len(STYLES), len(CONTENTS), hidden=8).eval()
    with torch.no_grad():
        labeller.style.bias[0] = 10.0  # sure of "angry" on every frame
    m = walking_motion(12)

    def told(far: float) -> np.ndarray:
        groups = np.ones(2, np.float32)
        labeller.familiar = (
            None
            if far == 0
            else Familiarity(
                np.array([4]),
                np.eye(8, dtype=np.float32),
                np.zeros((2, 3, 8), np.float32),
                groups * far / 2,
                groups * far,
            )
        )
        s = StreamStylizer(model, None, None, {"old": 1.0}, labeller=labeller, backend=backend)
        out = []
        for t in range(12):
            s.step(m.rotations[t], m.positions[t])
            out.append(s.labels[0][0].copy())
        return np.array(out)

    plain = told(0)
    assert np.allclose(told(1e6), plain)  # every state within a huge distance of a mean
    assert np.allclose(told(1e-6), np.eye(3)[STYLES.index(model.config.neutral_style)])
    assert (plain[:, 0] > 0.999).all()  # sure of angry without it


def test_an_inferred_style_follows_the_labellers_readings_over_style_seconds(model):
    """A labeller whose reading swings between two styles every frame (as the shipped one's did on
    Bandai-Namco-1's musical wave, read as active every few frames, and the style's change swung the
    hands with it): the style the stylizer uses is the readings' running mean over
    STYLE_SECONDS once the stream's first STYLE_SETTLED seconds are read (those taken as they come), a
    frame's change of it small."""
    from styleerd.runtime.stylizer import STYLE_SECONDS, STYLE_SETTLED

    labeller = OnlineLabeller(model.config.feature_dim, len(STYLES), len(CONTENTS), hidden=8).eval()
    s = StreamStylizer(model, None, "walk", {"old": 1.0}, labeller=labeller)
    T, settled = 60, int(STYLE_SETTLED * 30.0)
    readings = np.eye(len(STYLES), dtype=np.float32)[[t % 2 for t in range(T)]]  # angry, normal, angry ...
    step, frame = s.labeller.step, [0]

    def swinging(x, rows):
        _, content, state = step(x, rows)
        return readings[frame[0]][None], content, state

    s.labeller.step = swinging
    m, used = walking_motion(T), []
    for t in range(T):
        frame[0] = t
        s.step(m.rotations[t], m.positions[t])
        used.append(s.labels[0][0].copy())
    ease, expected = 1.0 - np.exp(-1.0 / (STYLE_SECONDS * 30.0)), list(readings[: settled + 1])
    for r in readings[settled + 1 :]:
        expected.append(expected[-1] + ease * (r - expected[-1]))
    np.testing.assert_allclose(used, expected, atol=1e-6)
    assert np.abs(np.diff(used, axis=0))[settled + 1 :].max() < 0.1  # the readings swing by 1 a frame


def test_root_speed_scales_each_ground_step_by_the_networks_speed_online(model, monkeypatch):
    """``root_speed``: each frame's ground step of the input root is scaled by the network's
    root speed over the input's (smoothed, clamped), height kept; checked against the torch
    generator's velocity output on the whole clip's features. With pose "input" the scale fades
    to 1 as the input is unfamiliar (the legs are then the input's own, and so is the pace), by
    the last frame's unfamiliarity. Off, the root is the input's."""
    m = walking_motion(60)
    f, _ = motion_features(m)
    stats = model.stats()
    x = torch.tensor(stats.normalize(f), dtype=torch.float32)[None]
    eye_s, eye_c = torch.eye(len(STYLES)), torch.eye(len(CONTENTS))
    with torch.no_grad():
        _, vel, _ = model(x, eye_s[[1]], eye_c[[0]], eye_s[[2]])
    root = model.layout.velocities.start
    net = vel[0, :, :3].double().numpy() * stats.std[root : root + 3] + stats.mean[root : root + 3]
    given = f[:, root : root + 3]
    leg = StreamStylizer(model, "normal", "walk", {"old": 1.0}).roles.leg_length
    # this random network's identity output is far from the input: thresholds inside its range, so the
    # pose "input" run is familiar on some frames and not on others (a stylizer reads them when made)
    monkeypatch.setattr(model, "familiar", (0.0, 1e9))  # u = the mean angle / 1e9: read it back as the angle
    probe = StreamStylizer(model, "normal", "walk", {"old": 1.0}, pose="input")
    angles = []
    for t in range(60):
        probe.step(m.rotations[t], m.positions[t])
        angles.append(probe.unfamiliar[0] * 1e9)
    low, high = np.percentile(angles, [30, 70])
    monkeypatch.setattr(model, "familiar", (low, high))
    for pose in ("network", "input"):
        on, off = (
            StreamStylizer(model, "normal", "walk", {"old": 1.0}, root_speed=True, pose=pose),
            StreamStylizer(model, "normal", "walk", {"old": 1.0}, pose=pose),
        )
        ratio, offset, expected, faded = 1.0, np.zeros(3), [], []
        for t in range(60):
            s_in, s_net = np.hypot(given[t, 0], given[t, 2]), np.hypot(net[t, 0], net[t, 2])
            now = np.clip(s_net / s_in, 0.4, 2.5) if s_in > 0.05 * leg else 1.0
            unfamiliar = on.unfamiliar[0] if pose == "input" else 0.0  # the last frame's
            faded.append(unfamiliar)
            ratio = 0.7 * ratio + 0.3 * (1.0 + (now - 1.0) * (1.0 - unfamiliar))
            if t:
                step = m.positions[t, 0] - m.positions[t - 1, 0]
                offset += (ratio - 1) * np.array([step[0], 0.0, step[2]])
            expected.append(m.positions[t, 0] + offset)
            r_on, p_on = on.step(m.rotations[t], m.positions[t])
            r_off, p_off = off.step(m.rotations[t], m.positions[t])
            assert np.array_equal(r_on, r_off) and np.array_equal(
                p_off[0], m.positions[t]
            )  # poses unchanged; off: the input's root
            assert np.allclose(p_on[0, 0], expected[t], atol=1e-4), (pose, t)
            assert p_on[0, 0, 1] == m.positions[t, 0, 1] and np.array_equal(p_on[0, 1:], m.positions[t, 1:])
        assert (
            np.abs(np.array(expected) - m.positions[:, 0]).max() > 0.1
        )  # the random network's speed is not the input's
    assert 0.0 < np.mean(faded) < 1.0  # the input pose's run faded the scale part of the time


def test_root_speed_is_causal(model):
    m = walking_motion(40)
    m2 = Motion(m.skeleton, m.rotations.copy(), m.positions.copy(), m.fps)
    m2.positions[25:, 0] += np.array([30.0, 0.0, 50.0])  # a future jump of the root
    m2.rotations[25:, 3] = quat.mul(m2.rotations[25:, 3], quat.from_angle_axis(np.array([0.8]), np.array([1.0, 0, 0])))
    a, b = (
        StreamStylizer(model, "normal", "walk", {"old": 1.0}, root_speed=True),
        StreamStylizer(model, "normal", "walk", {"old": 1.0}, root_speed=True),
    )
    for t in range(25):
        ra, pa = a.step(m.rotations[t], m.positions[t])
        rb, pb = b.step(m2.rotations[t], m2.positions[t])
        assert np.array_equal(ra, rb) and np.array_equal(pa, pb)


def test_numba_kernels_on_threads_with_parts_root_speed_and_some_rows_equal_one_thread(model):
    """Every path of the many-stream step through the threaded kernels: body parts with their
    own target (a backend pass each) and the input's own arms, the root speed, steps of some
    streams only (by index and as a slice), a stream reset mid-way: as on one thread."""
    n, frames = 48, 8
    ms = [walking_motion(frames, seed=k) for k in range(n)]
    frame = lambda t, rows=slice(None): (
        np.stack([m.rotations[t] for m in ms])[rows],
        np.stack([m.positions[t] for m in ms])[rows],
    )
    make = lambda threads: StreamStylizer(
        model,
        "normal",
        "walk",
        {"old": 1.0},
        n_streams=n,
        backend="numba",
        threads=threads,
        parts="legs=angry,arms=input",
        root_speed=True,
    )
    one, two = make(1), make(2)
    some = np.arange(0, n, 3)  # 16 streams: below PARALLEL_FROM
    most = np.arange(40)  # 40: at or above it
    # Not the same bits: each thread's shard is a matrix product of another height, and BLAS
    # sums float32 products in an order that depends on the height and the CPU. So the bound is
    # float32's: rotations (unit quaternions) within ROT_TOL, about 80 float32 ulps of 1; the root
    # moves by sum((ratio - 1) * step) with ratio <= 2.5 taken from the same float32 outputs, so
    # its offset is within 2.5 * ROT_TOL of the input's path length so far (relative, not absolute).
    ROT_TOL = 1e-5
    path = np.zeros(n)
    for t in range(frames):
        for st in (one, two):
            if t == 4:
                st.reset([5, 6])
        rows = [None, most, some][t % 3]
        got = [st.step(*frame(t, slice(None) if rows is None else rows), rows=rows) for st in (one, two)]
        if t:
            path += np.linalg.norm(np.stack([m.positions[t, 0] - m.positions[t - 1, 0] for m in ms]), axis=-1)
        moved = path if rows is None else path[rows]
        bound = 2.5 * ROT_TOL * moved + 8 * np.finfo(np.float64).eps * np.abs(got[0][1][:, 0]).max(-1)
        assert np.abs(got[0][0] - got[1][0]).max() <= ROT_TOL, t
        assert (np.abs(got[0][1][:, 0] - got[1][1][:, 0]).max(-1) <= bound).all(), t
        assert np.array_equal(got[0][1][:, 1:], got[1][1][:, 1:]), t  # the other joints' positions are the input's


def test_kernel_threads_are_one_for_small_steps_and_at_most_numbas():
    """A step's compiled kernels run on the threads asked for, capped at numba's, from
    ``PARALLEL_FROM`` streams; numba uses a layer that allows concurrent launches."""
    import numba

    from styleerd.data.parallel import PARALLEL_FROM, kernel_threads

    assert kernel_threads(1, 10_000) == 1 and kernel_threads(8, PARALLEL_FROM - 1) == 1
    assert kernel_threads(10_000, PARALLEL_FROM) == numba.config.NUMBA_NUM_THREADS == numba.get_num_threads()
    assert numba.config.THREADING_LAYER == "threadsafe"


def test_the_stream_profile_accounts_for_every_part_of_a_step(tmp_path):
    """benchmarks/profile_streams.py times each compiled kernel of a many-stream step from Python
    (on 2 threads: the parallel ones); the parts and the rest add up to the step."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    out = tmp_path / "profile.json"
    root = Path(__file__).parents[1]
    subprocess.run(
        [
            sys.executable,
            "benchmarks/profile_streams.py",
            "--streams",
            "40",
            "--steps",
            "5",
            "--rounds",
            "1",
            "--json",
            str(out),
        ],
        cwd=root,
        check=True,
        capture_output=True,
        timeout=600,
    )
    r = json.loads(out.read_text())["rounds"][0]
    parts = [r["features_us"], r["network_us"], r["root_on_heading_us"]]
    assert all(p > 0 for p in parts) and abs(sum(parts) + r["rest_us"] - r["step_us"]) < 1.0


def test_without_a_thread_safe_layer_the_kernels_stay_on_one_thread(model, monkeypatch):
    """Where neither OpenMP nor TBB loads, numba's only layer could not take concurrent launches:
    the kernels then run on the calling thread, and a stylizer asked for 2 threads still steps."""
    import numba

    from styleerd.data import parallel

    load = parallel.importlib.import_module

    def unloadable(name, *args, **kwargs):  # the layers' pools only: numba imports other modules lazily
        if name in ("numba.np.ufunc.tbbpool", "numba.np.ufunc.omppool"):
            raise OSError(f"{name}: libgomp.so.1: cannot open shared object file")
        return load(name, *args, **kwargs)

    monkeypatch.setattr(parallel.importlib, "import_module", unloadable)
    parallel.threadsafe_layer.cache_clear()
    try:
        assert parallel.kernel_threads(2, 1000) == 1
        ms = [walking_motion(3, seed=k) for k in range(40)]
        frame = lambda t: (np.stack([m.rotations[t] for m in ms]), np.stack([m.positions[t] for m in ms]))
        one, two = (
            StreamStylizer(model, "normal", "walk", {"old": 1.0}, n_streams=40, backend="numba", threads=k)
            for k in (1, 2)
        )
        for t in range(3):
            assert np.abs(two.step(*frame(t))[0] - one.step(*frame(t))[0]).max() <= 1e-5
    finally:
        monkeypatch.undo()
        parallel.threadsafe_layer.cache_clear()
    assert parallel.kernel_threads(2, 1000) == min(2, numba.config.NUMBA_NUM_THREADS)


def test_the_command_line_offers_the_stylizers_poses():
    """cli.py names the poses without importing the stylizer (numba): the same ones."""
    from styleerd.cli import POSES as CLI_POSES

    assert CLI_POSES == POSES


def reached(start, translations, given, axes, offsets, parents, limbs=None):
    """``runtime.stylizer._reach`` on a copy of the pose ``start`` (no two-bone limbs unless ``limbs``)."""
    from styleerd.runtime.stylizer import _children, _reach

    J = len(parents)
    first, children = _children(parents)
    got = start.copy()
    limbs = np.full(J, -1) if limbs is None else limbs
    _reach(got, translations, given, axes, offsets, parents, first, children, limbs, np.empty((J, 4)), np.empty((J, 3)))
    return got


def test_reach_turns_each_joint_by_the_shortest_arc_towards_its_childrens_targets():
    """``_reach`` (compiled) and its torch twin against scipy: down the chain, each joint but the root
    turned (in the world) by the shortest arc from its children's summed bone vectors to the summed
    vectors to where the input's joints are moved by the offsets (in the heading frame of the facing
    direction), so no bone turns about itself; with no offsets, the input's pose comes back."""
    from scipy.spatial.transform import Rotation

    from styleerd.model import torch_quat
    from styleerd.motion.kinematics import body_axes, heading_axes, heading_rotations
    from styleerd.runtime.stylizer import _children, _frame_axes

    m = walking_motion(5)
    sk, parents, J = m.skeleton, m.skeleton.parents, m.skeleton.n_joints
    first, children = _children(parents)
    assert [sorted(children[first[j] : first[j + 1]]) for j in range(J)] == [sk.children(j) for j in range(J)]
    assert max(np.bincount(parents[1:])) >= 3  # a joint with three children (the chest), one with two
    rng = np.random.default_rng(4)
    scipy = lambda q: Rotation.from_quat(q, scalar_first=True)
    for t in range(5):
        _, given = forward_kinematics(m.rotations[t], m.positions[t], parents)
        start = quat.normalize(m.rotations[t] + rng.normal(0, 0.2, (J, 4)))  # the input turned by a posture
        offsets = rng.normal(0, 0.15, (J, 3)) * np.linalg.norm(sk.offsets, axis=-1).mean()
        facing = np.array([np.sin(t), 0.0, np.cos(t)])
        if t % 2:  # the body's own frame (a posture measured so): the offsets' rotation from its axes, by scipy
            roles = BodyRoles.of(sk)
            axes = body_axes(given, 0, sk.names.index("Head"), roles.left, roles.right)
            targets = given + Rotation.from_matrix(axes.T).apply(offsets)
        else:
            axes = heading_axes(facing)
            targets = given + quat.mul_vec(heading_rotations(facing), offsets)
        compiled = np.empty((3, 3))  # the kernels' own axes (``_frame_axes``) are the numpy functions'
        joints = np.array([0, sk.names.index("Head"), *BodyRoles.of(sk).left, *BodyRoles.of(sk).right])
        _frame_axes(given, facing * 3.0, joints, bool(t % 2), compiled)
        assert np.abs(compiled - axes).max() < 1e-12
        G, X, want = [None] * J, np.zeros((J, 3)), [scipy(q) for q in start]
        for j in range(J):
            p = parents[j]
            G[j], X[j] = (want[j], given[j]) if p < 0 else (G[p] * want[j], X[p] + G[p].apply(m.positions[t, j]))
            kids = np.nonzero(parents == j)[0]
            if p < 0 or not len(kids):
                continue
            now = sum(G[j].apply(m.positions[t, k]) for k in kids)
            wanted = sum(targets[k] - X[j] for k in kids)
            axis = np.cross(now, wanted)
            angle = np.arctan2(np.linalg.norm(axis), now @ wanted)
            G[j] = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle) * G[j]
            want[j] = G[p].inv() * G[j]
        want = np.stack([w.as_quat(scalar_first=True) for w in want])

        got = reached(start, m.positions[t], given, axes, offsets, parents)
        assert np.degrees(quat.angle_between(got, want)).max() < 1e-9
        twin = torch_quat.reach(  # in the root's parent frame, relative to the root
            torch.from_numpy(start),
            torch.from_numpy(sk.offsets),
            torch.from_numpy(targets - given[0]),
            [int(p) for p in parents],
        ).numpy()
        assert np.degrees(quat.angle_between(twin, want)).max() < 1e-9

        same = reached(m.rotations[t], m.positions[t], given, axes, np.zeros((J, 3)), parents)
        assert np.degrees(quat.angle_between(same, m.rotations[t])).max() < 1e-6


def test_a_limb_puts_its_middle_joint_where_it_and_the_end_meet_their_targets_best():
    """``_reach`` with the skeleton's two-bone limbs (``limb_ends``: shoulder to hand, hip to foot) and
    its torch twin against scipy's optimiser: the elbow or knee lands on the point, at the upper bone's
    length from the limb's first joint, that minimises the squared distance to its own target plus
    the squared distance by which the lower bone misses the end's target; the lower bone then points
    at the end's target. A foot asked up its own shin comes up, where turning one joint at a time
    could only slide it along the shin (it stays put); with no offsets the pose is kept."""
    from scipy.optimize import minimize

    from styleerd.model import torch_quat
    from styleerd.motion.kinematics import heading_axes

    m = walking_motion(4)
    sk, parents, J = m.skeleton, m.skeleton.parents, m.skeleton.n_joints
    ends = limb_ends(sk)
    assert [sk.names[j] for j in np.nonzero(ends >= 0)[0]] == [
        "UpperLeg_L",
        "UpperLeg_R",
    ]  # its arms end at the forearm
    axes = heading_axes(np.array([0.0, 0.0, 1.0]))  # rows: +X, +Y, +Z, so the offsets are as they are

    def reached_at(start, t, offsets, limbs):
        _, given = forward_kinematics(m.rotations[t], m.positions[t], parents)
        got = reached(start, m.positions[t], given, axes, offsets, parents, limbs)
        return got, forward_kinematics(got, m.positions[t], parents)[1], given + offsets

    def miss(e, elbow, end, lower):  # what the limb's middle joint at e leaves of both targets, squared
        return np.sum((e - elbow) ** 2) + (np.linalg.norm(e - end) - lower) ** 2

    def on_sphere(v, upper):  # a point at upper from the limb's first joint, by two angles
        return upper * np.array([np.cos(v[0]) * np.cos(v[1]), np.sin(v[0]), np.cos(v[0]) * np.sin(v[1])])

    rng = np.random.default_rng(11)
    for t in range(4):
        start = quat.normalize(m.rotations[t] + rng.normal(0, 0.1, (J, 4)))
        offsets = rng.normal(0, 0.2, (J, 3)) * np.linalg.norm(sk.offsets, axis=-1).mean()
        got, g, targets = reached_at(start, t, offsets, ends)
        for j in np.nonzero(ends >= 0)[0]:
            h = ends[j]
            k = parents[h]
            upper, lower = np.linalg.norm(m.positions[t, k]), np.linalg.norm(m.positions[t, h])
            elbow, end = targets[k] - g[j], targets[h] - g[j]
            d = elbow / np.linalg.norm(elbow)
            best = minimize(
                lambda v, *args: miss(on_sphere(v, upper=args[0]), *args[1:]),
                [np.arcsin(d[1]), np.arctan2(d[2], d[0])],
                args=(upper, elbow, end, lower),
                method="Nelder-Mead",
                options={"xatol": 1e-12, "fatol": 1e-16, "maxiter": 20000},
            )
            assert abs(np.linalg.norm(g[k] - g[j]) - upper) < 1e-9 * upper
            assert np.linalg.norm(g[k] - g[j] - on_sphere(best.x, upper)) < 1e-4 * upper
            assert miss(g[k] - g[j], elbow, end, lower) <= best.fun + 1e-8 * upper**2
            bone, wanted = g[h] - g[k], targets[h] - g[k]
            assert bone @ wanted / (np.linalg.norm(bone) * np.linalg.norm(wanted)) > 1 - 1e-12
        twin = torch_quat.reach(
            torch.from_numpy(start),
            torch.from_numpy(sk.offsets),
            torch.from_numpy(targets - targets[0] + offsets[0]),
            [int(p) for p in parents],
            ends.tolist(),
        ).numpy()
        assert np.degrees(quat.angle_between(twin, got)).max() < 1e-6

    _, g, _ = reached_at(m.rotations[0], 0, np.zeros((J, 3)), ends)
    j = int(np.nonzero(ends >= 0)[0][0])
    h = ends[j]
    along = np.zeros((J, 3))
    along[h] = -0.3 * (g[h] - g[parents[h]])  # the foot asked up its shin, the knee to stay (a knee to bend)
    _, alone, targets = reached_at(m.rotations[0], 0, along, np.full(J, -1))
    assert np.linalg.norm(alone[h] - g[h]) < 1e-9 * np.linalg.norm(along[h])  # one joint at a time: it stays put
    _, limb, _ = reached_at(m.rotations[0], 0, along, ends)
    both = lambda p: np.sum((p[[parents[h], h]] - targets[[parents[h], h]]) ** 2)  # knee's miss and foot's, squared
    assert both(limb) < 0.8 * both(alone)  # 106 against 144 here: the knee gives a little, the foot comes up
    assert np.linalg.norm(limb[h] - targets[h]) < 0.75 * np.linalg.norm(along[h])
    same, _, _ = reached_at(m.rotations[0], 0, np.zeros((J, 3)), ends)
    assert np.degrees(quat.angle_between(same, m.rotations[0])).max() < 1e-6


def test_a_limb_end_the_posture_raises_rises_by_the_smooth_minimum_of_its_rise_and_the_way_to_the_eyes():
    """``_ends_below_the_eyes`` (compiled) and its torch twin, against a direct statement of the rule:
    a hand's (or foot's) rise r becomes (r^-3 + b^-3)^(-1/3), b how far it is below the eyes
    (``eyes_above_head`` above the head joint), so it ends below them and rises by nearly all of r
    when far below; none at or above them; a lowered end is kept; its middle joint's rise is scaled
    alike; everything else keeps its offsets. The output's height rises with the input's (no hand held
    still below the eyes)."""
    from scipy.spatial.transform import Rotation

    from styleerd.model import torch_quat
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime.stylizer import _ends_below_the_eyes

    sk = load_generator_weights().skeleton
    ends, head, parents = limb_ends(sk), sk.names.index("Head"), sk.parents
    eyes = eyes_above_head(sk)
    assert 7.0 < eyes < 9.0  # a sixth of Hips -> Head at rest (47.6 of the rig's units): about the eyes
    tips = [int(m) for m in ends if m >= 0]
    middles = [int(parents[m]) for m in tips]
    assert [sk.names[m] for m in tips] == ["Hand_L", "Hand_R", "Foot_L", "Foot_R"]
    rng = np.random.default_rng(11)
    kinds = set()
    for t in range(60):
        rot = quat.from_scaled_angle_axis(rng.normal(0, 0.8, (sk.n_joints, 3)))
        _, given = forward_kinematics(rot, sk.offsets, parents)
        axes = Rotation.random(random_state=t).as_matrix().T  # rows: left, up, forward
        offsets = rng.normal(0, 15.0, (sk.n_joints, 3))
        out = np.empty_like(offsets)
        _ends_below_the_eyes(offsets, given, axes, head, eyes, ends, parents, out)
        others = [j for j in range(sk.n_joints) if j not in tips + middles]
        assert np.array_equal(out[others], offsets[others])
        assert np.array_equal(out[tips + middles][:, [0, 2]], offsets[tips + middles][:, [0, 2]])
        for m, k in zip(tips, middles):
            r, below = offsets[m, 1], eyes - (given[m] - given[head]) @ axes[1]
            if r <= 0:
                kinds.add("lowered")
                assert out[m, 1] == r and out[k, 1] == offsets[k, 1]
                continue
            kinds.add("above the eyes" if below <= 0 else "below them")
            want = 0.0 if below <= 0 else (r**-3 + below**-3) ** (-1 / 3)
            assert abs(out[m, 1] - want) < 1e-9 and out[m, 1] <= max(below, 0.0) + 1e-12
            assert abs(out[k, 1] - (offsets[k, 1] * want / r if offsets[k, 1] > 0 else offsets[k, 1])) < 1e-9
        twin = torch_quat.ends_below_the_eyes(
            torch.from_numpy(offsets @ axes),
            torch.from_numpy(given),
            torch.from_numpy(axes[1]),
            head,
            eyes,
            ends.tolist(),
            [int(p) for p in parents],
        ).numpy()
        assert np.abs(twin - out @ axes).max() < 1e-9
    assert kinds == {"lowered", "above the eyes", "below them"}

    # one hand moved up through the eyes with a rise of 20: its target climbs all the way, and ends with it
    m, up = tips[0], np.eye(3)
    heights, over = [], np.linspace(-40.0, 5.0, 200)
    for h in over:
        given = np.zeros((sk.n_joints, 3))
        given[m, 1] = eyes + h  # h: the hand over the eyes (the head joint at 0)
        offsets = np.zeros((sk.n_joints, 3))
        offsets[m, 1] = 20.0
        _ends_below_the_eyes(offsets, given, up, head, eyes, ends, parents, out)
        heights.append(h + out[m, 1])
    heights = np.array(heights)
    assert np.all(np.diff(heights) > 0)  # never held still
    assert heights[0] > -40.0 + 19.0  # far below, nearly all of the rise
    assert heights[over < 0].max() < 0.0  # below the eyes, it stays under them


def test_streams_blended_together_get_what_each_gets_alone():
    """``_towards_the_input`` on a batch whose streams share a change of style in runs (A, A, B, A, B, B:
    the posture is put together once a run) and go part or all the way to the input (the whole way
    takes the target without the arc's sines), one not at all (the network knows its pose), gives each
    stream exactly what it gets alone."""
    from styleerd.model.config import FAMILIAR, UNFAMILIAR
    from styleerd.runtime.stylizer import _towards_the_input

    m = walking_motion(6)
    sk, J = m.skeleton, m.skeleton.n_joints
    rng = np.random.default_rng(7)
    N, S = 6, 3
    given = m.rotations[:N].copy()
    same = quat.normalize(given + rng.normal(0, 0.05, given.shape))
    styled = quat.normalize(given + rng.normal(0, 0.3, given.shape))
    runs = np.array([[1.0, -1.0, 0.0], [0.0, 0.5, -1.0]])
    diff = np.ascontiguousarray(runs[[0, 0, 1, 0, 1, 1]])
    posture, offsets = rng.normal(0, 0.3, (S, J, 3)), rng.normal(0, 3.0, (S, J, 3))
    seen = np.array([0.3, 1.0, 0.0, 1.0, 0.6, 1.0])  # at least this far: part way, all the way, or (2) as near
    bounds = np.stack([seen, np.ones(N)], -1)  # and at most all the way
    translations = np.ascontiguousarray(m.positions[:N])
    globals_ = np.stack([forward_kinematics(m.rotations[t], m.positions[t], sk.parents)[1] for t in range(N)])
    facing = np.tile([0.0, 0.0, 1.0], (N, 1))
    roles = BodyRoles.of(sk)
    joints = np.array([0, sk.names.index("Head"), *roles.left, *roles.right])

    def blend(rows):
        out, weight = styled[rows].copy(), np.zeros(len(rows))
        _towards_the_input(
            *(given[rows], same[rows], out, np.ascontiguousarray(diff[rows]), posture, offsets, bounds[rows]),
            *(FAMILIAR, UNFAMILIAR, weight, translations[rows], globals_[rows], facing[rows], joints, True, sk.parents),
            *(limb_ends(sk), eyes_above_head(sk)),
        )
        return out, weight

    together, weight = blend(np.arange(N))
    assert weight[2] == 0.0 and 0.0 < weight[0] < 1.0 and 0.0 < weight[4] < 1.0 and weight[[1, 3, 5]].min() == 1.0
    for n in range(N):
        alone, w = blend(np.array([n]))
        assert np.array_equal(together[n], alone[0]) and w[0] == weight[n], n
    assert np.degrees(quat.angle_between(together, styled)).max() > 5.0  # the blend did something


@pytest.mark.parametrize("rig", ["biped", "arms with hands"])
@pytest.mark.parametrize("posture", ["none", "rotations", "rotations and offsets", "rotations and body offsets"])
def test_validations_pose_input_is_the_stylizers(model, posture, rig, monkeypatch):
    """``train.validation.towards_the_input`` (torch, whole windows: what ``eval quality --pose
    input`` judges) gives the stylizer's pose "input" output frame by frame from a fresh state,
    with the unfamiliarity thresholds inside this random network's range; on the test biped, and on
    the shipped model's skeleton, whose arms end in hands (two-bone limbs, a hand's rise cut at the
    eyes)."""
    from styleerd.model import torch_quat
    from styleerd.model.stored import load_generator_weights
    from styleerd.train import validation

    sk = None if rig == "biped" else load_generator_weights().skeleton
    m = walking_motion(30, skeleton=sk)
    if sk is not None:
        f, _ = motion_features(walking_motion(100, skeleton=sk))
        torch.manual_seed(0)
        config = GeneratorConfig(sk.n_joints, STYLES, CONTENTS, neutral_layers=2, style_layers=2)
        model = StyleERD(config, sk, FeatureStats.fit(f, sk.n_joints))
        for p in model.parameters():
            p.data += 0.05 * torch.randn_like(p)
        model.eval()
    f, traj = motion_features(m)
    x = torch.as_tensor(model.stats().normalize(f), dtype=torch.float32)[None]
    rng = np.random.default_rng(7)
    shape = (len(STYLES), m.skeleton.n_joints, 3)
    vectors, offsets = (torch.tensor(rng.normal(0, scale, shape), dtype=torch.float32) for scale in (0.4, 5.0))
    monkeypatch.setattr(model, "posture", None if posture == "none" else vectors)
    monkeypatch.setattr(model, "posture_offsets", offsets if "offsets" in posture else None)
    monkeypatch.setattr(model, "posture_frame", "body" if "body" in posture else "heading")
    eye_s, eye_c = torch.eye(len(STYLES)), torch.eye(len(CONTENTS))
    with torch.no_grad():
        same, _, _ = model(x, eye_s[[1]], eye_c[[0]], eye_s[[1]])
        angles = torch.rad2deg(torch_quat.angle(same, model.raw_rotations(x))).mean(-1).numpy()
    low, high = np.percentile(angles, [30, 70])
    monkeypatch.setattr(model, "familiar", (low, high))
    with torch.no_grad():
        rot, vel, _ = model(x, eye_s[[1]], eye_c[[0]], eye_s[[2]])
        rot, _ = validation.towards_the_input(model, x, eye_s[[1]], eye_c[[0]], eye_s[[2]], rot, vel)
    want = rot[0].double().numpy()
    want[:, 0] = quat.mul(traj[:, 3:7], want[:, 0])
    s = StreamStylizer(model, "normal", "walk", {"old": 1.0}, pose="input")
    got = np.stack([s.step(m.rotations[t], m.positions[t])[0][0] for t in range(30)])
    assert 0.1 < s.unfamiliar_sum[0] / 30 < 0.9  # the frames span the blend
    assert np.degrees(quat.angle_between(got, want)).max() < 0.01  # float32 networks, composed in float32 and 64
