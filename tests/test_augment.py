"""Other-performer augmentation (for the labeller) and the labeller's lean to neutral."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from styleerd.data.augment import (
    MIRRORED_CONTENT,
    in_place,
    mirror,
    other_performer,
    random_joint_offsets,
    with_joint_offsets,
    with_proportions,
    with_speed,
)
from styleerd.model.checkpoint import load_generator
from styleerd.model.stored import toward_neutral
from styleerd.motion import quat
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import body_parts


@pytest.fixture(scope="module")
def model_walk():
    """A walk on the model's own skeleton (the generated walk retargeted onto it)."""
    from styleerd.motion.procedural import walk
    from styleerd.motion.retarget import to_target
    from styleerd.runtime.offline import map_skeleton

    g, _ = load_generator()
    m = walk(2.0, fps=30.0)
    return g, to_target(m, map_skeleton(m.skeleton, g, first_pose=m.rotations[0]))


def world(m: Motion) -> np.ndarray:
    return forward_kinematics(m.rotations, m.positions, m.skeleton.parents)[1]


def test_mirror_reflects_every_joint_onto_its_counterpart(model_walk):
    g, m = model_walk
    mm = mirror(m, g.stats().reference)
    parts = body_parts(m.skeleton)
    counterpart = np.arange(m.skeleton.n_joints)
    for p, j in parts.items():
        if p.startswith("left_"):
            counterpart[j], counterpart[parts["right_" + p[5:]]] = parts["right_" + p[5:]], j
    assert np.abs(world(m)[:, counterpart] * [-1, 1, 1] - world(mm)).max() < 1e-2  # cm: the rig's own asymmetry
    back = mirror(mm, g.stats().reference)
    assert np.abs(quat.positive_w(back.rotations) - quat.positive_w(m.rotations)).max() < 1e-6
    assert (
        MIRRORED_CONTENT["wave-left-hand"] == "wave-right-hand"
        and MIRRORED_CONTENT["walk-turn-right"] == "walk-turn-left"
    )


def test_proportions_speed_and_joint_offsets(model_walk):
    g, m = model_walk
    longer = with_proportions(m, 1.1, 1.0, 1.0)
    knee = body_parts(m.skeleton)["left_knee"]
    assert np.isclose(np.linalg.norm(longer.skeleton.offsets[knee]), 1.1 * np.linalg.norm(m.skeleton.offsets[knee]))
    assert np.allclose(longer.rotations, m.rotations)
    assert with_speed(m, 1.25).n_frames == pytest.approx(m.n_frames / 1.25, abs=1)
    rng = np.random.default_rng(0)
    offsets = random_joint_offsets(m.skeleton.n_joints, 12.0, rng)
    assert np.degrees(quat.angle_between(quat.identity(), offsets)).max() <= 12.0 + 1e-9
    turned = with_joint_offsets(m, offsets)
    # scipy: every global rotation turned by its offset in its own frame
    g0 = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)[0]
    g1 = forward_kinematics(turned.rotations, turned.positions, m.skeleton.parents)[0]
    a = Rotation.from_quat(g0.reshape(-1, 4), scalar_first=True) * Rotation.from_quat(
        np.tile(offsets, (m.n_frames, 1)), scalar_first=True
    )
    assert np.degrees((a.inv() * Rotation.from_quat(g1.reshape(-1, 4), scalar_first=True)).magnitude()).max() < 1e-6
    other, content = other_performer(m, "wave-left-hand", g.stats().reference, rng)
    assert content in ("wave-left-hand", "wave-right-hand") and np.isfinite(other.rotations).all()


def test_in_place_keeps_the_root_where_it_started():
    from styleerd.motion.procedural import walk

    m = walk(2.0, fps=30.0)
    still = in_place(m)
    assert np.ptp(still.positions[:, 0, [0, 2]], axis=0).max() == 0.0 and np.array_equal(
        still.positions[:, 0, 1], m.positions[:, 0, 1]
    )


def test_walks_and_runs_come_in_place_a_quarter_of_the_time_and_nothing_else_does(model_walk):
    """Game libraries ship walks in place: the labeller is taught them as walks."""
    g, m = model_walk
    rng = np.random.default_rng(1)
    travelled = lambda motion: np.ptp(motion.positions[:, 0, [0, 2]], axis=0).max()
    walks = [travelled(other_performer(m, "walk", g.stats().reference, rng)[0]) == 0.0 for _ in range(40)]
    assert 4 <= sum(walks) <= 18  # about 10 of 40
    waves = [travelled(other_performer(m, "wave-left-hand", g.stats().reference, rng)[0]) for _ in range(20)]
    assert min(waves) > 0.0


def test_unsure_posteriors_lean_to_neutral():
    p = np.array([[0.95, 0.05, 0.0], [0.4, 0.35, 0.25], [0.7, 0.3, 0.0]])
    out = toward_neutral(p, neutral=2)
    assert np.allclose(out.sum(-1), 1) and np.allclose(out[0], p[0])  # sure: kept
    assert np.allclose(out[1], [0, 0, 1])  # unsure: neutral
    assert np.allclose(out[2], [0.35, 0.15, 0.5])  # in between: halfway
    low = toward_neutral(np.array([[0.96, 0.015, 0.025], [0.7, 0.02, 0.28]], np.float32), neutral=2)
    assert low.dtype == np.float32 and np.allclose(low.sum(-1), 1)
    assert np.allclose(low[0], [0.96, 0.0, 0.04])  # under ABSENT (0.02): absent, its share to neutral
    assert np.allclose(low[1], [0.35, 0.0, 0.65])  # halfway, then 0.01 is absent


@pytest.mark.slow
def test_the_neutral_xia_walk_is_read_as_normal(shared_data):
    """The shipped labeller, through the stylizer, on the xia neutral walk (another performer,
    another skeleton, 120 fps): normal after 1, 10 and 30 frames and at the end."""
    from styleerd.eval.metrics import other_performer_labels
    from styleerd.model.checkpoint import load_labeller

    g, _ = load_generator()
    labels = other_performer_labels(g, load_labeller()[0], str(shared_data))
    assert all(v == "normal" for v in labels["neutral_01_000"].values()), labels["neutral_01_000"]
