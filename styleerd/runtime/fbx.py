"""FBX in and out, and armatures in Blender, through Blender's own Python module (``bpy``:
``pip install 'styleerd[blender]'``; bpy 4.2-5.0 run on Python 3.11).

An armature is read as a ``Motion`` whose rest pose is the armature's rest pose with every
joint frame aligned with the world (BVH's convention): a joint's global rotation is its bone's
world rotation relative to its rest, ``G = R_pose R_rest^-1``, in Y-up axes. That holds
whatever the bones' rolls and axes (FBX importers choose them), and it is how the result is
written back: ``R_pose = G' R_rest``, each bone keyed in its own rotation mode, so a skinned
character is driven without twist. Root locations are kept from the input.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from styleerd.atomic import atomic_write, check_output
from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import bvh, quat
from styleerd.motion.gltf import read_motion, write_glb
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import CHANNELS, Skeleton
from styleerd.runtime.offline import (
    TransferOptions,
    TransferReport,
    map_skeleton,
    source_clips,
    style_tag,
    stylised_onto,
    transfer_motion,
)

Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # Blender's Z-up world -> Y-up
ROTATIONS = ("Zrotation", "Xrotation", "Yrotation")


def blender():
    """Blender's Python module, or one clear error saying how to get it."""
    try:
        import bpy
    except ImportError:
        raise StyleERDError(
            "FBX needs Blender's Python module: pip install 'styleerd[blender]' (bpy 4.2 to 5.0, on Python 3.11)"
        ) from None
    return bpy


def _rotation(m) -> np.ndarray:
    """The rotation of a (possibly scaled) Blender 4x4 matrix, as a 3x3 numpy array."""
    r = np.array(m, dtype=np.float64)[:3, :3]
    return r / np.linalg.norm(r, axis=0, keepdims=True)


def _bones_parents_first(arm) -> list:
    order, stack = [], [b for b in arm.data.bones if b.parent is None][::-1]
    while stack:
        bone = stack.pop()
        order.append(bone)
        stack += list(bone.children)[::-1]
    return order


def single_armature(objects, where: str):
    """The one armature among ``objects`` (the one with the most bones if several)."""
    armatures = [o for o in objects if o.type == "ARMATURE"]
    if not armatures:
        raise StyleERDError(f"{where}: no armature (skeleton) in this file")
    return max(armatures, key=lambda o: len(o.data.bones))


def read_armature(arm, frames: range, fps: float) -> Motion:
    """The armature's motion over ``frames`` (scene frames, evaluated) as a ``Motion`` in
    Y-up world units, rest frames aligned with the world (see the module's docstring)."""
    scene = arm.users_scene[0] if arm.users_scene else blender().context.scene
    bones = _bones_parents_first(arm)
    if not bones:
        raise StyleERDError(f"armature {arm.name!r} has no bones")
    index = {b.name: i for i, b in enumerate(bones)}
    parents = np.array([index[b.parent.name] if b.parent else -1 for b in bones])
    if (parents == -1).sum() > 1:
        raise StyleERDError(
            f"armature {arm.name!r} has {(parents == -1).sum()} root bones; one root (the hips) is needed"
        )
    world = np.array(arm.matrix_world, dtype=np.float64)
    heads = np.array([world[:3, :3] @ np.array(b.head_local) + world[:3, 3] for b in bones]) @ Y_UP.T
    rest = np.stack([Y_UP @ _rotation(arm.matrix_world @ b.matrix_local) for b in bones])
    offsets = heads - np.where(parents[:, None] >= 0, heads[np.maximum(parents, 0)], 0.0)
    leaves = [i for i in range(len(bones)) if not bones[i].children]
    tails = {i: (world[:3, :3] @ np.array(bones[i].tail_local) + world[:3, 3]) @ Y_UP.T - heads[i] for i in leaves}
    skeleton = Skeleton(
        tuple(b.name for b in bones),
        parents,
        offsets,
        tuple(CHANNELS[:3] + ROTATIONS if p < 0 else ROTATIONS for p in parents),
        tuple((i, tails[i]) for i in leaves),
    )
    pose = [arm.pose.bones[b.name] for b in bones]
    T, J = len(frames), len(bones)
    g, root = np.empty((T, J, 3, 3)), np.empty((T, 3))
    for t, f in enumerate(frames):
        scene.frame_set(f)
        m = np.array(arm.matrix_world, dtype=np.float64)
        for j, pb in enumerate(pose):
            g[t, j] = Y_UP @ _rotation(arm.matrix_world @ pb.matrix)
        root[t] = Y_UP @ (m[:3, :3] @ np.array(pose[0].head) + m[:3, 3])
    global_rot = quat.from_xform(g @ np.swapaxes(rest, -1, -2)[None])
    local = global_rot.copy()
    local[:, 1:] = quat.mul(quat.inv(global_rot[:, parents[1:]]), global_rot[:, 1:])
    positions = np.broadcast_to(offsets, (T, J, 3)).copy()
    positions[:, 0] = root
    return Motion(skeleton, quat.positive_w(quat.normalize(local)), positions, fps)


def write_action(arm, motion: Motion, frames: range, name: str):
    """A new action on ``arm`` with ``motion`` (read by ``read_armature``, same bones) keyed
    on ``frames``: each bone's rotation in its own rotation mode, root locations from
    ``motion``. The armature's previous action is left as it was."""
    bpy = blender()
    from mathutils import Matrix

    bones = {b.name: b for b in arm.data.bones}
    names = motion.skeleton.names
    global_rot = forward_kinematics(motion.rotations, motion.positions, motion.skeleton.parents)[0]
    glob = quat.to_xform(global_rot)  # [T, J, 3, 3], Y-up world, relative to rest
    world = _rotation(arm.matrix_world)
    action = bpy.data.actions.new(name)
    if arm.animation_data is None:
        arm.animation_data_create()
    arm.animation_data.action = action
    pose_arm = {}  # armature-space pose rotations of the frame being keyed
    for t, f in enumerate(frames):
        for j, bone_name in enumerate(names):
            bone, pb = bones[bone_name], arm.pose.bones[bone_name]
            rest = _rotation(bone.matrix_local)
            pose_arm[bone_name] = world.T @ Y_UP.T @ glob[t, j] @ Y_UP @ world @ rest
            if bone.parent is None:
                basis = rest.T @ pose_arm[bone_name]
            else:
                parent_rest = _rotation(bone.parent.matrix_local)
                basis = (parent_rest.T @ rest).T @ pose_arm[bone.parent.name].T @ pose_arm[bone_name]
            q = Matrix(basis.tolist()).to_quaternion()
            if pb.rotation_mode == "QUATERNION":
                q.make_compatible(pb.rotation_quaternion)  # the short way from the last key: clean interpolation
                pb.rotation_quaternion = q
                pb.keyframe_insert("rotation_quaternion", frame=f, group=bone_name)
            elif pb.rotation_mode == "AXIS_ANGLE":
                axis, angle = q.to_axis_angle()
                pb.rotation_axis_angle = (angle, *axis)
                pb.keyframe_insert("rotation_axis_angle", frame=f, group=bone_name)
            else:
                pb.rotation_euler = (
                    q.to_euler(pb.rotation_mode, pb.rotation_euler) if t else q.to_euler(pb.rotation_mode)
                )
                pb.keyframe_insert("rotation_euler", frame=f, group=bone_name)
            if bone.parent is None:  # the root's location: the motion's root position, through the rest
                m = np.array(arm.matrix_world, dtype=np.float64)
                head_arm = np.linalg.solve(m[:3, :3], Y_UP.T @ motion.positions[t, 0] - m[:3, 3])
                pb.location = rest.T @ (head_arm - np.array(bone.head_local))
                pb.keyframe_insert("location", frame=f, group=bone_name)
    return action


def armature_from_motion(motion: Motion, name: str = "styleerd"):
    """A new armature object in the current scene with ``motion``'s skeleton at rest (bones
    from each joint to its first child or end site, in Blender's Z-up axes)."""
    bpy = blender()
    sk = motion.skeleton
    data = bpy.data.armatures.new(name)
    arm = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    heads = np.zeros((sk.n_joints, 3))
    for j in range(sk.n_joints):
        heads[j] = sk.offsets[j] + (heads[sk.parents[j]] if j else 0.0)
    ends = {j: off for j, off in sk.end_sites}
    edit = []
    for j, joint in enumerate(sk.names):
        kids = sk.children(j)
        direction = sk.offsets[kids[0]] if kids else ends.get(j, sk.offsets[j])
        if np.linalg.norm(direction) < 1e-6:
            direction = np.array([0.0, 1.0, 0.0]) * max(np.linalg.norm(sk.offsets, axis=1).mean(), 1e-3) * 0.2
        eb = data.edit_bones.new(joint)
        eb.head, eb.tail = (Y_UP.T @ heads[j]).tolist(), (Y_UP.T @ (heads[j] + direction)).tolist()
        if j:
            eb.parent = edit[sk.parents[j]]
        edit.append(eb)
    bpy.ops.object.mode_set(mode="OBJECT")
    return arm


def _new_scene(bpy) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


@contextlib.contextmanager
def _blender_output_kept():
    """Blender's own prints (its importer's traceback on a broken file, progress lines) go to a
    temporary file, not the user's terminal: file descriptors 1 and 2 themselves, which Blender's C
    code writes to. Yields the file, read back where a message is needed."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile("w+b") as kept:
        try:
            os.dup2(kept.fileno(), 1)
            os.dup2(kept.fileno(), 2)
            yield kept
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)


def _reason(error: Exception) -> str:
    """The line of a Blender operator's error that says what is wrong (not its traceback's
    ``Location: .../bpy/ops.py:109``)."""
    lines = [
        line.strip()
        for line in str(error).splitlines()
        if line.strip() and not line.strip().startswith(("Location:", "Traceback", "File "))
    ]
    return (lines[-1] if lines else type(error).__name__).removeprefix("Error: ")[:300]


def import_fbx(path: Path):
    """(armature, fps) of an FBX file imported into an empty scene."""
    bpy = blender()
    _new_scene(bpy)
    try:
        with _blender_output_kept():
            bpy.ops.import_scene.fbx(
                filepath=str(path), anim_offset=0.0
            )  # FBX time 0 is frame 0: a round trip keeps frame numbers
    except RuntimeError as e:
        raise StyleERDError(f"{path}: Blender cannot import this FBX: {_reason(e)}") from None
    arm = single_armature(bpy.context.scene.objects, str(path))
    scene = bpy.context.scene
    return arm, scene.render.fps / scene.render.fps_base


def takes(arm, animation: str, where: str) -> list[tuple[str, object, range]]:
    """(name, action, frames) of the armature's takes: every action the FBX importer made for it
    (named "armature|take"; the name is the take's), or the one named ``animation``."""
    bpy = blender()
    prefix = f"{arm.name}|"
    found = []
    for action in bpy.data.actions:
        name = action.name
        while name.startswith(prefix):  # Blender writes a take as "armature|action" and reads it as "armature|take"
            name = name.removeprefix(prefix)
        if name != action.name:
            found.append((name, action))
    if not found and arm.animation_data and arm.animation_data.action:
        found = [(arm.animation_data.action.name, arm.animation_data.action)]
    if not found:
        raise StyleERDError(f"{where}: the armature {arm.name!r} has no animation")
    if animation != "all":
        chosen = [(n, a) for n, a in found if animation in (n, a.name)]
        if not chosen:
            raise StyleERDError(
                f"{where}: no animation {animation!r}; it has: " + ", ".join(repr(n) for n, _ in found)[:300]
            )
        found = chosen
    out = []
    for name, action in found:
        first, last = (int(round(x)) for x in action.frame_range)
        out.append((name, action, range(first, last + 1)))
    return out


def fbx_clips(path: Path, animation: str = "all") -> tuple[object, list[tuple[str, object, Motion, range]], float]:
    """(armature, [(take name, its action, its motion, its frames)], fps) of an FBX file: every
    take, or ``animation``."""
    arm, fps = import_fbx(path)
    clips = []
    for name, action, frames in takes(arm, animation, str(path)):
        arm.animation_data.action = action
        clips.append((name, action, read_armature(arm, frames, fps), frames))
    return arm, clips, fps


def fbx_to_glb(source: Path, output: Path) -> None:
    """An FBX character (armature, skinned meshes, materials) as a GLB at rest, through Blender's
    glTF exporter (no animation: a page drives it)."""
    bpy = blender()
    import_fbx(source)
    try:
        with _blender_output_kept():
            bpy.ops.export_scene.gltf(filepath=str(output), export_format="GLB", export_animations=False)
    except RuntimeError as e:
        raise StyleERDError(f"{source}: Blender cannot write it as glTF: {_reason(e)}") from None


def fbx_rest(arm) -> Motion:
    """The armature's rest pose as one frame (every bone's pose cleared)."""
    bpy = blender()
    if arm.animation_data is not None:
        arm.animation_data.action = None
    for pb in arm.pose.bones:
        pb.matrix_basis.identity()
    bpy.context.view_layer.update()
    return read_armature(arm, range(bpy.context.scene.frame_current, bpy.context.scene.frame_current + 1), 30.0)


def _rest_keys(arm, frame: int, insert: bool) -> None:
    """Key (or unkey) every bone at its rest pose on ``frame``."""
    for pb in arm.pose.bones:
        paths = [
            "location",
            {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}.get(
                pb.rotation_mode, "rotation_euler"
            ),
        ]
        if insert:
            pb.matrix_basis.identity()
            for path in paths:
                pb.keyframe_insert(path, frame=frame)
        else:
            for path in paths:
                pb.keyframe_delete(path, frame=frame)


def export_fbx(path: Path, arm, frames: range, fps: float, every_action: bool = False) -> None:
    """The scene (the armature with its active action, or with ``every_action`` each of its
    actions as a take; its meshes) as FBX, written atomically. Blender writes a bone's default
    transform from the pose at the current frame, and without a skinned mesh there is no bind
    pose, so an importer would take that pose for the rest: the export runs on a frame just
    before the motion where a temporary key holds the rest pose (one action only: with several,
    the rest is the skinned meshes' bind pose)."""
    bpy = blender()
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames.start, frames.stop - 1
    scene.render.fps, scene.render.fps_base = max(1, int(round(fps))), max(1, int(round(fps))) / fps
    rest_frame = frames.start - 1
    scene_name = scene.name
    if not every_action:
        _rest_keys(arm, rest_frame, insert=True)
        scene.name = arm.animation_data.action.name  # one take is named after the scene: the action's name
    scene.frame_set(rest_frame)

    def write(tmp: str) -> None:
        bpy.ops.export_scene.fbx(
            filepath=tmp,
            use_selection=False,
            bake_anim=True,
            bake_anim_use_all_actions=every_action,
            bake_anim_use_nla_strips=False,
            bake_anim_simplify_factor=0.0,
            add_leaf_bones=False,
        )

    try:
        atomic_write(path, write, suffix=".fbx")
    finally:
        if not every_action:
            _rest_keys(arm, rest_frame, insert=False)
        scene.name = scene_name
        scene.frame_set(frames.start)


def _write_takes(arm, clips: list[tuple[str, object | None, Motion, range]], options: TransferOptions) -> None:
    """Each stylised clip as an action of ``arm``, named as its take (``NAME-STYLE`` beside the
    original with ``keep_original``; without, the original action is removed first)."""
    bpy = blender()
    tag = style_tag(options.target)
    for name, original, motion, frames in clips:
        if original is not None and not options.keep_original:
            bpy.data.actions.remove(original)
        write_action(arm, motion, frames, f"{name}-{tag}" if options.keep_original else name)


def _single(output: Path, clips: list) -> None:
    if len(clips) > 1:
        raise StyleERDError(
            f"{output}: a {output.suffix.lower()} here holds one animation and the input has {len(clips)} "
            f"({', '.join(repr(c[0]) for c in clips)[:200]}); pick one with --animation NAME, or write .fbx"
        )


def transfer_fbx(
    source: Path, output: Path, model: GeneratorWeights, options: TransferOptions, report=None
) -> TransferReport:
    """FBX -> FBX (the same file: every take stylised, or ``options.animation``), FBX -> BVH/GLB
    (one take), or BVH/glTF -> FBX (a new armature), through Blender."""
    bpy = blender()
    kind = output.suffix.lower()
    if kind not in (".fbx", ".bvh", ".glb"):
        raise StyleERDError(f"{output}: from or to FBX the output must be .fbx, .bvh or .glb")
    check_output(output, source)
    fps = model.meta["data"]["fps"]
    if source.suffix.lower() == ".fbx":
        arm, inputs, file_fps = fbx_clips(source, options.animation)
    else:
        motion = read_motion(source)
        _new_scene(bpy)
        arm, file_fps = armature_from_motion(motion, source.stem), motion.fps
        inputs = [(source.stem, None, motion, range(1, motion.n_frames + 1))]
    labels: list = []
    outs = [
        (
            name,
            action,
            transfer_motion(motion, model, fps, options, report if k == 0 else None, labels, str(source)),
            frames,
        )
        for k, (name, action, motion, frames) in enumerate(inputs)
    ]
    if kind in (".bvh", ".glb"):
        _single(output, outs)
        if kind == ".bvh":
            bvh.write(output, outs[0][2])
        else:
            write_glb(output, outs[0][2], mesh=options.mesh, name=outs[0][0])
    else:
        _write_takes(arm, outs, options)
        export_fbx(output, arm, outs[0][3], file_fps, every_action=len(outs) > 1 or options.keep_original)
    out = outs[0][2]
    return TransferReport(sum(o[2].n_frames for o in outs), out.fps, labels[-1] if labels else None, len(outs))


def transfer_onto_fbx(
    source: Path, avatar: Path, output: Path, model: GeneratorWeights, options: TransferOptions, report=None
) -> TransferReport:
    """A motion (BVH, glTF, VRMA or FBX: every take or ``options.animation``) stylised and put on
    an FBX character's armature (``offline.on_avatar``: mapped bones turn as the motion's, scaled
    to its legs), written into a copy of the character (.fbx, one take per clip, meshes kept) or,
    for one clip, as a BVH of its skeleton."""
    kind = output.suffix.lower()
    if kind not in (".fbx", ".bvh"):
        raise StyleERDError(f"{output}: onto an FBX character the output must be .fbx or .bvh")
    check_output(output, source, avatar)
    motions, explicit = source_clips(source, model, options)  # an FBX's takes through Blender too
    if kind == ".bvh":
        _single(output, motions)
    arm, file_fps = import_fbx(avatar)  # a new scene: the source's armature (already read) is gone
    try:  # the character's own takes, if it has any
        originals = {name: action for name, action, _ in takes(arm, "all", str(avatar))}
    except StyleERDError:
        originals = {}
    rest = fbx_rest(arm)
    onto = map_skeleton(rest.skeleton, model, None, str(avatar), rest.rotations[0])
    worn, label = stylised_onto(
        motions, explicit, rest, onto, model, model.meta["data"]["fps"], options, source, avatar, report
    )
    if kind == ".bvh":
        bvh.write(output, worn[0][1])
    else:
        if not options.keep_original:
            for action in originals.values():
                blender().data.actions.remove(action)
        _write_takes(arm, [(name, None, m, range(1, m.n_frames + 1)) for name, m in worn], options)
        export_fbx(
            output,
            arm,
            range(1, worn[0][1].n_frames + 1),
            file_fps,
            every_action=len(worn) > 1 or options.keep_original,
        )
    return TransferReport(sum(m.n_frames for _, m in worn), worn[0][1].fps, label, len(worn))
