"""What the viewer's page uploads besides BVH: a motion in a glTF file (a VRM Animation, a GLB's
first animation) read into BVH text for the page to stream, and an avatar that is no VRM (a GLB
character, or an FBX one made a GLB by Blender where its ``bpy`` is installed) read into what the
page needs to drive it like one: the node of each VRM humanoid bone,
found by ``motion.humanoid`` as ``transfer --onto`` finds it, and every joint's local rotation in
the canonical T-pose (VRM's rest: facing +Z, left along +X), which the page sets before it builds
three-vrm's humanoid on the nodes."""

from __future__ import annotations

import re
import threading
from pathlib import Path

import numpy as np

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import bvh, quat
from styleerd.motion.gltf import VRM_PARTS, read_gltf_character, read_gltf_clips
from styleerd.motion.retarget import body_parts
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.offline import humanoid_joint_map, map_skeleton

MOTIONS = (".vrma", ".glb", ".vrm")  # a .gltf's buffers are files of their own: not one upload
AVATARS = (".glb", ".fbx")  # a .vrm avatar is read by the page itself (three-vrm); an FBX needs Blender's bpy
_BLENDER = threading.Lock()  # bpy is one Blender: one FBX at a time
MAX_BVH_CHARS = 32 << 20  # the text a page is sent back


def _bvh_names(skeleton: Skeleton) -> Skeleton:
    """The skeleton with names BVH can carry: no spaces or braces, each once."""
    names: list[str] = []
    for name in skeleton.names:
        clean = re.sub(r"[\s{}]+", "_", name) or "joint"
        while clean in names:
            clean += "_"
        names.append(clean)
    return Skeleton(tuple(names), skeleton.parents, skeleton.offsets, skeleton.channels, skeleton.end_sites)


def motion_bvh(path: Path) -> dict:
    """The first animation of a glTF file as BVH text, with its name, frames and rate."""
    name, clip = read_gltf_clips(path, [0])[0]
    m = clip.motion
    text = bvh.format_bvh(type(m)(_bvh_names(m.skeleton), m.rotations, m.positions, m.fps), precision=6)
    if len(text) > MAX_BVH_CHARS:
        raise StyleERDError(
            f"{path.name}: animation {name!r} is {m.n_frames} frames of {m.skeleton.n_joints} joints, too long for the "
            "viewer; stylise it with styleerd transfer"
        )
    return {"bvh": text, "animation": name, "frames": m.n_frames, "fps": m.fps}


def avatar_rig(path: Path, model: GeneratorWeights) -> dict:
    """A GLB character as a VRM humanoid: ``bones`` (VRM bone name -> glTF node) and ``tpose``
    (glTF node -> its local rotation x, y, z, w in the canonical T-pose). An FBX character is
    first made a GLB by Blender: then ``glb`` holds its bytes, for the page to load."""
    if path.suffix.lower() == ".fbx":
        glb = path.with_suffix(".glb")
        with _BLENDER:
            from styleerd.runtime.fbx import fbx_to_glb  # imports bpy: only for FBX

            fbx_to_glb(path, glb)
        return {**avatar_rig(glb, model), "glb": glb.read_bytes()}
    character = read_gltf_character(path)
    rest = character.motion
    jm = map_skeleton(rest.skeleton, model, humanoid_joint_map(model, character, None), path.name, rest.rotations[0])
    parts = body_parts(rest.skeleton, rest.rotations[0])
    bone_of = {part: bone for bone, part in VRM_PARTS.items() if bone != "upperChest"}
    bones = {bone_of[p]: character.nodes[j] for p, j in parts.items() if p in bone_of}
    # the T-pose as the skeleton's local rotations (its frames are the rest's, world-aligned), then as each
    # node's, as ``gltf.write_gltf_animations`` keys them (the root's: under the nodes above it)
    sk, tpose = rest.skeleton, jm.source_tpose
    above = np.where((sk.parents >= 0)[:, None], tpose[np.maximum(sk.parents, 0)], quat.identity((sk.n_joints,)))
    parent_rest = np.where(
        (sk.parents >= 0)[:, None], character.rest_global[np.maximum(sk.parents, 0)], quat.identity((sk.n_joints,))
    )
    parent_rest[0] = character.above[0]
    local = quat.mul(quat.inv(parent_rest), quat.mul(quat.mul(quat.inv(above), tpose), character.rest_global))
    local = quat.positive_w(quat.normalize(local))
    return {
        "bones": bones,
        "tpose": {str(n): np.round(local[j][[1, 2, 3, 0]], 7).tolist() for j, n in enumerate(character.nodes)},
    }
