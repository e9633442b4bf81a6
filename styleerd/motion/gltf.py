"""Motion -> binary glTF (.glb): the skeleton as a node hierarchy with a skin, and one
animation (joint rotations; translations of the joints that have BVH position channels).

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
from styleerd.motion.kinematics import forward_kinematics
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


def write_glb(path: str | Path, motion: Motion, metres_per_unit: float | None = None) -> None:
    sk, T = motion.skeleton, motion.n_frames
    scale = metres_per_unit or guess_metres_per_unit(motion)
    blob = bytearray()
    views, accessors = [], []

    def add(array: np.ndarray, kind: str, with_bounds: bool = False) -> int:
        data = np.ascontiguousarray(array, dtype=np.float32)
        views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=data.nbytes))
        blob.extend(data.tobytes())
        blob.extend(b"\0" * (-len(blob) % 4))
        flat = data.reshape(len(data), -1)
        bounds = {"min": flat.min(0).tolist(), "max": flat.max(0).tolist()} if with_bounds else {}
        accessors.append(gl.Accessor(bufferView=len(views) - 1, componentType=gl.FLOAT, count=len(data), type=kind, **bounds))
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
    _, rest = forward_kinematics(quat.identity((sk.n_joints,)), sk.offsets.copy(), sk.parents)
    ibm = np.tile(np.eye(4), (sk.n_joints, 1, 1))
    ibm[:, :3, 3] = -rest
    inverse_binds = add(ibm.transpose(0, 2, 1).reshape(sk.n_joints, 16), gl.MAT4)
    doc = gl.GLTF2(
        asset=gl.Asset(generator="styleerd", version="2.0"),
        scene=0,
        scenes=[gl.Scene(nodes=[len(nodes) - 1])],
        nodes=nodes,
        skins=[gl.Skin(name="skeleton", joints=list(range(sk.n_joints)), skeleton=0, inverseBindMatrices=inverse_binds)],
        animations=[gl.Animation(name="styleerd", samplers=samplers, channels=channels)],
        buffers=[gl.Buffer(byteLength=len(blob))],
        bufferViews=views,
        accessors=accessors,
    )
    doc.set_binary_blob(bytes(blob))
    atomic_write(Path(path), lambda tmp: doc.save_binary(str(tmp)))
