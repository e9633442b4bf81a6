"""A motion put on the user's own avatar (``transfer --onto``): a generated walk on a non-Mixamo
rig, a VRM Animation and RobotExpressive's dance, stylised and worn by Godette (a real VRM 0.x
avatar with no animation): the avatar file kept (nodes, meshes, materials, VRM extensions), the
validator finding nothing new, the feet at the floor, the hands at their sides of the body, the
avatar travelling as the input does, scaled to its legs."""

import subprocess
import sys

import numpy as np
import pygltflib as gl
import pytest
from test_gltf_mesh import needs_node, validate

from styleerd.motion import bvh
from styleerd.motion.gltf import read_gltf, read_gltf_character
from styleerd.motion.humanoid import body_parts
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.procedural import rig_families
from styleerd.motion.resample import resample

CLI = [sys.executable, "-m", "styleerd.cli", "transfer"]


@pytest.fixture(scope="module")
def characters(shared_data):
    return shared_data / "characters"


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, check=False, timeout=600)


def body(motion):
    """Per frame: the lowest foot or toe joint's height, the hips' ground position, and the
    hands' offsets across the body (left minus the hips' middle, along left hip minus right hip)."""
    p = body_parts(motion.skeleton, motion.rotations[0])
    _, g = forward_kinematics(motion.rotations, motion.positions, motion.skeleton.parents)
    feet = [p[k] for k in ("left_foot", "right_foot", "left_toe", "right_toe") if k in p]
    across = g[:, p["left_hip"]] - g[:, p["right_hip"]]
    across /= np.linalg.norm(across, axis=-1, keepdims=True)
    middle = (g[:, p["left_hip"]] + g[:, p["right_hip"]]) / 2
    hands = [((g[:, p[f"{s}_hand"]] - middle) * across).sum(-1) for s in ("left", "right")]
    return g[:, feet, 1].min(1), g[:, p["hips"]][:, [0, 2]], hands


def test_a_walk_on_a_character_creator_rig_worn_by_a_vrm_avatar(characters, tmp_path):
    walk = rig_families()["Character Creator (CC_Base_, twist and share bones, RL_BoneRoot)"][0][:180]
    bvh.write(tmp_path / "walk.bvh", walk)
    avatar = characters / "Godette.vrm"
    r = run(tmp_path / "walk.bvh", "--style", "elderly", "--onto", avatar, "-o", tmp_path / "walk.vrm")
    assert r.returncode == 0, r.stderr
    assert "onto Godette.vrm (model -> avatar)" in r.stdout
    src, out = gl.GLTF2().load_binary(str(avatar)), gl.GLTF2().load_binary(str(tmp_path / "walk.vrm"))
    assert [n.name for n in out.nodes] == [n.name for n in src.nodes]
    assert (len(out.meshes), len(out.materials), len(out.skins)) == (len(src.meshes), len(src.materials), 1)
    assert out.extensions == src.extensions and len(out.animations) == 1
    worn = read_gltf(tmp_path / "walk.vrm").motion
    rest = read_gltf_character(avatar).motion
    assert worn.n_frames == walk.n_frames
    lowest, ground, hands = body(worn)
    rest_lowest = body(rest)[0][0]
    assert lowest.min() > rest_lowest - 0.03 and np.median(lowest) < rest_lowest + 0.03  # on the floor, not in it
    assert (hands[0] > 0).all() and (hands[1] < 0).all()  # each hand on its own side: no arm across the body
    travelled = np.linalg.norm(ground[-1] - ground[0])
    src_travel = np.linalg.norm(np.diff(body(walk)[1][[0, -1]], axis=0)) / 100  # centimetres -> metres
    assert 0.4 * src_travel < travelled < 1.2 * src_travel  # scaled by the legs, Godette's are shorter


def test_a_vrm_animation_and_a_glb_clip_worn_and_bvh_out(characters, tmp_path):
    avatar = characters / "Godette.vrm"
    r = run(characters / "test.vrma", "--style", "feminine", "--onto", avatar, "-o", tmp_path / "a.vrm")
    assert r.returncode == 0, r.stderr
    assert read_gltf(tmp_path / "a.vrm").motion.n_frames == read_gltf(characters / "test.vrma").motion.n_frames
    robot = characters / "RobotExpressive.glb"
    r = run(robot, "--style", "elderly", "--animation", "Dance", "--onto", avatar, "-o", tmp_path / "dance.glb")
    assert r.returncode == 0, r.stderr
    assert [a.name for a in gl.GLTF2().load_binary(str(tmp_path / "dance.glb")).animations] == ["Dance"]
    r = run(robot, "--style", "elderly", "--onto", avatar, "-o", tmp_path / "all.bvh")
    assert r.returncode == 2 and "pick one with --animation NAME" in r.stderr
    r = run(robot, "--style", "elderly", "--animation", "Wave", "--onto", avatar, "-o", tmp_path / "wave.bvh")
    assert r.returncode == 0 and bvh.read(tmp_path / "wave.bvh").skeleton.n_joints == 68
    r = run(robot, "--style", "elderly", "--onto", tmp_path / "missing.vrm", "-o", tmp_path / "x.vrm")
    assert r.returncode == 2 and "Traceback" not in r.stderr and not (tmp_path / "x.vrm").exists()


@needs_node
def test_the_avatar_wearing_a_motion_is_as_valid_as_the_avatar(characters, tmp_path):
    walk = rig_families()["Mixamo (mixamorig:), extra Armature root"][0][:60]
    bvh.write(tmp_path / "walk.bvh", walk)
    avatar = characters / "Godette.vrm"
    assert (
        run(tmp_path / "walk.bvh", "--style", "exhausted", "--onto", avatar, "-o", tmp_path / "o.vrm").returncode == 0
    )

    def counts(path):
        issues = validate(path)["issues"]
        return issues["numErrors"], issues["numWarnings"], sorted({m["code"] for m in issues["messages"]})

    assert counts(tmp_path / "o.vrm") == counts(avatar)


def test_a_live_stylizer_on_an_avatar_with_no_animation(characters, tmp_path):
    """``model.stylizer(skeleton="avatar.vrm")``: a VRM avatar with no animation gives its skeleton
    (it was refused: "no animation to stylise"), its humanoid maps it, and the stream runs at the
    model's rate; a motion worn by it, streamed frame by frame, comes out as the whole-motion
    transfer with the same map does."""
    import styleerd
    from styleerd.runtime.offline import humanoid_joint_map

    worn = tmp_path / "worn.bvh"
    r = run(characters / "test.vrma", "--onto", characters / "Godette.vrm", "--style", "normal", "-o", worn)
    assert r.returncode == 0, r.stderr
    motion = resample(bvh.read(worn), 30.0)  # the model's rate, where a stream and a file are stepped alike
    model = styleerd.load()
    live = model.stylizer("elderly", skeleton=characters / "Godette.vrm", input_style="normal")
    assert live.skeleton.names == motion.skeleton.names and live.n_channels == bvh.channel_values(motion).shape[1]
    streamed = np.stack([live.step(frame) for frame in bvh.channel_values(motion)])
    vrm = humanoid_joint_map(model.weights, read_gltf_character(characters / "Godette.vrm"), None)
    whole = model.transfer(motion, "elderly", input_style="normal", joint_map=vrm)
    assert np.abs(streamed - bvh.channel_values(whole)).max() < 1e-3  # degrees and cm: one stream, two call paths
    assert np.abs(streamed - bvh.channel_values(motion)).max() > 5.0  # stylised, not passed through
    animated = model.stylizer("elderly", skeleton=characters / "test.vrma")
    assert animated.channels.fps == 10.0  # an animated file's stream rate is its animation's
