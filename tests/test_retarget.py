"""Retargeting: generated skeletons (renamed, rescaled, other rest poses, extra joints) whose
motion is known to be the model skeleton's motion, and the real Xia skeleton."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from styleerd.model.checkpoint import load_generator
from styleerd.motion import bvh, quat
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import body_parts, joint_map, to_source, to_target
from styleerd.motion.skeleton import Skeleton

MIXAMO = {
    "Hips": "Hips",
    "Spine": "Spine",
    "Chest": "Spine2",
    "Neck": "Neck",
    "Head": "Head",
    "Shoulder_L": "LeftShoulder",
    "UpperArm_L": "LeftArm",
    "LowerArm_L": "LeftForeArm",
    "Hand_L": "LeftHand",
    "Shoulder_R": "RightShoulder",
    "UpperArm_R": "RightArm",
    "LowerArm_R": "RightForeArm",
    "Hand_R": "RightHand",
    "UpperLeg_L": "LeftUpLeg",
    "LowerLeg_L": "LeftLeg",
    "Foot_L": "LeftFoot",
    "Toes_L": "LeftToeBase",
    "UpperLeg_R": "RightUpLeg",
    "LowerLeg_R": "RightLeg",
    "Foot_R": "RightFoot",
    "Toes_R": "RightToeBase",
}


@pytest.fixture(scope="module")
def model_skeleton() -> Skeleton:
    return load_generator()[0].skeleton


def model_motion(sk: Skeleton, n: int = 40, seed: int = 0) -> Motion:
    """Smooth random motion on the model skeleton (any rotations do): a random pose plus
    sinusoids, a moving root."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None, None] / 30.0
    rotvec = rng.normal(0, 0.8, (1, sk.n_joints, 3)) + 0.4 * np.sin(
        2 * np.pi * rng.uniform(0.3, 1.5, (1, sk.n_joints, 3)) * t
    )
    rot = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_quat(scalar_first=True).reshape(n, sk.n_joints, 4)
    pos = np.broadcast_to(sk.offsets, (n, sk.n_joints, 3)).copy()
    pos[:, 0] = np.stack([30 * t[:, 0, 0], 90 + np.sin(t[:, 0, 0]), 10 * t[:, 0, 0]], -1)
    return Motion(sk, rot, pos, 30.0)


def generated(motion: Motion, seed: int, scale: float) -> Motion:
    """The same movement on another skeleton: Mixamo names with a namespace, every joint with
    another rest orientation (random: T-pose, A-pose or anything), an extra spine joint that
    never moves, two finger joints per hand, all lengths scaled.

    With R_j the rest change of joint j: offset'_j = R_parent offset_j and G'_j = G_j R_j^-1,
    so local'_j = R_parent local_j R_j^-1 (scipy does the algebra, independently of quat.py)."""
    sk, T = motion.skeleton, motion.n_frames
    rng = np.random.default_rng(seed)
    R = Rotation.random(sk.n_joints, random_state=rng)
    names, parents, offsets, rots = [], [], [], []
    index = {}
    for j, name in enumerate(sk.names):
        p = sk.parents[j]
        local = Rotation.from_quat(motion.rotations[:, j], scalar_first=True)
        offset = R[p].apply(sk.offsets[j]) if p >= 0 else sk.offsets[j]
        new_local = (R[p] * local * R[j].inv()) if p >= 0 else (local * R[j].inv())
        parent = index.get(p, -1)
        if name == "Chest":  # an extra joint halfway, identity rotation, then the chest
            names.append("mixamorig:Spine1")
            parents.append(parent)
            offsets.append(offset / 2)
            rots.append(np.tile([1.0, 0, 0, 0], (T, 1)))
            parent, offset = len(names) - 1, R[p].apply(sk.offsets[j]) / 2
            new_local = R[p] * local * R[j].inv()
        index[j] = len(names)
        names.append("mixamorig:" + MIXAMO[name])
        parents.append(parent)
        offsets.append(offset)
        rots.append(new_local.as_quat(scalar_first=True))
        if name.startswith("Hand_"):
            side = "Left" if name.endswith("L") else "Right"
            for k in (1, 2):
                names.append(f"mixamorig:{side}HandIndex{k}")
                parents.append(len(names) - 2)
                offsets.append(rng.normal(0, 3, 3))
                rots.append(Rotation.from_rotvec(rng.normal(0, 0.3, (T, 3))).as_quat(scalar_first=True))
    rot = np.stack(rots, 1)
    pos = np.broadcast_to(np.array(offsets) * scale, (T, len(names), 3)).copy()
    pos[:, 0] = motion.positions[:, 0] * scale
    skel = Skeleton(
        tuple(names),
        np.array(parents),
        np.array(offsets) * scale,
        tuple(("Zrotation", "Xrotation", "Yrotation") for _ in names),
    )
    return Motion(skel, rot, pos, motion.fps)


def world_positions(m: Motion) -> np.ndarray:
    return forward_kinematics(m.rotations, m.positions, m.skeleton.parents)[1]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_generated_skeletons_retarget_to_the_original_movement(model_skeleton, seed):
    original = model_motion(model_skeleton, seed=seed)
    other = generated(original, seed, scale=0.01)  # metres instead of centimetres
    jm = joint_map(model_skeleton, other.skeleton)
    assert {model_skeleton.names[t]: other.skeleton.names[s] for t, s in jm.pairs} == {
        k: "mixamorig:" + v for k, v in MIXAMO.items()
    }
    assert np.isclose(jm.scale, 100.0)
    on_model = to_target(other, jm)
    # every joint of the model lands where the original motion had it
    assert np.abs(world_positions(on_model) - world_positions(original)).max() < 1e-4  # cm
    back = to_source(on_model, jm, other)
    assert np.abs(world_positions(back) - world_positions(other)).max() < 1e-9


def test_changed_model_motion_goes_back_as_the_same_bone_directions(model_skeleton):
    original = model_motion(model_skeleton, seed=5)
    other = generated(original, 5, scale=2.0)
    jm = joint_map(model_skeleton, other.skeleton)
    changed = model_motion(model_skeleton, seed=6)  # what a network might output
    back = to_source(changed, jm, other)
    g_changed, g_back = world_positions(changed), world_positions(back)
    for t, s in jm.pairs:
        for t2, s2 in jm.pairs:
            if (
                model_skeleton.parents[t2] == t and model_skeleton.names[t] != "Spine"
            ):  # Spine->Chest spans the extra joint
                a, b = g_changed[:, t2] - g_changed[:, t], g_back[:, s2] - g_back[:, s]
                cos = (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
                assert cos.min() > 1 - 1e-9, (model_skeleton.names[t], model_skeleton.names[t2])
    fingers = [i for i, n in enumerate(other.skeleton.names) if "Index" in n]
    assert np.allclose(back.rotations[:, fingers], other.rotations[:, fingers])  # no counterpart: own motion


def test_unnamed_joints_are_found_down_their_limb_and_an_explicit_map_overrides(model_skeleton):
    other = generated(model_motion(model_skeleton), 0, 1.0)
    names = list(other.skeleton.names)
    names[names.index("mixamorig:LeftLeg")] = "knee_thing"
    sk = Skeleton(tuple(names), other.skeleton.parents, other.skeleton.offsets, other.skeleton.channels)
    assert body_parts(sk)["left_knee"] == names.index("knee_thing")  # topology: between hip and foot
    names[names.index("mixamorig:LeftForeArm")] = "a"
    names[names.index("mixamorig:LeftHand")] = "b"
    sk = Skeleton(tuple(names), other.skeleton.parents, other.skeleton.offsets, other.skeleton.channels)
    parts = body_parts(sk)  # down the arm from the shoulder, past the finger joints' branch
    assert (parts["left_elbow"], parts["left_hand"]) == (names.index("a"), names.index("b"))
    jm = joint_map(model_skeleton, sk)
    assert (model_skeleton.index("Hand_L"), names.index("b")) in jm.pairs
    jm = joint_map(model_skeleton, sk, {"Hand_L": "mixamorig:LeftHandIndex1"})
    assert (model_skeleton.index("Hand_L"), names.index("mixamorig:LeftHandIndex1")) in jm.pairs
    with pytest.raises(ValueError, match="'nope' is not a joint of the input skeleton"):
        joint_map(model_skeleton, sk, {"Hand_L": "nope"})


def test_xia_clips_round_trip_exactly_and_keep_limb_directions(shared_data, model_skeleton):
    for path in sorted((shared_data / "xia-sample").glob("*.bvh")):
        src = bvh.read(path)
        jm = joint_map(model_skeleton, src.skeleton)
        assert len(jm.pairs) == model_skeleton.n_joints
        on_model = to_target(src, jm)
        g_src, g_model = world_positions(src), world_positions(on_model)
        for a, b in (
            ("UpperArm_L", "LowerArm_L"),
            ("LowerArm_R", "Hand_R"),
            ("UpperLeg_L", "LowerLeg_L"),
            ("LowerLeg_R", "Foot_R"),
            ("Foot_L", "Toes_L"),
        ):
            ta, tb = model_skeleton.index(a), model_skeleton.index(b)
            sa, sb = dict(jm.pairs)[ta], dict(jm.pairs)[tb]
            u, v = g_model[:, tb] - g_model[:, ta], g_src[:, sb] - g_src[:, sa]
            cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
            assert cos.min() > 1 - 1e-9, (path.name, a, b)
        head_up = (g_model[:, model_skeleton.index("Head"), 1] - g_model[:, 0, 1]).min()
        assert head_up > 0  # upright on the model skeleton
        back = to_source(on_model, jm, src)
        assert np.abs(quat.mul(quat.inv(back.rotations), src.rotations)[..., 0]).min() > 1 - 1e-12
        assert np.array_equal(back.positions, src.positions)


def test_a_skeleton_with_no_leg_length_is_refused_with_a_clear_error(model_skeleton):
    other = generated(model_motion(model_skeleton), 0, 1.0)
    flat = Skeleton(
        other.skeleton.names, other.skeleton.parents, np.zeros_like(other.skeleton.offsets), other.skeleton.channels
    )
    with pytest.raises(ValueError, match="the input skeleton's legs have no length"):
        joint_map(model_skeleton, flat)
