import numpy as np

from conftest import walking_motion
from styleerd.data.features import FeatureLayout, FeatureStats, features_to_motion, motion_features, pose_features
from styleerd.motion import quat
from styleerd.motion.kinematics import forward_kinematics
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
        assert np.allclose(ft[0], f[t], atol=1e-9) and np.allclose(tt[0], traj[t], atol=1e-9)  # two arithmetic paths (small vs whole-clip arrays)


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
