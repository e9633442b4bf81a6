"""glTF export read back with pygltflib; joint positions from its nodes and animation
(scipy rotations, an independent forward kinematics) against ours."""

import numpy as np
import pygltflib as gl
from conftest import walking_motion
from scipy.spatial.transform import Rotation

from styleerd.motion.gltf import write_glb
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.procedural import walk


def read_accessor(doc, blob, index):
    a = doc.accessors[index]
    v = doc.bufferViews[a.bufferView]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
    return np.frombuffer(
        blob, dtype=np.float32, count=a.count * width, offset=v.byteOffset + (a.byteOffset or 0)
    ).reshape(a.count, width)


def world_positions_from_glb(path):
    doc = gl.GLTF2().load(str(path))
    blob = doc.binary_blob()
    top = doc.nodes[doc.scenes[doc.scene].nodes[0]]
    n = len(doc.nodes) - 1
    anim = doc.animations[0]
    T = doc.accessors[anim.samplers[0].input].count
    rot = np.tile([0.0, 0, 0, 1], (T, n, 1))
    pos = np.array([doc.nodes[j].translation for j in range(n)], float)[None].repeat(T, 0)
    for ch in anim.channels:
        values = read_accessor(doc, blob, anim.samplers[ch.sampler].output)
        (rot if ch.target.path == "rotation" else pos)[:, ch.target.node] = values
    parent = {c: p for p in range(n) for c in doc.nodes[p].children}
    world_r, world_p = [None] * n, [None] * n
    for j in range(n):  # nodes are written parents first
        r = Rotation.from_quat(rot[:, j])
        if j in parent:
            world_p[j] = world_r[parent[j]].apply(pos[:, j]) + world_p[parent[j]]
            world_r[j] = world_r[parent[j]] * r
        else:
            world_p[j], world_r[j] = pos[:, j], r
    return np.stack(world_p, 1) * top.scale[0], doc, T


def test_glb_joint_positions_match_forward_kinematics(tmp_path):
    for motion, scale in ((walk(2.0), 0.01), (walking_motion(30), 0.01)):
        write_glb(tmp_path / "m.glb", motion)
        got, doc, T = world_positions_from_glb(tmp_path / "m.glb")
        _, ours = forward_kinematics(motion.rotations, motion.positions, motion.skeleton.parents)
        assert T == motion.n_frames and [x.name for x in doc.nodes[:-1]] == list(motion.skeleton.names)
        assert np.abs(got - ours * scale).max() < 1e-5  # float32 in metres
        assert len(doc.skins[0].joints) == motion.skeleton.n_joints
        times = read_accessor(doc, doc.binary_blob(), doc.animations[0].samplers[0].input)[:, 0]
        assert np.allclose(np.diff(times), 1 / motion.fps, atol=1e-6)


def test_transfer_writes_the_same_motion_as_glb_and_bvh(tmp_path):
    from styleerd.model.checkpoint import load_generator
    from styleerd.motion import bvh
    from styleerd.runtime.offline import TransferOptions, transfer_file

    model, _meta = load_generator()
    bvh.write(tmp_path / "in.bvh", walk(1.0))
    transfer_file(
        tmp_path / "in.bvh",
        tmp_path / "out.bvh",
        model,
        30.0,
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
    )
    a = bvh.read(tmp_path / "out.bvh")
    transfer_file(
        tmp_path / "in.bvh",
        tmp_path / "out.glb",
        model,
        30.0,
        TransferOptions({"elderly": 1.0}, input_style="normal", content="walk"),
    )
    got, _, T = world_positions_from_glb(tmp_path / "out.glb")
    _, ours = forward_kinematics(a.rotations, a.positions, a.skeleton.parents)
    assert T == a.n_frames and np.abs(got - ours * 0.01).max() < 1e-4  # the BVH went through text
