"""Humanoid mapping with no joint map: generated rigs of every naming family and quirk (twist,
share, IK, pole and end bones, extra roots, no toes, no hand joint, numbered and nameless
joints), the real cmu-sample rigs against their hand-written maps, RobotExpressive; maps that
are wrong are refused with the reason; non-humanoids get one line."""

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from styleerd.model.stored import load_generator_weights
from styleerd.motion import bvh
from styleerd.motion.humanoid import OPTIONAL, REQUIRED, body_parts, side_and_stem, tokens
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.procedural import rig_families, tpose_skeleton
from styleerd.motion.retarget import joint_map, to_source, to_target
from styleerd.motion.skeleton import Skeleton

# The joint maps (model joint -> the rig's joint) once written by hand for cmu-sample's two rig
# families (Character Creator, CMU ASF names): the oracle the automatic mapping must agree with
RIG_MAPS = {
    "cc-base": {
        "Hips": "CC_Base_Hip",
        "Spine": "CC_Base_Spine01",
        "Chest": "CC_Base_Spine02",
        "Neck": "CC_Base_NeckTwist01",
        "Head": "CC_Base_Head",
        **{
            f"{m}_{s}": f"CC_Base_{s}_{c}"
            for s in "LR"
            for m, c in (
                ("Shoulder", "Clavicle"),
                ("UpperArm", "Upperarm"),
                ("LowerArm", "Forearm"),
                ("Hand", "Hand"),
                ("UpperLeg", "Thigh"),
                ("LowerLeg", "Calf"),
                ("Foot", "Foot"),
                ("Toes", "ToeBase"),
            )
        },
    },
    "cmu-asf": {
        "Spine": "lowerback",
        "Chest": "Chest2",
        "Neck": "Neck",
        **{
            f"{m}_{s}": f"{side}{c}"
            for s, side in (("L", "Left"), ("R", "Right"))
            for m, c in (
                ("Shoulder", "Collar"),
                ("UpperArm", "Shoulder"),
                ("LowerArm", "Elbow"),
                ("Hand", "Wrist"),
                ("UpperLeg", "Hip"),
                ("LowerLeg", "Knee"),
                ("Foot", "Ankle"),
                ("Toes", "Toe"),
            )
        },
    },
}
FAMILIES = rig_families()
CHECKED = REQUIRED + ("left_collar", "right_collar", "left_toe", "right_toe")


@pytest.fixture(scope="module")
def model():
    return load_generator_weights()


def global_rotations(m) -> Rotation:
    g, _ = forward_kinematics(m.rotations, m.positions, m.skeleton.parents)
    return Rotation.from_quat(g.reshape(-1, 4), scalar_first=True)


def test_names_read_as_words_of_any_rig_family():
    assert tokens("mixamorig:LeftUpLeg") == ["left", "up", "leg"]
    assert side_and_stem("CC_Base_L_Thigh") == ("left", "thigh")
    assert side_and_stem("UpperArm.R") == ("right", "upperarm")
    assert side_and_stem("J_Bip_C_UpperChest") == (None, "upperchest")
    assert side_and_stem("spine_01") == (None, "spine1")
    assert side_and_stem("LHipJoint") == ("left", "hipjoint")  # not the hip: CMU's pelvis bone


@pytest.mark.parametrize("family", list(FAMILIES))
def test_every_rig_family_maps_with_no_map_and_round_trips_in_full(model, family):
    motion, carries = FAMILIES[family]
    sk = motion.skeleton
    demo = body_parts(tpose_skeleton())
    parts = body_parts(sk, motion.rotations[0])
    expected = {p: carries.get(tpose_skeleton().names[j]) for p, j in demo.items() if p in CHECKED}
    assert {p: sk.names[parts[p]] for p in expected if expected[p]} == {p: n for p, n in expected.items() if n}
    jm = joint_map(model.skeleton, sk, None, model.stats().reference, motion.rotations[0])
    back = to_source(to_target(motion, jm), jm, motion)
    # every joint's global rotation, swing and twist, comes back (scipy as the oracle)
    angle = (global_rotations(back) * global_rotations(motion).inv()).magnitude()
    assert np.degrees(angle).max() < 1e-6


def test_every_family_gives_the_model_the_same_motion_as_the_demo_rig(model):
    """The mapping is the same whatever the rig: the model sees one motion from every family
    (families with toes; a rig without toes leaves the foot's roll to its rest)."""
    reference = None
    for family, (motion, _) in FAMILIES.items():
        jm = joint_map(model.skeleton, motion.skeleton, None, model.stats().reference, motion.rotations[0])
        on_model = to_target(motion, jm)
        rot = Rotation.from_quat(on_model.rotations.reshape(-1, 4), scalar_first=True)
        if reference is None:
            reference = rot
        angles = np.degrees((rot * reference.inv()).magnitude()).reshape(motion.n_frames, -1)
        feet = [model.skeleton.index(n) for n in ("Foot_L", "Foot_R", "Toes_L", "Toes_R")]
        others = np.delete(angles, feet, axis=1) if "no toes" in family else angles
        assert others.max() < 1e-6, family


def test_the_real_cmu_sample_rigs_map_as_their_hand_written_maps(shared_data, model):
    from styleerd.data.datasets import unpack

    base = unpack(shared_data / "cmu-sample.tar.xz") / "cmu-sample"
    tp = body_parts(model.skeleton)
    for rig, folder in (("cc-base", "iclone"), ("cmu-asf", "asf-names")):
        for clip in sorted((base / folder).glob("*.bvh"))[::10]:
            m = bvh.read(clip)
            parts = body_parts(m.skeleton, m.rotations[0])
            found = {model.skeleton.names[j]: m.skeleton.names[parts[p]] for p, j in tp.items() if p in parts}
            assert {k: found.get(k) for k in RIG_MAPS[rig]} == RIG_MAPS[rig], clip
            assert all(p in parts for p in REQUIRED)


def test_robot_expressive_maps_with_its_ik_feet_and_no_hand_joint(shared_data, model):
    from styleerd.motion.gltf import read_gltf

    g = read_gltf(shared_data / "characters" / "RobotExpressive.glb")
    sk = g.motion.skeleton
    parts = {p: sk.names[j] for p, j in body_parts(sk, g.motion.rotations[0]).items()}
    assert parts["left_foot"] == "Foot.L" and parts["right_foot"] == "Foot.R"  # under the root, not the legs
    assert (parts["left_hip"], parts["left_knee"], parts["left_shoulder"]) == ("UpperLeg.L", "LowerLeg.L", "UpperArm.L")
    assert parts["left_hand"].startswith("Palm") and parts["left_collar"] == "Shoulder.L"
    assert "PoleTarget.L" not in parts.values()
    jm = joint_map(model.skeleton, sk, None, model.stats().reference, g.motion.rotations[0])
    back = to_source(to_target(g.motion, jm), jm, g.motion)
    assert np.degrees((global_rotations(back) * global_rotations(g.motion).inv()).magnitude()).max() < 1e-6


def _creature(legs: int) -> Skeleton:
    """A body along +Z with ``legs`` legs hanging down in pairs and a head in front: a quadruped
    (4) or a crab (8)."""
    names, parents, offsets = ["body"], [-1], [(0.0, 50.0, 0.0)]
    for k in range(legs):
        z = 30.0 - 60.0 * (k // 2) / max(legs // 2 - 1, 1)
        x = 15.0 if k % 2 == 0 else -15.0
        names += [f"leg{k}_upper", f"leg{k}_lower", f"leg{k}_paw"]
        parents += [0, len(names) - 3, len(names) - 2]
        offsets += [(x, -5.0, z), (0.0, -20.0, 0.0), (0.0, -24.0, 0.0)]
    names += ["neck", "skull"]
    parents += [0, len(names) - 2]
    offsets += [(0.0, 10.0, 40.0), (0.0, 5.0, 15.0)]
    return Skeleton(
        tuple(names), np.array(parents), np.array(offsets), (("Zrotation", "Xrotation", "Yrotation"),) * len(names)
    )


@pytest.mark.parametrize("legs", [4, 8])
def test_non_humanoids_are_refused_in_one_line(model, legs):
    with pytest.raises(ValueError) as e:
        joint_map(model.skeleton, _creature(legs))
    assert str(e.value).startswith("not a humanoid") and "\n" not in str(e.value)


def _numbered(family: str = "numbered joints (CesiumMan-like: Skeleton_torso_joint_1, leg_joint_L_1)"):
    return FAMILIES[family][0]


def test_wrong_maps_are_refused_with_the_reason(model):
    mixamo = FAMILIES["Mixamo (mixamorig:), extra Armature root"][0].skeleton
    with pytest.raises(ValueError, match="left hand and right hand are both mapped to 'mixamorig:RightHand'"):
        joint_map(model.skeleton, mixamo, {"Hand_L": "mixamorig:RightHand"})
    with pytest.raises(
        ValueError, match="left elbow 'mixamorig:RightForeArm' is a right-side joint: the bone would cross"
    ):
        joint_map(
            model.skeleton, mixamo, {"LowerArm_L": "mixamorig:RightForeArm", "LowerArm_R": "mixamorig:LeftForeArm"}
        )
    with pytest.raises(
        ValueError, match="left hand 'mixamorig:LeftForeArm' does not hang below left elbow 'mixamorig:LeftHand'"
    ):
        joint_map(model.skeleton, mixamo, {"LowerArm_L": "mixamorig:LeftHand", "Hand_L": "mixamorig:LeftForeArm"})
    nameless = FAMILIES["nameless nodes (node<N>)"][0]
    parts = body_parts(nameless.skeleton)
    left, right = (nameless.skeleton.names[parts[f"{s}_shoulder"]] for s in ("left", "right"))
    swapped = {"UpperArm_L": right, "UpperArm_R": left}
    with pytest.raises(ValueError, match="is not left of .*: the bones would cross the body"):
        joint_map(model.skeleton, nameless.skeleton, swapped)


def _armless(tmp_path):
    """A numbered rig whose arms end at the elbow (nothing to find the hands by): written as BVH."""
    m = _numbered()
    keep = [j for j, n in enumerate(m.skeleton.names) if "arm_joint" not in n or n.endswith(("__4_", "__3_"))]
    sk = m.skeleton
    index = {j: k for k, j in enumerate(keep)}
    small = Skeleton(
        tuple(sk.names[j] for j in keep),
        np.array([-1 if sk.parents[j] < 0 else index[int(sk.parents[j])] for j in keep]),
        sk.offsets[keep],
        tuple(sk.channels[j] for j in keep),
    )
    from styleerd.motion.motion import Motion

    path = tmp_path / "armless.bvh"
    bvh.write(path, Motion(small, m.rotations[:, keep], m.positions[:, keep], m.fps))
    return path


def test_an_unmappable_rig_shows_its_joint_tree_and_a_map_to_edit(tmp_path):
    path = _armless(tmp_path)
    run = [sys.executable, "-m", "styleerd.cli", "transfer", str(path), "--style", "elderly"]
    r = subprocess.run([*run, "-o", str(tmp_path / "out.bvh")], check=False, capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "cannot map the skeleton: no joint found for left shoulder (model joint UpperArm_L)" in r.stderr
    assert "(an arm has no elbow between the shoulder and the hand)" in r.stderr
    assert "    Skeleton_torso_joint_2" in r.stderr  # its own tree, indented
    assert "--write-joint-map" in r.stderr and not (tmp_path / "out.bvh").exists()
    r = subprocess.run(
        [*run, "--write-joint-map", str(tmp_path / "map.json")], check=False, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    guessed = json.loads((tmp_path / "map.json").read_text())
    assert guessed["Hips"] == "Skeleton_torso_joint_1" and guessed["UpperLeg_L"] == "Skeleton_leg_joint_L_1"
    assert guessed["Hand_L"] == ""
    guessed |= {"UpperArm_L": "Skeleton_arm_joint_L__4_", "LowerArm_L": "Skeleton_arm_joint_L__3_"}
    guessed |= {"Hand_L": "Skeleton_arm_joint_L__3_"}
    (tmp_path / "map.json").write_text(json.dumps(guessed))
    r = subprocess.run(
        [*run, "-o", str(tmp_path / "out.bvh"), "--joint-map", str(tmp_path / "map.json")],
        check=False,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "both mapped to 'Skeleton_arm_joint_L__3_'" in r.stderr


def test_optional_parts_are_a_subset_the_mapping_knows():
    assert set(OPTIONAL).isdisjoint(REQUIRED)


def test_info_shows_a_rigs_mapping_or_why_there_is_none(shared_data, tmp_path):
    """``styleerd info`` on a BVH: frames, rate and channels, the joint tree, and the mapping onto
    the model (bone frames from the first frame where the rest pose is no T-pose), or the reason
    there is none and what to do; a joint map passed is used."""
    info = [sys.executable, "-m", "styleerd.cli", "info"]
    cmu = shared_data / "cmu-sample.tar.xz"
    from styleerd.data.datasets import unpack

    take = unpack(cmu) / "cmu-sample" / "asf-names" / "126_01.bvh"
    r = subprocess.run([*info, str(take)], check=False, capture_output=True, text=True)
    assert r.returncode == 0 and not r.stderr, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].endswith("126_01.bvh: 2593 frames at 120 fps (21.61 s), 31 joints, 96 channels")
    assert "  Hips  [Xposition Yposition Zposition Zrotation Yrotation Xrotation]" in lines
    mapped = dict(line.strip().split(" <- ") for line in lines if line.startswith("  ") and " <- " in line)
    assert {k: mapped.get(k) for k in RIG_MAPS["cmu-asf"]} == RIG_MAPS["cmu-asf"] and len(mapped) == 21
    assert lines[-1].endswith("taken from: the first frame (the rest pose is no T- or A-pose)")
    path = _armless(tmp_path)
    r = subprocess.run([*info, str(path)], check=False, capture_output=True, text=True)
    assert r.returncode == 0 and not r.stderr, r.stderr
    assert "\n    Skeleton_torso_joint_2  [Zrotation Xrotation Yrotation]\n" in r.stdout  # the tree, indented
    assert "no joint mapping onto the model:" in r.stdout and "no joint found for left shoulder" in r.stdout
    assert "--write-joint-map" in r.stdout and r.stdout.count("Skeleton_torso_joint_2") == 1
    wrong = {"Hand_L": "Skeleton_arm_joint_L__3_", "LowerArm_L": "Skeleton_arm_joint_L__3_"}
    (tmp_path / "map.json").write_text(json.dumps(wrong))
    r = subprocess.run(
        [*info, str(path), "--joint-map", str(tmp_path / "map.json")], check=False, capture_output=True, text=True
    )
    assert r.returncode == 0 and "both mapped to 'Skeleton_arm_joint_L__3_'" in r.stdout


def test_info_on_a_folder_says_in_two_lines_a_file_what_it_is_and_whether_it_maps(shared_data, tmp_path):
    """Before a batch: every motion file of a folder (and below), its first line and whether it maps
    onto the model; a file that cannot be read is said in one line and the next one read."""
    import shutil

    from styleerd.data.datasets import unpack

    take = unpack(shared_data / "cmu-sample.tar.xz") / "cmu-sample" / "asf-names" / "126_01.bvh"
    (tmp_path / "takes" / "more").mkdir(parents=True)
    shutil.copy(take, tmp_path / "takes" / "more" / "swim.bvh")
    shutil.copy(_armless(tmp_path), tmp_path / "takes" / "armless.bvh")
    (tmp_path / "takes" / "broken.bvh").write_text("HIERARCHY\nROOT a\n{\n")
    (tmp_path / "takes" / "notes.txt").write_text("not a motion")
    info = [sys.executable, "-m", "styleerd.cli", "info", str(tmp_path / "takes")]
    r = subprocess.run(info, check=False, capture_output=True, text=True)
    assert r.returncode == 0 and not r.stderr, r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 2 + 1 + 2 + 1 and "notes.txt" not in r.stdout
    assert lines[0].endswith("takes/armless.bvh: 360 frames at 60 fps (6.00 s), 17 joints, 54 channels")
    assert lines[1].startswith("  no joint mapping onto the model: cannot map the skeleton: no joint found")
    assert lines[2].startswith(str(tmp_path / "takes" / "broken.bvh") + ":") and lines[2].count("broken.bvh") == 1
    assert lines[3].endswith("more/swim.bvh: 2593 frames at 120 fps (21.61 s), 31 joints, 96 channels")
    assert lines[4] == "  maps onto the model"
    assert lines[5] == "3 files: 1 map onto the model, 1 do not, 1 unread"
