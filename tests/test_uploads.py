"""What the viewer's page uploads (``serve.uploads``): a VRM Animation read into BVH text that the
BVH reader takes back, and a GLB character's humanoid and T-pose, checked by setting the T-pose on
the file's own nodes and composing them with scipy: arms out to the sides at shoulder height, the
left hand on +X, legs straight down, facing +Z."""

from __future__ import annotations

import numpy as np
import pygltflib as gl
from scipy.spatial.transform import Rotation

from styleerd.model.stored import load_generator_weights
from styleerd.motion import bvh
from styleerd.serve.uploads import avatar_rig, motion_bvh


def test_a_vrm_animation_comes_back_as_bvh(shared_data):
    out = motion_bvh(shared_data / "characters" / "test.vrma")
    m = bvh.parse(out["bvh"])
    assert m.n_frames == out["frames"] > 10 and abs(m.fps - out["fps"]) < 1e-6
    assert "hips" in m.skeleton.names and np.isfinite(m.rotations).all()
    assert np.ptp(m.rotations, axis=0).max() > 0.1  # it moves


def test_a_glb_characters_t_pose_on_its_own_nodes(shared_data):
    path = shared_data / "characters" / "RobotExpressive.glb"
    rig = avatar_rig(path, load_generator_weights(None))
    assert {"hips", "spine", "head", "leftUpperArm", "leftHand", "rightHand", "leftFoot", "rightFoot"} <= set(
        rig["bones"]
    )
    doc = gl.GLTF2().load_binary(str(path))
    parent = {c: i for i, n in enumerate(doc.nodes) for c in n.children or []}

    def world(i: int) -> tuple[Rotation, np.ndarray, np.ndarray]:
        n = doc.nodes[i]
        r = Rotation.from_quat(rig["tpose"].get(str(i), n.rotation or [0, 0, 0, 1]))
        t, s = np.array(n.translation or [0.0, 0, 0]), np.array(n.scale or [1.0, 1, 1])
        if i not in parent:
            return r, t, s
        pr, pt, ps = world(parent[i])
        return pr * r, pt + pr.apply(ps * t), ps * s

    at = {name: world(node)[1] for name, node in rig["bones"].items()}
    height = at["head"][1] - min(at["leftFoot"][1], at["rightFoot"][1])
    for side, sign in (("left", 1), ("right", -1)):
        arm = at[f"{side}Hand"] - at[f"{side}UpperArm"]
        assert sign * arm[0] > 0.3 * height and abs(arm[1]) < 0.02 * height and abs(arm[2]) < 0.05 * height, arm
        leg = at[f"{side}Foot"] - at[f"{side}UpperLeg"]
        assert leg[1] < -0.2 * height and np.hypot(leg[0], leg[2]) < 0.15 * abs(leg[1]), leg
    across = at["leftUpperArm"] - at["rightUpperArm"]
    facing = np.cross(across, [0.0, 1.0, 0.0])
    assert facing[2] > 0.9 * np.linalg.norm(facing), facing  # left on +X, up +Y: facing +Z
