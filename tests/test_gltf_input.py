"""glTF / VRM in: a character file's skeleton and animation are read (rest rotations, rolled
joint frames, a units node above the root, VRM humanoid bone names), stylised, and written
back as the same file with only the animation replaced; the Khronos validator passes both."""

import numpy as np
import pygltflib as gl
import pytest
from test_gltf_mesh import needs_node, validate
from test_rotations import scipy_globals

from styleerd.errors import StyleERDError
from styleerd.eval.rotations import rotation_errors
from styleerd.model.checkpoint import load_generator
from styleerd.motion import bvh, quat
from styleerd.motion.gltf import read_gltf, write_glb
from styleerd.motion.procedural import walk, with_rest_frames
from styleerd.runtime.offline import TransferOptions, transfer_file

VRM_BONES = {
    "Hips": "hips",
    "Spine": "spine",
    "Spine2": "upperChest",
    "Spine1": "chest",
    "Neck": "neck",
    "Head": "head",
}
for side in ("Left", "Right"):
    s = side.lower()
    VRM_BONES.update(
        {
            f"{side}Shoulder": f"{s}Shoulder",
            f"{side}Arm": f"{s}UpperArm",
            f"{side}ForeArm": f"{s}LowerArm",
            f"{side}Hand": f"{s}Hand",
            f"{side}UpLeg": f"{s}UpperLeg",
            f"{side}Leg": f"{s}LowerLeg",
            f"{side}Foot": f"{s}Foot",
            f"{side}ToeBase": f"{s}Toes",
        }
    )


def vrm_character(path, seconds: float = 3.0, seed: int = 0):
    """A VRM-1.0-style character made here: the demo walk on a rig whose joint frames are
    rolled about their bones (rest rotations in the nodes, T-pose geometry), meaningless node
    names (only the VRM humanoid says which bone is which), a skinned body, in metres."""
    original = walk(seconds, fps=30.0)
    sk = original.skeleton
    rng = np.random.default_rng(seed)
    frames = quat.identity((sk.n_joints,))
    for j in range(sk.n_joints):
        kids = sk.children(j)
        along = sk.offsets[kids[0]] if kids else sk.offsets[j]
        frames[j] = quat.from_angle_axis(rng.uniform(-np.pi, np.pi), along / np.linalg.norm(along))
    rolled = with_rest_frames(original, frames, tuple(f"bone_{j:02d}" for j in range(sk.n_joints)))
    parent_frames = np.where(
        (sk.parents >= 0)[:, None], frames[np.maximum(sk.parents, 0)], quat.identity((sk.n_joints,))
    )
    write_glb(path, rolled, mesh=True, rest_rotations=quat.mul(quat.inv(parent_frames), frames))
    doc = gl.GLTF2().load_binary(str(path))
    bones = {VRM_BONES[n]: {"node": j} for j, n in enumerate(sk.names)}
    doc.extensionsUsed = ["VRMC_vrm"]
    doc.extensions = {
        "VRMC_vrm": {
            "specVersion": "1.0",
            "meta": {"name": "test", "licenseUrl": "https://example.invalid", "avatarPermission": "onlyAuthor"},
            "humanoid": {"humanBones": bones},
        }
    }
    doc.save_binary(str(path))
    return original


@pytest.fixture(scope="module")
def model():
    return load_generator()


def test_reading_a_character_gives_its_movement(tmp_path):
    original = vrm_character(tmp_path / "character.vrm")
    got = read_gltf(tmp_path / "character.vrm")
    assert got.motion.n_frames == original.n_frames and got.motion.fps == 30.0
    assert got.parts["left_knee"] == "bone_15" and got.parts["chest"] == "bone_03"  # upperChest wins over chest
    for a, b in zip(
        scipy_globals(original), scipy_globals(got.motion)
    ):  # world-aligned rest: the same rotations as the T-pose rig
        assert np.degrees((a.inv() * b).magnitude()).max() < 1e-3
    g = got.motion
    from styleerd.motion.kinematics import forward_kinematics

    p_orig = forward_kinematics(original.rotations, original.positions, original.skeleton.parents)[1] * 0.01  # metres
    p_got = forward_kinematics(g.rotations, g.positions, g.skeleton.parents)[1]
    assert np.abs(p_orig - p_got).max() < 1e-5


@needs_node
def test_vrm_round_trip_keeps_the_file_and_the_rotations(model, tmp_path):
    g, meta = model
    vrm_character(tmp_path / "character.vrm")
    lines = []
    transfer_file(
        tmp_path / "character.vrm",
        tmp_path / "out.vrm",
        g,
        meta["data"]["fps"],
        TransferOptions({"normal": 1.0}, input_style="normal", content="walk"),
        report=lines.append,
    )
    assert (
        "first frame" not in lines[0] and "rest pose (a T- or A-pose)" in lines[0]
    )  # the VRM's rest pose is its T-pose
    src, out = (
        gl.GLTF2().load_binary(str(tmp_path / "character.vrm")),
        gl.GLTF2().load_binary(str(tmp_path / "out.vrm")),
    )
    assert [n.name for n in out.nodes] == [n.name for n in src.nodes]
    assert [(n.rotation, n.translation, n.mesh, n.skin, n.children) for n in out.nodes] == [
        (n.rotation, n.translation, n.mesh, n.skin, n.children) for n in src.nodes
    ]
    assert (
        len(out.meshes) == len(src.meshes) == 1
        and out.skins[0].joints == src.skins[0].joints
        and out.extensions == src.extensions
    )
    assert len(out.animations) == 1
    for path in ("character.vrm", "out.vrm"):
        issues = validate(tmp_path / path)["issues"]
        assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), (path, issues["messages"][:10])
    source = read_gltf(tmp_path / "character.vrm")
    a, b = source.motion, read_gltf(tmp_path / "out.vrm").motion
    errors = rotation_errors(a, b, sorted(a.skeleton.index(n) for n in source.parts.values()))
    assert len(errors) == 21
    legs_and_trunk = {
        k: v for k, v in errors.items() if k in ("bone_00", "bone_01", "bone_14", "bone_15", "bone_18", "bone_19")
    }
    assert max(v[2] for v in legs_and_trunk.values()) < 12, errors  # twist kept, as on the BVH rigs
    assert max(v[0] for v in errors.values()) < 30, errors


def test_gltf_to_bvh_and_bad_gltf_inputs(model, tmp_path):
    g, meta = model
    vrm_character(tmp_path / "c.glb", seconds=1.0)
    transfer_file(
        tmp_path / "c.glb",
        tmp_path / "c.bvh",
        g,
        meta["data"]["fps"],
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
    )
    assert bvh.read(tmp_path / "c.bvh").n_frames == 30
    (tmp_path / "junk.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
    with pytest.raises(StyleERDError, match="junk.glb: not a readable glTF file"):
        transfer_file(
            tmp_path / "junk.glb",
            tmp_path / "x.glb",
            g,
            30.0,
            TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
        )
    doc = gl.GLTF2().load_binary(str(tmp_path / "c.glb"))
    doc.animations = []
    doc.save_binary(str(tmp_path / "still.glb"))
    with pytest.raises(StyleERDError, match="still.glb: no animation to stylise"):
        transfer_file(
            tmp_path / "still.glb",
            tmp_path / "x.glb",
            g,
            30.0,
            TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
        )
    with pytest.raises(StyleERDError, match="the output must be .glb, .vrm, .vrma or .bvh"):
        transfer_file(
            tmp_path / "c.glb",
            tmp_path / "x.fbx",
            g,
            30.0,
            TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
        )
    assert not (tmp_path / "x.glb").exists()


def test_vrm_0x_humanoid_names_the_bones_too(tmp_path):
    vrm_character(tmp_path / "c.vrm", seconds=1.0)
    doc = gl.GLTF2().load_binary(str(tmp_path / "c.vrm"))
    bones = doc.extensions["VRMC_vrm"]["humanoid"]["humanBones"]
    doc.extensionsUsed = ["VRM"]
    doc.extensions = {"VRM": {"humanoid": {"humanBones": [{"bone": b, "node": v["node"]} for b, v in bones.items()]}}}
    doc.save_binary(str(tmp_path / "old.vrm"))
    assert read_gltf(tmp_path / "old.vrm").parts == read_gltf(tmp_path / "c.vrm").parts
