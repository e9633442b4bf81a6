import numpy as np
from conftest import walking_motion
from scipy.spatial.transform import Rotation, Slerp

from styleerd.motion import quat
from styleerd.motion.kinematics import facing_directions, foot_contacts, forward_kinematics, heading_rotations
from styleerd.motion.motion import drop_root
from styleerd.motion.resample import resample
from styleerd.motion.skeleton import BodyRoles, Skeleton


def fk_oracle(rotations, positions, parents):
    """Independent FK with scipy rotation matrices and an explicit per-joint chain walk."""
    T, J = rotations.shape[:2]
    mats = Rotation.from_quat(rotations[..., [1, 2, 3, 0]].reshape(-1, 4)).as_matrix().reshape(T, J, 3, 3)
    out = np.zeros((T, J, 3))
    for j in range(J):
        chain = []
        k = j
        while k >= 0:
            chain.append(k)
            k = parents[k]
        for t in range(T):
            p, R = np.zeros(3), np.eye(3)
            for k in reversed(chain):
                p = p + R @ positions[t, k]
                R = R @ mats[t, k]
            out[t, j] = p
    return out


def test_fk_matches_scipy_oracle():
    m = walking_motion(20)
    g_rot, g_pos = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
    assert np.allclose(g_pos, fk_oracle(m.rotations, m.positions, m.skeleton.parents), atol=1e-9)
    # global rotation of a leaf is the ordered product of the chain's local rotations
    r = Rotation.identity()
    for k in [0, 1, 2, 4, 5]:
        r = r * Rotation.from_quat(m.rotations[3, k, [1, 2, 3, 0]])
    assert np.isclose(abs(np.dot(g_rot[3, 5], r.as_quat()[[3, 0, 1, 2]])), 1.0)


def test_drop_root_keeps_fk_exactly():
    m = walking_motion(10)
    sk = m.skeleton
    placeholder = Skeleton(
        names=("joint_Root",) + sk.names,
        parents=np.concatenate([[-1], sk.parents + 1]),
        offsets=np.concatenate([[[1.0, 2.0, 3.0]], sk.offsets]),
        channels=(sk.channels[0],) + sk.channels,
    )
    rng = np.random.default_rng(0)
    root_rot = quat.normalize(np.array([1, 0.01, 0.02, -0.01]) + 0.01 * rng.normal(size=(10, 4)))
    rot = np.concatenate([root_rot[:, None], m.rotations], 1)
    pos = np.concatenate([np.full((10, 1, 3), 0.5), m.positions], 1)
    from styleerd.motion.motion import Motion

    big = Motion(placeholder, rot, pos, m.fps)
    small = drop_root(big)
    assert small.skeleton.names == sk.names
    _, g_big = forward_kinematics(big.rotations, big.positions, big.skeleton.parents)
    _, g_small = forward_kinematics(small.rotations, small.positions, small.skeleton.parents)
    assert np.allclose(g_big[:, 1:], g_small, atol=1e-9)


def test_heading_faces_walking_direction_and_turns_with_the_body():
    m = walking_motion(30)
    roles = BodyRoles.of(m.skeleton)
    yaw = np.random.default_rng(1).uniform(-np.pi, np.pi, 30)
    spin = quat.from_angle_axis(yaw, np.array([0.0, 1.0, 0.0]))
    rot = quat.identity((30, m.skeleton.n_joints))  # rest pose: hips and shoulders level
    _, g0 = forward_kinematics(rot, m.positions, m.skeleton.parents)
    assert np.allclose(facing_directions(g0, roles.left, roles.right), [0, 0, 1], atol=1e-9)
    rot[:, 0] = spin
    _, g = forward_kinematics(rot, m.positions, m.skeleton.parents)
    d = facing_directions(g, roles.left, roles.right)
    assert np.allclose(d, np.stack([np.sin(yaw), np.zeros(30), np.cos(yaw)], -1), atol=1e-9)
    assert np.allclose(quat.mul_vec(heading_rotations(d), np.array([0.0, 0, 1])), d, atol=1e-9)


def test_degenerate_facing_keeps_previous_direction():
    g = np.zeros((3, 2, 3))
    g[:, 0] = [1, 0, 0]  # left joint
    g[1, 0] = [0, 1, 0]  # frame 1: across vector points up
    d = facing_directions(g, (0,), (1,))
    assert np.allclose(d[1], d[0]) and np.allclose(d[0], [0, 0, 1])


def test_foot_contacts_from_speed():
    p = np.zeros((4, 1, 3))
    p[2, 0, 0] = 1.0
    prev = np.concatenate([p[:1], p[:-1]])
    c = foot_contacts(p, prev, (0,), fps=30.0, max_speed=10.0)
    assert c[:, 0].tolist() == [1.0, 1.0, 0.0, 0.0]


def test_resample_matches_scipy_slerp_and_keeps_identity():
    m = walking_motion(31, fps=30.0)
    assert resample(m, 30.0).rotations is m.rotations
    up = resample(m, 120.0)
    assert up.n_frames == 121 and up.fps == 120.0
    t_src = np.arange(31) / 30.0
    for j in (0, 5):
        s = Slerp(t_src, Rotation.from_quat(m.rotations[:, j, [1, 2, 3, 0]]))
        ref = s(np.arange(121) / 120.0).as_quat()[:, [3, 0, 1, 2]]
        assert np.allclose(np.abs(np.sum(ref * up.rotations[:, j], -1)), 1.0, atol=1e-9)
    assert np.allclose(up.positions[::4], m.positions)
    down = resample(m, 12.0)
    assert down.n_frames == 13
    assert np.allclose(down.positions[1, 0], (m.positions[2, 0] + m.positions[3, 0]) / 2)


def test_resample_to_a_given_frame_count_round_trips_the_length():
    m = walking_motion(41, fps=120.0)
    down = resample(m, 30.0)
    assert down.n_frames == 11
    back = resample(down, 120.0, n_frames=41)
    assert back.n_frames == 41 and np.allclose(back.positions[::4], m.positions[::4])
    longer = resample(walking_motion(42, fps=120.0), 30.0)
    assert resample(longer, 120.0, n_frames=42).n_frames == 42  # the last frame is held


def test_forward_positions_equal_forward_kinematics():
    m = walking_motion(20)
    _, g = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
    from styleerd.motion.kinematics import forward_positions

    assert np.abs(forward_positions(m.rotations, m.positions, m.skeleton.parents) - g).max() < 1e-9
    assert np.abs(forward_positions(m.rotations[3], m.positions[3], m.skeleton.parents) - g[3]).max() < 1e-9
