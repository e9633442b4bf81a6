"""Motion -> binary glTF (.glb): the skeleton as a node hierarchy with a skin, and one
animation (joint rotations; translations of the joints that have BVH position channels).
With ``mesh``, a simple skinned body: one prism per bone, rigidly bound to the bone, with a
ridge on its front so a bone rolled about itself shows.

glTF is in metres: a top node scales the skeleton by ``metres_per_unit`` (by default guessed
from the leg length: centimetre and metre data are recognised, anything else is scaled to a
0.9 m leg). Axes are left as they are: BVH data is Y up, as glTF is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl

from styleerd.atomic import atomic_write
from styleerd.motion import quat
from styleerd.motion.kinematics import bone_fronts, forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import find_role


def guess_metres_per_unit(motion: Motion) -> float:
    sk = motion.skeleton
    try:
        hip, knee, foot = (find_role(sk, f"left_{p}") for p in ("hip", "knee", "foot"))
        leg = float(np.linalg.norm(sk.offsets[knee]) + np.linalg.norm(sk.offsets[foot]))
    except KeyError:
        _, g = forward_kinematics(motion.rotations[:1], motion.positions[:1], sk.parents)
        leg = float(np.ptp(g[0, :, 1])) / 2
    if 60 <= leg <= 120:
        return 0.01
    if 0.6 <= leg <= 1.2:
        return 1.0
    return 0.9 / max(leg, 1e-9)


def bone_prisms(skeleton, rest_positions: np.ndarray, rest_rotations: np.ndarray, thickness: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A body of one prism per bone (parent joint -> joint), in the bind pose given by the
    joints' global rest positions and rotations: (positions ``[V, 3]``, normals ``[V, 3]``,
    the joint each vertex follows ``[V]``, triangles ``[F, 3]``). The cross-section is a
    pentagon whose point lies on the bone's front, flat-shaded (vertices not shared)."""
    fronts = bone_fronts(skeleton)
    # cross-section: (across, front) coordinates, the point towards the front
    section = np.array([[-1.0, -0.8], [1.0, -0.8], [1.0, 0.5], [0.0, 1.6], [-1.0, 0.5]])
    pos, nor, joint, tri = [], [], [], []
    for j in range(1, skeleton.n_joints):
        p = int(skeleton.parents[j])
        a, b = rest_positions[p], rest_positions[j]
        length = float(np.linalg.norm(b - a))
        if length < 1e-9 or not fronts[j].any():
            continue
        axis = (b - a) / length
        front = quat.mul_vec(rest_rotations[p], fronts[j])
        across = np.cross(axis, front)
        r = min(thickness, 0.18 * length)
        ring = [a[None] + r * (u * across + v * front) for u, v in section]
        ring = np.concatenate(ring)  # [5, 3] at the parent end
        ends = (ring + 0.04 * length * axis, ring + 0.96 * length * axis)
        faces = [[ends[0][k], ends[0][(k + 1) % 5], ends[1][(k + 1) % 5], ends[1][k]] for k in range(5)]
        faces += [list(ends[1]), list(ends[0][::-1])]
        for face in faces:
            face = np.array(face)
            n = np.cross(face[1] - face[0], face[2] - face[0])
            if np.dot(n, face.mean(0) - (a + b) / 2) < 0:  # outward
                face, n = face[::-1], -n
            base = sum(len(x) for x in pos)
            pos.append(face)
            nor.append(np.tile(n / np.linalg.norm(n), (len(face), 1)))
            joint.append(np.full(len(face), p))
            tri += [[base, base + k, base + k + 1] for k in range(1, len(face) - 1)]
    return np.concatenate(pos), np.concatenate(nor), np.concatenate(joint), np.array(tri)


def write_glb(path: str | Path, motion: Motion, metres_per_unit: float | None = None, mesh: bool = False) -> None:
    sk, T = motion.skeleton, motion.n_frames
    scale = metres_per_unit or guess_metres_per_unit(motion)
    blob = bytearray()
    views, accessors = [], []

    def add(array: np.ndarray, kind: str, with_bounds: bool = False, component: int = gl.FLOAT, target: int | None = None) -> int:
        dtype = {gl.FLOAT: np.float32, gl.UNSIGNED_SHORT: np.uint16, gl.UNSIGNED_INT: np.uint32}[component]
        data = np.ascontiguousarray(array, dtype=dtype)
        views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=data.nbytes, target=target))
        blob.extend(data.tobytes())
        blob.extend(b"\0" * (-len(blob) % 4))
        flat = data.reshape(len(data), -1)
        bounds = {"min": flat.min(0).tolist(), "max": flat.max(0).tolist()} if with_bounds else {}
        accessors.append(gl.Accessor(bufferView=len(views) - 1, componentType=component, count=len(data), type=kind, **bounds))
        return len(accessors) - 1

    xyzw = quat.normalize(motion.rotations)[..., [1, 2, 3, 0]]
    nodes = [
        gl.Node(name=name, translation=motion.positions[0, j].tolist(), rotation=xyzw[0, j].tolist(), children=sk.children(j))
        for j, name in enumerate(sk.names)
    ]
    nodes.append(gl.Node(name="styleerd", scale=[scale] * 3, children=[0]))
    times = add(np.arange(T) / motion.fps, gl.SCALAR, with_bounds=True)
    samplers, channels = [], []
    for j in range(sk.n_joints):
        animated = [("rotation", add(xyzw[:, j], gl.VEC4))]
        if j == 0 or sk.has_positions(j):
            animated.append(("translation", add(motion.positions[:, j], gl.VEC3)))
        for target, output in animated:
            samplers.append(gl.AnimationSampler(input=times, output=output, interpolation="LINEAR"))
            channels.append(gl.AnimationChannel(sampler=len(samplers) - 1, target=gl.AnimationChannelTarget(node=j, path=target)))
    # inverse bind matrices of the rest pose (zero rotations), column-major as glTF stores them
    rest_rot, rest = forward_kinematics(quat.identity((sk.n_joints,)), sk.offsets.copy(), sk.parents)
    ibm = np.tile(np.eye(4), (sk.n_joints, 1, 1))
    ibm[:, :3, 3] = -rest
    inverse_binds = add(ibm.transpose(0, 2, 1).reshape(sk.n_joints, 16), gl.MAT4)
    scene_nodes, meshes = [len(nodes) - 1], []
    if mesh:
        leg = 0.9 / scale  # a body's thickness, in the skeleton's units
        v, n, joint, tri = bone_prisms(sk, rest, rest_rot, 0.06 * leg)
        joints = np.zeros((len(v), 4), np.uint16)
        joints[:, 0] = joint
        weights = np.zeros((len(v), 4), np.float32)
        weights[:, 0] = 1.0
        vertex = dict(target=gl.ARRAY_BUFFER)
        attributes = gl.Attributes(POSITION=add(v, gl.VEC3, True, **vertex), NORMAL=add(n, gl.VEC3, **vertex),
                                   JOINTS_0=add(joints, gl.VEC4, component=gl.UNSIGNED_SHORT, **vertex), WEIGHTS_0=add(weights, gl.VEC4, **vertex))  # fmt: skip
        indices = add(tri.reshape(-1), gl.SCALAR, component=gl.UNSIGNED_INT, target=gl.ELEMENT_ARRAY_BUFFER)
        meshes = [gl.Mesh(name="body", primitives=[gl.Primitive(attributes=attributes, indices=indices, material=0)])]
        nodes.append(gl.Node(name="body", mesh=0, skin=0))
        scene_nodes.append(len(nodes) - 1)
    doc = gl.GLTF2(
        asset=gl.Asset(generator="styleerd", version="2.0"),
        scene=0,
        scenes=[gl.Scene(nodes=scene_nodes)],
        nodes=nodes,
        meshes=meshes,
        materials=[gl.Material(name="body", pbrMetallicRoughness=gl.PbrMetallicRoughness(baseColorFactor=[0.75, 0.72, 0.68, 1.0], metallicFactor=0.0, roughnessFactor=0.7))] if mesh else [],
        skins=[gl.Skin(name="skeleton", joints=list(range(sk.n_joints)), skeleton=0, inverseBindMatrices=inverse_binds)],
        animations=[gl.Animation(name="styleerd", samplers=samplers, channels=channels)],
        buffers=[gl.Buffer(byteLength=len(blob))],
        bufferViews=views,
        accessors=accessors,
    )
    doc.set_binary_blob(bytes(blob))
    atomic_write(Path(path), lambda tmp: doc.save_binary(str(tmp)))
