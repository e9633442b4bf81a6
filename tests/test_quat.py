import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from styleerd.motion import quat


def to_scipy(q):
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def from_scipy(r):
    return r.as_quat()[..., [3, 0, 1, 2]]


def random_quats(n, seed=0):
    return from_scipy(Rotation.random(n, random_state=seed))


def same_rotation(a, b, atol=1e-9):
    return np.allclose(np.abs(np.sum(a * b, axis=-1)), 1.0, atol=atol)


@pytest.mark.parametrize("order", quat.ORDERS)
def test_from_euler_matches_scipy_intrinsic(order):
    e = np.random.default_rng(1).uniform(-np.pi, np.pi, size=(500, 3))
    assert same_rotation(quat.from_euler(e, order), from_scipy(Rotation.from_euler(order.upper(), e)))


@pytest.mark.parametrize("order", quat.ORDERS)
def test_to_euler_matches_scipy(order):
    q = random_quats(500)
    e = quat.to_euler(q, order)
    expected = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler(order.upper())
    assert np.allclose(e, expected, atol=1e-9)
    assert same_rotation(quat.from_euler(e, order), q)


@pytest.mark.parametrize("order", quat.ORDERS)
@pytest.mark.parametrize("middle", [np.pi / 2, -np.pi / 2])
def test_to_euler_at_gimbal_lock_gives_same_rotation(order, middle):
    rng = np.random.default_rng(2)
    e = np.stack([rng.uniform(-3, 3, 50), np.full(50, middle), rng.uniform(-3, 3, 50)], -1)
    q = quat.from_euler(e, order)
    back = quat.to_euler(q, order)
    assert same_rotation(quat.from_euler(back, order), q, atol=1e-7)
    assert np.allclose(back[:, 2], 0.0)


@pytest.mark.parametrize("order", quat.ORDERS)
def test_nearest_euler_recovers_any_equivalent_triple(order):
    rng = np.random.default_rng(3)
    e = rng.uniform(-np.pi, np.pi, size=(300, 3))
    e[:, 1] = rng.uniform(-1.5, 1.5, 300)
    variants = np.where(rng.random((300, 1)) < 0.5, quat.alternate_euler(e), e)
    variants = variants + 2 * np.pi * rng.integers(-2, 3, size=(300, 3))
    q = quat.from_euler(variants, order)
    assert np.allclose(quat.nearest_euler(quat.to_euler(q, order), variants), variants, atol=1e-9)


def test_unroll_euler_removes_wraps():
    a = np.linspace(0, 4 * np.pi, 200)
    e = np.stack([a, 0.2 * np.sin(a), -a], -1)
    q = quat.from_euler(e, "zxy")
    un = quat.unroll_euler(quat.to_euler(q, "zxy"))
    assert np.abs(np.diff(un, axis=0)).max() < 0.1
    assert np.allclose(un, e, atol=1e-9)


def test_mul_inv_mul_vec_and_xform_match_scipy():
    a, b = random_quats(300, 4), random_quats(300, 5)
    v = np.random.default_rng(6).normal(size=(300, 3))
    assert same_rotation(quat.mul(a, b), from_scipy(to_scipy(a) * to_scipy(b)))
    assert same_rotation(quat.inv(a), from_scipy(to_scipy(a).inv()))
    assert np.allclose(quat.mul_vec(a, v), to_scipy(a).apply(v))
    assert np.allclose(quat.to_xform(a), to_scipy(a).as_matrix())
    assert same_rotation(quat.from_xform(to_scipy(a).as_matrix()), a)


def test_from_xform_handles_half_turns():
    q = quat.from_angle_axis(np.full(3, np.pi), np.eye(3))
    assert same_rotation(quat.from_xform(quat.to_xform(q)), q)


def test_angle_axis_and_angle_between():
    q = random_quats(200, 7)
    angle, axis = quat.to_angle_axis(q)
    rv = to_scipy(q).as_rotvec()
    assert np.allclose(angle, np.linalg.norm(rv, axis=-1))
    assert same_rotation(quat.from_angle_axis(angle, axis), q)
    r = random_quats(200, 8)
    assert np.allclose(quat.angle_between(q, r), (to_scipy(q).inv() * to_scipy(r)).magnitude())


def test_slerp_matches_scipy():
    a, b = random_quats(100, 9), random_quats(100, 10)
    t = np.random.default_rng(11).random(100)
    for i in range(100):
        s = Slerp([0, 1], Rotation.concatenate([to_scipy(a[i]), to_scipy(b[i])]))
        assert same_rotation(quat.slerp(a[i], b[i], t[i]), from_scipy(s(t[i])))


def test_between_takes_v0_to_v1_including_opposite():
    rng = np.random.default_rng(12)
    v0, v1 = rng.normal(size=(100, 3)), rng.normal(size=(100, 3))
    v1[0] = -v0[0]
    q = quat.between(v0, v1)
    got = quat.mul_vec(q, v0 / np.linalg.norm(v0, axis=-1, keepdims=True))
    assert np.allclose(got, v1 / np.linalg.norm(v1, axis=-1, keepdims=True))


def test_compiled_scalar_helpers_against_the_array_functions_and_scipy():
    """The scalar helpers compiled loops use: between against the array function (including
    opposite and zero vectors), Euler angles both ways and the nearest Euler triple against
    scipy (including gimbal lock)."""
    rng = np.random.default_rng(3)
    v0, v1 = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    v1[0], v0[1], v1[2] = -v0[0], 0.0, 0.0
    v0[3], v1[3] = [0.95, 0.1, 0.0], [-0.95, -0.1, 0.0]  # opposite, mostly along x
    for a, b in zip(v0, v1):
        assert np.allclose(quat.between_scalars(*a, *b), quat.between(a, b), atol=1e-12)
    q = Rotation.random(50, random_state=4).as_quat()[:, [3, 0, 1, 2]]
    q[0] = from_scipy(Rotation.from_euler("ZXY", [30, 90, 10], degrees=True))  # gimbal lock
    for order in quat.ORDERS:
        axes = ["xyz".index(a) for a in order]
        for row in q:
            e = np.array(quat.quat_scalars_to_euler(*row, *axes))
            assert (
                same_rotation(from_scipy(Rotation.from_euler(order.upper(), e)), row) and abs(e[1]) <= np.pi / 2 + 1e-12
            )
            assert same_rotation(np.array(quat.euler_scalars_to_quat(*e, *axes)), row)
            ref = e + rng.normal(0, 3, 3)
            near = np.array(quat.nearest_euler_scalars(*e, *ref))
            assert same_rotation(from_scipy(Rotation.from_euler(order.upper(), near)), row, atol=1e-7)
            assert np.sum((near - ref) ** 2) <= np.sum((e - ref) ** 2) + 1e-12


def test_rotation_vectors_match_scipy_both_ways():
    """``from_scaled_angle_axis`` and ``to_scaled_angle_axis`` against scipy's rotation vectors,
    the zero vector (identity) and angles near pi included; the torch twin the same."""
    import torch

    from styleerd.model import torch_quat

    v = Rotation.random(500, random_state=3).as_rotvec()
    v[:3] = [[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [0.0, np.pi - 1e-6, 0.0]]
    q = quat.from_scaled_angle_axis(v)
    assert same_rotation(q, from_scipy(Rotation.from_rotvec(v)), atol=1e-12)
    assert np.allclose(quat.to_scaled_angle_axis(q), Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_rotvec(), atol=1e-9)
    assert np.allclose(torch_quat.from_scaled_angle_axis(torch.tensor(v)).numpy(), q, atol=1e-12)
