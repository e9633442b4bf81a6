"""Motion -> binary glTF (.glb): the skeleton as a node hierarchy with a skin, and one
animation (joint rotations; translations of the joints that have BVH position channels).
With ``mesh``, a simple skinned body: one prism per bone, rigidly bound to the bone, with a
ridge on its front so a bone rolled about itself shows.

Reading (``read_gltf``, ``read_gltf_clips``) takes a glTF/GLB/VRM file's skeleton and its
animations into Motions whose rest frames are world-aligned, as BVH's are;
``write_gltf_animations`` puts motions back into the same file as named animations, everything
but the animations unchanged.

glTF is in metres: a top node scales the skeleton by ``metres_per_unit`` (by default guessed
from the leg length: centimetre and metre data are recognised, anything else is scaled to a
0.9 m leg). Axes are left as they are: BVH data is Y up, as glTF is.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pygltflib as gl

from styleerd.atomic import atomic_write
from styleerd.errors import StyleERDError
from styleerd.motion import bvh, quat
from styleerd.motion.humanoid import body_parts, pose_positions
from styleerd.motion.kinematics import bone_fronts, forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import POSITION_CHANNELS, Skeleton


def guess_metres_per_unit(motion: Motion) -> float:
    """Metres per unit of ``motion``'s skeleton, guessed from its leg length (centimetres or
    metres; otherwise scaled to a 0.9 m leg)."""
    sk = motion.skeleton
    parts = body_parts(sk)
    if all(f"left_{p}" in parts for p in ("hip", "knee", "foot")):
        hip, knee, foot = pose_positions(sk)[1][[parts[f"left_{p}"] for p in ("hip", "knee", "foot")]]
        leg = float(np.linalg.norm(knee - hip) + np.linalg.norm(foot - knee))
    else:
        _, g = forward_kinematics(motion.rotations[:1], motion.positions[:1], sk.parents)
        leg = float(np.ptp(g[0, :, 1])) / 2
    if 60 <= leg <= 120:
        return 0.01
    if 0.6 <= leg <= 1.2:
        return 1.0
    return 0.9 / max(leg, 1e-9)


def _append(
    views: list,
    accessors: list,
    blob: bytearray,
    array: np.ndarray,
    kind: str,
    with_bounds: bool = False,
    component: int = gl.FLOAT,
    target: int | None = None,
) -> int:
    """Append ``array`` to ``blob`` (4-byte aligned) with a buffer view and an accessor of
    buffer 0; returns the accessor's index."""
    dtype = {gl.FLOAT: np.float32, gl.UNSIGNED_SHORT: np.uint16, gl.UNSIGNED_INT: np.uint32}[component]
    data = np.ascontiguousarray(array, dtype=dtype)
    views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=data.nbytes, target=target))
    blob.extend(data.tobytes())
    blob.extend(b"\0" * (-len(blob) % 4))
    flat = data.reshape(len(data), -1)
    bounds = {"min": flat.min(0).tolist(), "max": flat.max(0).tolist()} if with_bounds else {}
    accessors.append(
        gl.Accessor(bufferView=len(views) - 1, componentType=component, count=len(data), type=kind, **bounds)
    )
    return len(accessors) - 1


def bone_prisms(
    skeleton, rest_positions: np.ndarray, rest_rotations: np.ndarray, thickness: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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


def write_glb(
    path: str | Path,
    motion: Motion,
    metres_per_unit: float | None = None,
    mesh: bool = False,
    rest_rotations: np.ndarray | None = None,
    name: str = "styleerd",
) -> None:
    """The motion as a .glb: nodes, a skin bound in the rest pose (zero rotations, or the local
    ``rest_rotations [J, 4]``, which then are the nodes' default rotations), one animation
    called ``name``."""
    sk, T = motion.skeleton, motion.n_frames
    scale = metres_per_unit or guess_metres_per_unit(motion)
    blob = bytearray()
    views, accessors = [], []

    def add(
        array: np.ndarray, kind: str, with_bounds: bool = False, component: int = gl.FLOAT, target: int | None = None
    ) -> int:
        return _append(views, accessors, blob, array, kind, with_bounds, component, target)

    xyzw = quat.normalize(motion.rotations)[..., [1, 2, 3, 0]]
    rest_local = (
        quat.identity((sk.n_joints,))
        if rest_rotations is None
        else quat.normalize(np.asarray(rest_rotations, dtype=np.float64))
    )
    default = xyzw[0] if rest_rotations is None else rest_local[:, [1, 2, 3, 0]]
    nodes = [
        gl.Node(
            name=name,
            translation=(motion.positions[0, j] if rest_rotations is None else sk.offsets[j]).tolist(),
            rotation=default[j].tolist(),
            children=sk.children(j),
        )
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
            channels.append(
                gl.AnimationChannel(sampler=len(samplers) - 1, target=gl.AnimationChannelTarget(node=j, path=target))
            )
    # inverse bind matrices of the rest pose, column-major as glTF stores them
    rest_rot, rest = forward_kinematics(rest_local, sk.offsets.copy(), sk.parents)
    ibm = np.tile(np.eye(4), (sk.n_joints, 1, 1))
    inv_rot = quat.to_xform(quat.inv(rest_rot))
    ibm[:, :3, :3] = inv_rot
    ibm[:, :3, 3] = -np.einsum("jab,jb->ja", inv_rot, rest)
    inverse_binds = add(ibm.transpose(0, 2, 1).reshape(sk.n_joints, 16), gl.MAT4)
    scene_nodes, meshes = [len(nodes) - 1], []
    if mesh:
        leg = 0.9 / scale  # a body's thickness, in the skeleton's units
        v, n, joint, tri = bone_prisms(sk, rest, rest_rot, 0.06 * leg)
        joints = np.zeros((len(v), 4), np.uint16)
        joints[:, 0] = joint
        weights = np.zeros((len(v), 4), np.float32)
        weights[:, 0] = 1.0
        vertex = {"target": gl.ARRAY_BUFFER}
        attributes = gl.Attributes(
            POSITION=add(v, gl.VEC3, True, **vertex),
            NORMAL=add(n, gl.VEC3, **vertex),
            JOINTS_0=add(joints, gl.VEC4, component=gl.UNSIGNED_SHORT, **vertex),
            WEIGHTS_0=add(weights, gl.VEC4, **vertex),
        )
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
        materials=[
            gl.Material(
                name="body",
                pbrMetallicRoughness=gl.PbrMetallicRoughness(
                    baseColorFactor=[0.75, 0.72, 0.68, 1.0], metallicFactor=0.0, roughnessFactor=0.7
                ),
            )
        ]
        if mesh
        else [],
        skins=[
            gl.Skin(name="skeleton", joints=list(range(sk.n_joints)), skeleton=0, inverseBindMatrices=inverse_binds)
        ],
        animations=[gl.Animation(name=name, samplers=samplers, channels=channels)],
        buffers=[gl.Buffer(byteLength=len(blob))],
        bufferViews=views,
        accessors=accessors,
    )
    doc.set_binary_blob(bytes(blob))
    atomic_write(Path(path), lambda tmp: doc.save_binary(str(tmp)))


# ---------------------------------------------------------------- reading, and writing back

# VRM humanoid bone -> body part (VRM 0.x and 1.0 share these names); upperChest wins over
# chest where both exist, since the arms branch off it
VRM_PARTS = {"hips": "hips", "spine": "spine", "chest": "chest", "upperChest": "chest", "neck": "neck", "head": "head"}
for _side in ("left", "right"):
    VRM_PARTS.update(
        {
            f"{_side}Shoulder": f"{_side}_collar",
            f"{_side}UpperArm": f"{_side}_shoulder",
            f"{_side}LowerArm": f"{_side}_elbow",
            f"{_side}Hand": f"{_side}_hand",
            f"{_side}UpperLeg": f"{_side}_hip",
            f"{_side}LowerLeg": f"{_side}_knee",
            f"{_side}Foot": f"{_side}_foot",
            f"{_side}Toes": f"{_side}_toe",
        }
    )
MAX_SECONDS = 3600.0  # of an animation: an hour (a key time of 1e7 s would ask for 197 GiB)
MAX_DEPTH = 256  # of a node tree, as the BVH reader's
MAX_TRANSFORM = 1e7  # |value| of a node's transform or a key: 10,000 km, or a quaternion of that size, is garbage
MAX_VALUES = (
    20_000_000  # joint frames of one animation (an hour of 150 joints at 30 fps; 0.6 GB as float64 quaternions)
)
_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


@dataclass
class GltfMotion:
    """A glTF's skeleton and animation as a Motion on a skeleton whose rest frames are
    world-aligned (the glTF's rest pose with every joint's rest rotation taken out, as BVH
    has it), and what it takes to put a motion back into the same file."""

    doc: gl.GLTF2
    blob: bytes
    motion: Motion
    nodes: list[int]  # skeleton joint -> node
    rest_global: np.ndarray  # [J, 4] their global rest rotations
    above: tuple[np.ndarray, np.ndarray, float]  # the root's ancestors: rotation, translation, uniform scale
    parts: dict[str, str]  # body part -> joint name, from a VRM humanoid (empty otherwise)
    animated_translation: np.ndarray  # [J] bool


def _whole(value, what: str, low: int = 0, high: int = 1 << 40) -> int:
    """``value`` as an integer in [low, high], or a ValueError naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"{what} must be an integer in [{low}, {high}], got {value!r}"[:200])
    return value


def _accessor(doc: gl.GLTF2, blob: bytes, index: int) -> np.ndarray:
    """An accessor's elements ``[count, width]`` as float64, every field checked against the
    glTF 2.0 rules and the buffer's length first (elements gathered by index: no view reaches
    outside the buffer whatever the file says)."""
    index = _whole(index, "an accessor index", 0, len(doc.accessors) - 1)
    a = doc.accessors[index]
    if a.sparse is not None or a.bufferView is None:
        raise ValueError(f"accessor {index}: sparse or empty accessors are not supported")
    if a.componentType not in _COMPONENTS or a.type not in _WIDTH:
        raise ValueError(
            f"accessor {index}: component type {a.componentType!r} or type {a.type!r} is not a glTF 2.0 one"[:200]
        )
    view = doc.bufferViews[_whole(a.bufferView, f"accessor {index}'s bufferView", 0, len(doc.bufferViews) - 1)]
    dtype = np.dtype(_COMPONENTS[a.componentType])
    element = dtype.itemsize * _WIDTH[a.type]
    count = _whole(a.count, f"accessor {index}'s count", 1, len(blob))
    view_start = _whole(view.byteOffset or 0, f"buffer view {a.bufferView}'s byteOffset")
    view_length = _whole(view.byteLength, f"buffer view {a.bufferView}'s byteLength", 1)
    stride = (
        element
        if view.byteStride is None
        else _whole(view.byteStride, f"buffer view {a.bufferView}'s byteStride", 4, 252)
    )
    offset = _whole(a.byteOffset or 0, f"accessor {index}'s byteOffset")
    if stride < element or offset % dtype.itemsize:
        raise ValueError(
            f"accessor {index}: a stride of {stride} bytes for {element}-byte elements, or an unaligned offset"
        )
    if view_start + view_length > len(blob) or offset + stride * (count - 1) + element > view_length:
        raise ValueError(f"accessor {index} reaches past the end of its buffer view or buffer")
    at = view_start + offset + stride * np.arange(count)[:, None] + np.arange(element)[None]
    out = np.frombuffer(blob, dtype=np.uint8)[at].view(dtype).reshape(count, _WIDTH[a.type]).astype(np.float64)
    if a.normalized and dtype.kind in "iu":
        out = np.maximum(out / np.iinfo(dtype).max, -1.0)
    return out


def _outside(path: Path, uri: str) -> bool:
    """Whether a buffer or image URI of the .gltf ``path`` names a file outside its own folder
    (an absolute path, ``..``, another scheme); data: URIs are inside the file."""
    from urllib.parse import unquote, urlparse

    if uri.startswith("data:"):
        return False
    parsed = urlparse(uri)
    if parsed.scheme or parsed.netloc:
        return True
    folder = path.resolve().parent
    target = (folder / unquote(parsed.path)).resolve()
    return not target.is_relative_to(folder)


def _load(path: Path) -> tuple[gl.GLTF2, bytes]:
    try:
        if path.suffix.lower() == ".gltf":
            doc = gl.GLTF2().load_json(str(path))
            if len(doc.buffers) != 1:
                raise ValueError(f"{len(doc.buffers)} buffers (one is supported)")
            uri = doc.buffers[0].uri
            if isinstance(uri, str) and _outside(path, uri):
                raise StyleERDError(f"{path}: its buffer {uri[:100]!r} is outside the file's own folder; not read")
            doc.convert_buffers(gl.BufferFormat.BINARYBLOB)
        else:
            doc = gl.GLTF2().load_binary(str(path))
        blob = doc.binary_blob() or b""
    except StyleERDError:
        raise
    except Exception as e:  # noqa: BLE001  pygltflib raises whatever its parser meets
        raise StyleERDError(f"{path}: not a readable glTF file ({type(e).__name__}: {str(e)[:200]})") from None
    return doc, blob


def _node_trs(node: gl.Node, n: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rotation wxyz, translation, scale) of node ``n``, every number finite and of the right count."""
    try:
        if node.matrix is not None:
            m = np.array(node.matrix, dtype=np.float64).reshape(4, 4).T
            values = [m]
        else:
            r = np.array(node.rotation if node.rotation is not None else [0, 0, 0, 1.0], dtype=np.float64).reshape(4)[
                [3, 0, 1, 2]
            ]
            t, s = (
                np.array(node.translation or [0, 0, 0.0], dtype=np.float64).reshape(3),
                np.array(node.scale or [1, 1, 1.0], dtype=np.float64).reshape(3),
            )
            values = [r, t, s]
    except (TypeError, ValueError):
        raise ValueError(
            f"node {n} ({node.name!r}): its matrix, rotation, translation or scale is not a list of numbers of the "
            "right length"[:200]
        ) from None
    if not all(np.isfinite(v).all() for v in values):
        raise ValueError(f"node {n} ({node.name!r}): its transform has a NaN or infinite value"[:200])
    if max(float(np.abs(v).max()) for v in values) >= MAX_TRANSFORM:  # the norms below would overflow
        raise ValueError(f"node {n} ({node.name!r}): its transform is out of range (|value| < {MAX_TRANSFORM:g})")
    if node.matrix is not None:
        scale = np.linalg.norm(m[:3, :3], axis=0)
        if (scale < 1e-12).any():
            raise ValueError(f"node {n} ({node.name!r}): its matrix has a zero scale"[:200])
        return quat.from_xform(m[:3, :3] / scale), m[:3, 3].copy(), scale
    if np.linalg.norm(r) < 1e-12:
        raise ValueError(f"node {n} ({node.name!r}): its rotation is zero"[:200])
    return quat.normalize(r), t, s


def _vrm_parts(doc: gl.GLTF2) -> dict[str, int]:
    """Body part -> node, from a VRM 1.0 (VRMC_vrm), VRM Animation (VRMC_vrm_animation) or VRM
    0.x (VRM) humanoid."""
    ext = doc.extensions or {}
    bones: dict[str, int] = {}
    vrm1 = next((ext[k] for k in ("VRMC_vrm", "VRMC_vrm_animation") if k in ext), None)  # an avatar, an animation
    if vrm1 is not None:
        bones = {k: v["node"] for k, v in vrm1.get("humanoid", {}).get("humanBones", {}).items()}
    elif "VRM" in ext:
        bones = {b["bone"]: b["node"] for b in ext["VRM"].get("humanoid", {}).get("humanBones", [])}
    parts: dict[str, int] = {}
    for bone, node in bones.items():
        part = VRM_PARTS.get(bone)
        if part and (part not in parts or bone == "upperChest"):
            parts[part] = int(node)
    return parts


def _tree(doc: gl.GLTF2) -> dict[int, int]:
    """Node -> its parent, checked to be a forest (no node its own child, none with two parents,
    no cycle) no deeper than ``MAX_DEPTH``; node indices in range."""
    parent: dict[int, int] = {}
    for i, node in enumerate(doc.nodes):
        for c in node.children or []:
            c = _whole(c, f"node {i}'s child", 0, len(doc.nodes) - 1)
            if c == i or c in parent:
                raise ValueError(
                    f"node {c} is {'its own child' if c == i else f'a child of both node {parent[c]} and node {i}'}: "
                    "the nodes must form a tree"
                )
            parent[c] = i
    depth: dict[int, int] = {}
    for n in range(len(doc.nodes)):
        path = []
        while n not in depth and n in parent:
            path.append(n)
            n = parent[n]
            if len(path) > MAX_DEPTH:
                raise ValueError(f"the node tree is deeper than {MAX_DEPTH} or has a cycle (through node {n})")
        d = depth.get(n, 0)
        for m in reversed(path):
            d += 1
            depth[m] = d
            if d > MAX_DEPTH:
                raise ValueError(f"the node tree is deeper than {MAX_DEPTH} (node {m})")
    return parent


def animation_names(doc: gl.GLTF2) -> list[str]:
    """Each animation's name (``animation<N>`` for a nameless one)."""
    return [a.name or f"animation{k}" for k, a in enumerate(doc.animations or [])]


def _animation_index(doc: gl.GLTF2, animation: int | str) -> int:
    """The index of the animation named ``animation`` (or numbered), or a ValueError listing them."""
    names = animation_names(doc)
    if not names:
        raise ValueError("no animation to stylise (a character: put a motion on it with transfer --onto)")
    if isinstance(animation, int) and -len(names) <= animation < len(names):
        return animation % len(names)
    if animation in names:
        return names.index(animation)
    shown = str(animation)[:60] + ("..." if len(str(animation)) > 60 else "")
    raise ValueError(f"no animation {shown!r}; the file has: {', '.join(names)}"[:400])


def read_gltf(path: str | Path, animation: int | str = 0, fps: float | None = None) -> GltfMotion:
    """A glTF/GLB/VRM file's skeleton (its first skin) and one animation (by index or name),
    sampled at ``fps`` (by default the animation's own key rate, within 10-120)."""
    return read_gltf_clips(path, [animation], fps)[0][1]


def read_gltf_character(path: str | Path) -> GltfMotion:
    """A glTF/GLB/VRM character's skeleton in its rest pose (one frame), animated or not: an
    avatar to put a motion on."""
    path = Path(path)
    doc, blob = _load(path)
    with _refused_as(path):
        return _read(doc, blob, None, None)


def read_gltf_clips(
    path: str | Path, animations: list[int | str] | None = None, fps: float | None = None
) -> list[tuple[str, GltfMotion]]:
    """(name, clip) of each animation named or numbered in ``animations`` (None: every one),
    each on the file's first skin, as ``read_gltf`` reads one."""
    path = Path(path)
    doc, blob = _load(path)
    with _refused_as(path):
        wanted = range(len(doc.animations or [])) if animations is None else animations
        indices = [_animation_index(doc, a) for a in wanted] or [_animation_index(doc, 0)]
        names = animation_names(doc)
        return [(names[k], _read(doc, blob, k, fps)) for k in indices]


def read_gltf_file(path: str | Path) -> tuple[GltfMotion, list[tuple[str, GltfMotion]]]:
    """A glTF/GLB/VRM file read once: its character in the rest pose (``read_gltf_character``) and
    every animation (``read_gltf_clips``; none for a character with none)."""
    path = Path(path)
    doc, blob = _load(path)
    with _refused_as(path):
        names = animation_names(doc)
        return _read(doc, blob, None, None), [(names[k], _read(doc, blob, k, None)) for k in range(len(names))]


@contextmanager
def _refused_as(path: Path):
    """What a malformed file raises while it is read, as one StyleERDError naming the file."""
    try:
        yield
    except (ValueError, KeyError, IndexError, TypeError, AttributeError) as e:
        raise StyleERDError(f"{path}: {str(e)[:400]}") from None


def _read(doc: gl.GLTF2, blob: bytes, animation: int | None, fps: float | None) -> GltfMotion:
    """The skeleton of the first skin (or, with no skin, as in a VRM Animation, the VRM
    humanoid's hips and everything below them) and animation ``animation`` sampled at ``fps``
    (None: one frame, the rest pose)."""
    parent = _tree(doc)

    def chain(n: int) -> list[int]:
        out = [n]
        while out[-1] in parent:
            out.append(parent[out[-1]])
        return out

    if doc.skins:
        joints = {_whole(j, "a skin joint", 0, len(doc.nodes) - 1) for j in doc.skins[0].joints or []}
    elif "hips" in (humanoid := _vrm_parts(doc)):
        hips = _whole(humanoid["hips"], "the humanoid's hips node", 0, len(doc.nodes) - 1)
        joints = {n for n in range(len(doc.nodes)) if hips in chain(n)}
    else:
        raise ValueError("no skin and no VRM humanoid: the file has no skeleton to stylise")
    if not joints:
        raise ValueError("the skin has no joints")
    chains = [chain(j) for j in joints]
    common = set(chains[0]).intersection(*map(set, chains[1:]))
    if not common:
        raise ValueError("the skin's joints have no common root node")
    root = next(n for n in chains[0] if n in common)
    members = {n for c in chains for n in c[: c.index(root) + 1]}
    order: list[int] = []
    stack = [root]
    while stack:  # depth first, parents before children
        n = stack.pop()
        order.append(n)
        stack.extend(reversed([c for c in (doc.nodes[n].children or []) if c in members]))
    index = {n: k for k, n in enumerate(order)}
    J = len(order)
    parents = np.array([-1] + [index[parent[n]] for n in order[1:]])
    trs = [_node_trs(doc.nodes[n], n) for n in order]
    rest_local = np.stack([r for r, _, _ in trs])
    rest_t = np.stack([t for _, t, _ in trs])
    if any(not np.allclose(s, 1.0, rtol=1e-4) for _, _, s in trs[1:]):
        raise ValueError("joints with a scale other than 1 are not supported")
    # the root's ancestors: their rotation and translation, and a uniform scale (units)
    a_rot, a_pos, a_scale = quat.identity(), np.zeros(3), float(np.mean(trs[0][2]))
    for n in chain(root)[1:]:
        r, t, s = _node_trs(doc.nodes[n], n)
        a_pos = t + float(np.mean(s)) * quat.mul_vec(r, a_pos)
        a_rot, a_scale = quat.mul(r, a_rot), a_scale * float(np.mean(s))
    rest_local[0] = quat.mul(a_rot, rest_local[0])
    rest_global, _ = forward_kinematics(rest_local, rest_t, parents)
    # sample the animation
    keyed: dict[tuple[int, str], tuple[np.ndarray, np.ndarray, str]] = {}
    steps = []
    for ch in [] if animation is None else doc.animations[animation].channels:
        anim = doc.animations[animation]
        if ch.target.node in index and ch.target.path in ("rotation", "translation"):
            sampler = anim.samplers[_whole(ch.sampler, "a channel's sampler", 0, len(anim.samplers) - 1)]
            times, values = _accessor(doc, blob, sampler.input)[:, 0], _accessor(doc, blob, sampler.output)
            if not (np.isfinite(times).all() and np.isfinite(values).all()):
                raise ValueError(f"animation channel of node {ch.target.node}: a key time or value is NaN or infinite")
            if len(values) and np.abs(values).max() >= MAX_TRANSFORM:
                raise ValueError(
                    f"animation channel of node {ch.target.node}: a {ch.target.path} is out of range "
                    f"(|value| < {MAX_TRANSFORM:g})"
                )
            if times[0] < 0 or times[-1] > MAX_SECONDS or (np.diff(times) < 0).any():
                raise ValueError(
                    f"animation channel of node {ch.target.node}: key times must rise from 0 to at most "
                    f"{MAX_SECONDS:g} s"
                )
            if sampler.interpolation == "CUBICSPLINE":
                values = values[1::3]  # (in-tangent, value, out-tangent): the values, linearly
            if len(times) != len(values) or len(times) == 0:
                raise ValueError(
                    f"animation channel of node {ch.target.node}: {len(times)} times, {len(values)} values"
                )
            keyed[(index[ch.target.node], ch.target.path)] = (times, values, sampler.interpolation or "LINEAR")
            steps.append(np.diff(times))
    if not keyed and animation is not None:
        raise ValueError("the animation moves none of the skeleton's joints")
    end = max((float(t[-1]) for t, _, _ in keyed.values()), default=0.0)
    if fps is None and not steps:
        fps = 30.0
    elif fps is None:
        dt = np.concatenate(steps)
        dt = dt[dt > 1e-6]
        fps = float(np.clip(round(1.0 / np.median(dt)) if len(dt) else 30.0, 10, 120))
    T = int(np.floor(end * fps + 1e-6)) + 1
    if T * J > MAX_VALUES:
        raise ValueError(f"{T} frames of {J} joints is more than this reader takes ({MAX_VALUES:,} joint frames)")
    t = np.arange(T) / fps
    local = np.broadcast_to(rest_local, (T, J, 4)).copy()
    local[:, 0] = trs[0][0]  # the root's own rotation; its ancestors go on below
    pos = np.broadcast_to(rest_t, (T, J, 3)).copy()
    moved = np.zeros(J, bool)
    for (j, what), (times, values, interpolation) in keyed.items():
        k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1)
        k1 = np.minimum(k + 1, len(times) - 1)
        span = np.maximum(times[k1] - times[k], 1e-12)
        w = np.where((interpolation == "STEP") | (k1 == k), 0.0, np.clip((t - times[k]) / span, 0.0, 1.0))
        if what == "rotation":
            q = values[:, [3, 0, 1, 2]]
            local[:, j] = quat.slerp(quat.normalize(q[k]), quat.normalize(q[k1]), w)
        else:
            pos[:, j] = values[k] * (1 - w[:, None]) + values[k1] * w[:, None]
            moved[j] = True
    local[:, 0] = quat.mul(a_rot, local[:, 0])
    pos[:, 0] = a_pos + a_scale * quat.mul_vec(a_rot, pos[:, 0])
    # to world-aligned rest frames: G' = G * inv(rest_global), offsets turned by the parent's rest
    parent_rest = np.where((parents >= 0)[:, None], rest_global[np.maximum(parents, 0)], quat.identity((J,)))
    rot = quat.mul(quat.mul(parent_rest, local), quat.inv(rest_global))
    rot[:, 0] = quat.mul(local[:, 0], quat.inv(rest_global[0]))
    offsets = a_scale * quat.mul_vec(parent_rest, rest_t)
    offsets[0] = a_pos + a_scale * quat.mul_vec(a_rot, rest_t[0])
    pos[:, 1:] = a_scale * quat.mul_vec(parent_rest[None, 1:], pos[:, 1:])
    channels = tuple(
        POSITION_CHANNELS + ("Zrotation", "Xrotation", "Yrotation")
        if j == 0 or moved[j]
        else ("Zrotation", "Xrotation", "Yrotation")
        for j in range(J)
    )
    names = tuple(doc.nodes[n].name or f"node{n}" for n in order)
    if len(set(names)) != len(names):
        names = tuple(f"{nm}.{n}" for nm, n in zip(names, order))
    skeleton = Skeleton(names, parents, offsets, channels)
    motion = Motion(skeleton, quat.normalize(rot), pos, fps)
    parts = {p: names[index[n]] for p, n in _vrm_parts(doc).items() if n in index}
    return GltfMotion(doc, blob, motion, order, rest_global, (a_rot, a_pos, a_scale), parts, moved)


def write_gltf_animations(
    path: str | Path, source: GltfMotion, clips: list[tuple[str | None, Motion]], keep_original: bool = False
) -> None:
    """``source``'s file with an animation per clip (name, motion on ``source.motion``'s
    skeleton), in place of its own animations or, with ``keep_original``, after them: same
    nodes, meshes, skins, materials and extensions; the rotation of every joint and the
    translation of the root (and of joints whose translation was animated or moves in the clip)
    keyed at every frame. Data only the replaced animations used is dropped from the buffer."""
    import copy

    doc = copy.deepcopy(source.doc)
    blob = bytearray(source.blob)
    blob.extend(b"\0" * (-len(blob) % 4))
    made = [_animation(doc, blob, source, motion, name) for name, motion in clips]
    doc.animations = (list(doc.animations or []) if keep_original else []) + made
    blob = _compacted(doc, bytes(blob))
    doc.buffers = [gl.Buffer(byteLength=len(blob))]
    doc.set_binary_blob(blob)
    atomic_write(Path(path), lambda tmp: doc.save_binary(str(tmp)))


def _animation(doc: gl.GLTF2, blob: bytearray, source: GltfMotion, motion: Motion, name: str | None) -> gl.Animation:
    """``motion`` (on ``source.motion``'s skeleton) as a glTF animation of ``source``'s nodes,
    its keys appended to ``doc``'s buffer ``blob``."""
    parents, J = motion.skeleton.parents, motion.skeleton.n_joints
    a_rot, a_pos, a_scale = source.above
    parent_rest = np.where((parents >= 0)[:, None], source.rest_global[np.maximum(parents, 0)], quat.identity((J,)))
    local = quat.mul(quat.inv(parent_rest)[None], quat.mul(motion.rotations, source.rest_global[None]))
    local[:, 0] = quat.mul(quat.inv(a_rot), local[:, 0])  # the root's parent_rest is identity: take its ancestors out
    pos = np.empty_like(motion.positions)
    pos[:, 0] = quat.mul_vec(quat.inv(a_rot), motion.positions[:, 0] - a_pos) / a_scale
    pos[:, 1:] = quat.mul_vec(quat.inv(parent_rest)[None, 1:], motion.positions[:, 1:]) / a_scale

    def add(array: np.ndarray, kind: str, with_bounds: bool = False) -> int:
        return _append(doc.bufferViews, doc.accessors, blob, array, kind, with_bounds)

    times = add(np.arange(motion.n_frames) / motion.fps, gl.SCALAR, with_bounds=True)
    samplers, channels = [], []
    xyzw = quat.normalize(local)[..., [1, 2, 3, 0]]
    moves = source.animated_translation | ~np.isclose(motion.positions, motion.skeleton.offsets).all((0, 2))
    for j, node in enumerate(source.nodes):
        animated = [("rotation", add(xyzw[:, j], gl.VEC4))]
        if j == 0 or moves[j]:  # the root, joints the input moved, the hips an avatar is walked by
            animated.append(("translation", add(pos[:, j], gl.VEC3)))
        for target, output in animated:
            samplers.append(gl.AnimationSampler(input=times, output=output, interpolation="LINEAR"))
            channels.append(
                gl.AnimationChannel(sampler=len(samplers) - 1, target=gl.AnimationChannelTarget(node=node, path=target))
            )
    return gl.Animation(name=name, samplers=samplers, channels=channels)


def _fields(attributes) -> dict:
    """A primitive's attributes or morph target as a dict that writes through (pygltflib gives
    either an ``Attributes`` object or a plain dict)."""
    return attributes if isinstance(attributes, dict) else vars(attributes)


# Extensions whose data lives in buffer views this module does not follow: no compaction there.
_OPAQUE_DATA = ("KHR_draco_mesh_compression", "EXT_meshopt_compression", "EXT_mesh_gpu_instancing")


def _compacted(doc: gl.GLTF2, blob: bytes) -> bytes:
    """The buffer with only the accessors and buffer views still used (by meshes, skins,
    animations, images), ``doc``'s indices renumbered to match; unchanged where an extension
    keeps data out of sight (Draco, meshopt, instancing)."""
    if any(e in (doc.extensionsUsed or []) for e in _OPAQUE_DATA):
        return blob
    used_accessors: set[int] = set()
    for mesh in doc.meshes or []:
        for prim in mesh.primitives:
            for attributes in [prim.attributes, *(prim.targets or [])]:
                used_accessors.update(v for v in _fields(attributes).values() if isinstance(v, int))
            if prim.indices is not None:
                used_accessors.add(prim.indices)
    used_accessors.update(s.inverseBindMatrices for s in doc.skins or [] if s.inverseBindMatrices is not None)
    for anim in doc.animations or []:
        used_accessors.update(x for s in anim.samplers for x in (s.input, s.output))
    accessor_index = {old: new for new, old in enumerate(sorted(used_accessors))}
    accessors = [doc.accessors[k] for k in sorted(used_accessors)]
    views_of = [a.bufferView for a in accessors]
    for a in accessors:
        if a.sparse is not None:
            views_of += [a.sparse.indices.bufferView, a.sparse.values.bufferView]
    views_of += [im.bufferView for im in doc.images or []]
    used_views = sorted({v for v in views_of if v is not None})
    view_index = {old: new for new, old in enumerate(used_views)}
    out = bytearray()
    views = []
    for k in used_views:
        start = doc.bufferViews[k].byteOffset or 0
        out.extend(b"\0" * (-len(out) % 4))
        views.append(gl.BufferView(**{**vars(doc.bufferViews[k]), "byteOffset": len(out)}))
        out.extend(blob[start : start + doc.bufferViews[k].byteLength])
    for a in accessors:
        if a.bufferView is not None:
            a.bufferView = view_index[a.bufferView]
        if a.sparse is not None:
            a.sparse.indices.bufferView = view_index[a.sparse.indices.bufferView]
            a.sparse.values.bufferView = view_index[a.sparse.values.bufferView]
    for im in doc.images or []:
        if im.bufferView is not None:
            im.bufferView = view_index[im.bufferView]
    for mesh in doc.meshes or []:
        for prim in mesh.primitives:
            for attributes in [prim.attributes, *(prim.targets or [])]:
                fields = _fields(attributes)
                for key, v in list(fields.items()):
                    if isinstance(v, int):
                        fields[key] = accessor_index[v]
            if prim.indices is not None:
                prim.indices = accessor_index[prim.indices]
    for skin in doc.skins or []:
        if skin.inverseBindMatrices is not None:
            skin.inverseBindMatrices = accessor_index[skin.inverseBindMatrices]
    for anim in doc.animations or []:
        for sampler in anim.samplers:
            sampler.input, sampler.output = accessor_index[sampler.input], accessor_index[sampler.output]
    doc.accessors, doc.bufferViews = accessors, views
    out.extend(b"\0" * (-len(out) % 4))
    return bytes(out)


def humanoid_pose(motion: Motion, tpose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every joint's rotation away from the T-pose, relative to its parent's (a VRM normalized
    humanoid's local rotation: identity in the T-pose), ``[T, J, 4]``, and the world positions
    ``[T, J, 3]``; ``tpose [J, 4]``: every joint's global rotation in the T-pose."""
    parents = motion.skeleton.parents
    g, pos = forward_kinematics(motion.rotations, motion.positions, parents)
    away = quat.mul(g, quat.inv(tpose)[None])  # each joint's world rotation away from the T-pose
    parent_away = np.where(
        (parents >= 0)[None, :, None], away[:, np.maximum(parents, 0)], quat.identity(away.shape[:2])
    )
    return quat.normalize(quat.mul(quat.inv(parent_away), away)), pos


def tpose_positions(skeleton: Skeleton, tpose: np.ndarray, standing: np.ndarray) -> np.ndarray:
    """``[J, 3]`` joint positions in the T-pose (global rotations ``tpose [J, 4]``), the hips
    above the origin at the height they have over the lowest joint in a standing pose
    (``standing [J, 4]`` local rotations: in the T-pose the feet point forward, so its own lowest
    joint is the ankle, not the toe on the floor)."""
    parents = skeleton.parents
    parent_t = np.where((parents >= 0)[:, None], tpose[np.maximum(parents, 0)], quat.identity((skeleton.n_joints,)))
    _, rest = forward_kinematics(quat.mul(quat.inv(parent_t), tpose), skeleton.offsets.copy(), parents)
    _, stand = forward_kinematics(quat.normalize(standing), skeleton.offsets.copy(), parents)
    return rest - [rest[0, 0], rest[0, 1] - (stand[0, 1] - stand[:, 1].min()), rest[0, 2]]


def vrm_bones(skeleton: Skeleton, parts: dict[str, int]) -> list[str]:
    """Each joint's VRM humanoid bone name ("" for a joint that plays no part)."""
    bone_of = {part: bone for bone, part in VRM_PARTS.items() if bone != "upperChest"}
    names = [""] * skeleton.n_joints
    for part, j in parts.items():
        names[j] = bone_of.get(part, "")
    return names


def write_vrma(
    path: str | Path,
    motion: Motion,
    tpose: np.ndarray,
    standing: np.ndarray,
    parts: dict[str, int],
    metres_per_unit: float = 0.01,
    name: str = "styleerd",
) -> None:
    """``motion`` as a VRM Animation (VRMC_vrm_animation 1.0) called ``name``: one node per joint, named and
    listed in the humanoid for the joints that play a body part (``parts``: part -> joint), at
    rest in the T-pose of VRM (facing +Z, left along +X, every node's rest rotation the
    identity, the hips as high as in ``standing``, local rotations of a standing pose); each
    node keyed with its rotation away from that T-pose (``tpose [J, 4]``: every joint's global
    rotation in it) and the hips with their path, from where the clip starts, over the floor its
    lowest joints meet (5th percentile: offline).
    VRM apps (three-vrm's VRMAnimationLoaderPlugin, UniVRM) put it on any VRM avatar."""
    sk, T = motion.skeleton, motion.n_frames
    parents = sk.parents
    local, pos = humanoid_pose(motion, tpose)
    rest = tpose_positions(sk, tpose, standing) * metres_per_unit
    names = list(sk.names)
    humanoid = {}
    for j, bone in enumerate(vrm_bones(sk, parts)):
        if bone:
            names[j] = bone
            humanoid[bone] = {"node": j}
    blob = bytearray()
    views, accessors = [], []

    def add(array: np.ndarray, kind: str, with_bounds: bool = False) -> int:
        return _append(views, accessors, blob, array, kind, with_bounds)

    nodes = [
        gl.Node(
            name=names[j],
            translation=(rest[j] - (rest[parents[j]] if parents[j] >= 0 else 0.0)).tolist(),
            children=sk.children(j),
        )
        for j in range(sk.n_joints)
    ]
    times = add(np.arange(T) / motion.fps, gl.SCALAR, with_bounds=True)
    samplers, channels = [], []
    floor = np.percentile(pos[..., 1].min(1), 5)  # where the feet meet the ground, as on the rest's floor
    hips_path = (pos[:, 0] - [pos[0, 0, 0], floor, pos[0, 0, 2]]) * metres_per_unit
    for j in range(sk.n_joints):
        animated = [("rotation", add(local[:, j, [1, 2, 3, 0]], gl.VEC4))]
        if j == 0:
            animated.append(("translation", add(hips_path, gl.VEC3)))
        for target, output in animated:
            samplers.append(gl.AnimationSampler(input=times, output=output, interpolation="LINEAR"))
            channels.append(
                gl.AnimationChannel(sampler=len(samplers) - 1, target=gl.AnimationChannelTarget(node=j, path=target))
            )
    doc = gl.GLTF2(
        asset=gl.Asset(generator="styleerd", version="2.0"),
        scene=0,
        scenes=[gl.Scene(nodes=[0])],
        nodes=nodes,
        animations=[gl.Animation(name=name, samplers=samplers, channels=channels)],
        buffers=[gl.Buffer(byteLength=len(blob))],
        bufferViews=views,
        accessors=accessors,
        extensionsUsed=["VRMC_vrm_animation"],
        extensions={"VRMC_vrm_animation": {"specVersion": "1.0", "humanoid": {"humanBones": humanoid}}},
    )
    doc.set_binary_blob(bytes(blob))
    atomic_write(Path(path), lambda tmp: doc.save_binary(str(tmp)))


GLTF_INPUTS = (".glb", ".gltf", ".vrm", ".vrma")


def read_motion(path: str | Path, animation: int | str = 0) -> Motion:
    """A motion from a BVH, glTF, GLB or VRM file (its first skin's skeleton and an animation,
    by default the first, by index (-1: the last) or name)."""
    if Path(path).suffix.lower() in GLTF_INPUTS:
        return read_gltf(path, animation).motion
    return bvh.read(path)
