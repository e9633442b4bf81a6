import numpy as np
import pytest
from conftest import walking_motion

from styleerd.data.features import (
    FeatureLayout,
    FeatureStats,
    features_to_motion,
    motion_features,
    pose_features,
    stream_features,
)
from styleerd.motion import quat
from styleerd.motion.kinematics import facing_directions, forward_kinematics, heading_rotations
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import BodyRoles


def test_layout_and_shapes():
    m = walking_motion(40)
    f, traj = motion_features(m)
    layout = FeatureLayout(m.skeleton.n_joints)
    assert f.shape == (40, layout.dim) and traj.shape == (40, 7)
    assert np.all(f[0, layout.velocities] == 0)  # first frame: no previous frame
    q = f[:, layout.rotations].reshape(40, -1, 4)
    assert np.allclose(np.linalg.norm(q, axis=-1), 1) and np.all(q[..., 0] >= 0)
    assert set(np.unique(f[:, layout.contacts])) <= {0.0, 1.0}


def test_causal_perturbing_a_future_frame_changes_no_past_feature():
    m = walking_motion(50)
    f, traj = motion_features(m)
    for t in (0, 10, 48):
        rot, pos = m.rotations.copy(), m.positions.copy()
        rot[t + 1] = quat.normalize(rot[t + 1] + 0.3)
        pos[t + 1] += 7.0
        f2, traj2 = motion_features(Motion(m.skeleton, rot, pos, m.fps))
        assert np.array_equal(f2[: t + 1], f[: t + 1]) and np.array_equal(traj2[: t + 1], traj[: t + 1])
        assert not np.allclose(f2[t + 1], f[t + 1])


def test_streaming_one_frame_at_a_time_equals_whole_clip():
    m = walking_motion(25)
    roles = BodyRoles.of(m.skeleton)
    f, traj = motion_features(m)
    prev = None
    for t in range(25):
        r, p = m.rotations[t : t + 1], m.positions[t : t + 1]
        if prev is None:
            _, prev = forward_kinematics(r, p, m.skeleton.parents)
        ft, tt, prev = pose_features(r, p, prev, m.skeleton, roles, m.fps)
        assert np.allclose(ft[0], f[t], atol=1e-9) and np.allclose(
            tt[0], traj[t], atol=1e-9
        )  # two arithmetic paths (small vs whole-clip arrays)


@pytest.mark.parametrize("n_streams", [3, 70])
def test_compiled_stream_features_equal_normalised_whole_clip_features(n_streams):
    """The streaming hot path (one compiled loop: unit quaternions, FK, heading, features,
    normalisation) against pose_features + FeatureStats.normalize, many streams at once, with
    unnormalised input quaternions and a frame whose facing is undefined (lying on its side)."""
    T = 12
    clips = [walking_motion(T, seed=k) for k in range(n_streams)]
    side = quat.from_angle_axis(np.array(np.pi / 2), np.array([0.0, 0.0, 1.0]))
    clips[1].rotations[5] = [1.0, 0.0, 0.0, 0.0]
    clips[1].rotations[5, 0] = side  # rest pose on its side: hips and shoulders line up vertically
    skeleton, roles = clips[0].skeleton, BodyRoles.of(clips[0].skeleton)
    offline = [motion_features(m) for m in clips]
    stats = FeatureStats.fit(np.concatenate([f for f, _ in offline]), skeleton.n_joints)
    rot = np.stack([m.rotations for m in clips], 1) * np.random.default_rng(0).uniform(0.5, 2.0, (T, n_streams, 1, 1))
    pos = np.stack([m.positions for m in clips], 1)
    previous, facing, started = (
        np.zeros((n_streams, skeleton.n_joints, 3)),
        np.zeros((n_streams, 3)),
        np.zeros(n_streams, bool),
    )
    for t in range(T):
        x, traj, previous, facing, ok = stream_features(
            rot[t], pos[t], previous, facing, started, skeleton, roles, clips[0].fps, stats, 1e6
        )
        started[:] = True
        assert ok.all() and x.dtype == np.float32
        for k, (f, tr) in enumerate(offline):
            assert np.abs(x[k] - stats.normalize(f[t])).max() < 1e-5  # float32
            assert np.abs(traj[k] - tr[t]).max() < 1e-9
    assert np.allclose(offline[1][1][5, 3:], offline[1][1][4, 3:])  # the degenerate frame kept the heading before


def test_compiled_stream_features_flag_values_past_the_limit():
    m = walking_motion(2)
    stats = FeatureStats.fit(motion_features(m)[0], m.skeleton.n_joints)
    pos = np.repeat(m.positions[:1], 2, 0)
    pos[1, 0] = [0.0, 0.0, 1e9]  # a root a million km away moved there in one frame
    previous = np.repeat(m.positions[:1], 2, 0)
    _x, *_, ok = stream_features(
        np.repeat(m.rotations[:1], 2, 0),
        pos,
        previous,
        np.zeros((2, 3)),
        np.ones(2, bool),
        m.skeleton,
        BodyRoles.of(m.skeleton),
        m.fps,
        stats,
        1e6,
    )
    assert ok.tolist() == [True, False]


def test_compiled_heading_equals_the_angle_of_the_facing_all_around():
    """The compiled kernel's heading (half-angle identities, no trigonometry) against
    kinematics.heading_rotations (arctan2) for a character turned to every angle: both sides
    of the identities' switch (cos 120 degrees) and exactly 180 degrees (w = 0) included."""
    m = walking_motion(1)
    skeleton, roles = m.skeleton, BodyRoles.of(m.skeleton)
    stats = FeatureStats.fit(
        np.concatenate([motion_features(walking_motion(12, seed=k))[0] for k in range(2)]), skeleton.n_joints
    )
    angles = np.concatenate(
        [np.linspace(-np.pi, np.pi, 721), np.radians([119.999, 120.0, 120.001, -120.0, 180.0, -180.0])]
    )
    n = len(angles)
    turn = quat.from_angle_axis(angles, np.array([0.0, 1.0, 0.0]))
    rot, pos = np.repeat(m.rotations[:1], n, 0), np.repeat(m.positions[:1], n, 0)
    rot[:, 0] = quat.mul(turn, rot[:, 0])
    _, traj, g, facing, ok = stream_features(
        rot,
        pos,
        np.zeros((n, skeleton.n_joints, 3)),
        np.zeros((n, 3)),
        np.zeros(n, bool),
        skeleton,
        roles,
        m.fps,
        stats,
        1e6,
    )
    expected = heading_rotations(facing)
    assert ok.all() and np.all(traj[:, 3] >= 0)
    assert np.abs(traj[:, 3:7] - expected).max() < 1e-12  # same sign too: w >= 0 in both
    assert np.abs(traj[:, 3:7] - heading_rotations(facing_directions(g, roles.left, roles.right))).max() < 1e-12


def test_features_do_not_depend_on_where_the_character_is_or_faces():
    m = walking_motion(30)
    f, _ = motion_features(m)
    spin = quat.from_angle_axis(np.array(1.1), np.array([0.0, 1.0, 0.0]))
    rot, pos = m.rotations.copy(), m.positions.copy()
    rot[:, 0] = quat.mul(spin, rot[:, 0])
    pos[:, 0] = quat.mul_vec(spin, pos[:, 0]) + [300.0, 0.0, -50.0]
    f2, _ = motion_features(Motion(m.skeleton, rot, pos, m.fps))
    assert np.allclose(f, f2, atol=1e-9)


def test_reconstruction_gives_back_the_motion():
    m = walking_motion(30)
    f, traj = motion_features(m)
    back = features_to_motion(f, traj, m.skeleton, m.fps)
    _, g = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
    _, g2 = forward_kinematics(back.rotations, back.positions, back.skeleton.parents)
    assert np.abs(g - g2).max() < 1e-9


def test_stats_centre_scale_by_block_and_align_hemispheres():
    m = walking_motion(200)
    f, _ = motion_features(m)
    J = m.skeleton.n_joints
    layout = FeatureLayout(J)
    flipped = f.copy()
    flipped[::2, 4:8] *= -1  # same rotations, other sign
    stats = FeatureStats.fit(flipped, J)
    x = stats.normalize(flipped)
    assert np.allclose(x, stats.normalize(f))
    assert np.allclose(x[:, : 10 * J].mean(0), 0, atol=1e-9)
    for block in (layout.rotations, layout.positions, layout.velocities):
        assert np.isclose(x[:, block].var(0).mean(), 1.0)  # pooled: unit variance per block
        assert np.ptp(stats.std[block]) == 0
    assert np.array_equal(x[:, layout.contacts], f[:, layout.contacts])
    assert np.allclose(stats.denormalize(x)[:, 4 * J :], f[:, 4 * J :])
    again = FeatureStats.from_dict(stats.to_dict())
    assert np.allclose(again.normalize(f), x)
