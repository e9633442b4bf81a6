"""Run by tests/test_blender.py with the Python of a virtualenv holding ``styleerd[blender]``
(Blender's ``bpy``): builds a Mixamo-named character in Blender (bones with their own rolls, a
skinned body, the generated walk keyed through Blender's own pose API), exports it as FBX, and
measures what the test asserts. Prints one JSON object.

    python blender_checks.py make WORKDIR      # WORKDIR/walk.fbx and WORKDIR/walk.bvh (the same motion)
    python blender_checks.py compare WORKDIR   # WORKDIR/out.fbx re-imported vs WORKDIR/ref.bvh
    python blender_checks.py addon WORKDIR     # the add-on's operator on walk.fbx vs ref.bvh
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

from styleerd.motion import bvh, procedural, quat
from styleerd.motion.kinematics import forward_kinematics

Y_UP_TO_BLENDER = Matrix(((1, 0, 0), (0, 0, -1), (0, 1, 0)))  # (x, y, z) Y-up -> Blender's (x, -z, y)
SCALE = 0.01  # the character in metres, like an imported Mixamo file


def empty_scene() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def world_rest_relative(arm, frames) -> tuple[list[str], np.ndarray]:
    """Per frame and bone, the bone's world rotation relative to its rest, in Y-up axes, as
    quaternions ``[T, J, 4]``: mathutils only, independent of styleerd.runtime.fbx."""
    names = [b.name for b in arm.data.bones]
    to_y = Y_UP_TO_BLENDER.transposed()
    rest = {b.name: (arm.matrix_world @ b.matrix_local).to_quaternion() for b in arm.data.bones}
    out = np.empty((len(frames), len(names), 4))
    for t, f in enumerate(frames):
        bpy.context.scene.frame_set(f)
        for j, name in enumerate(names):
            pose = (arm.matrix_world @ arm.pose.bones[name].matrix).to_quaternion()
            rel = (pose @ rest[name].inverted()).to_matrix()
            out[t, j] = (to_y @ rel @ Y_UP_TO_BLENDER).to_quaternion()
    return names, out


def bvh_world(path: Path) -> tuple[list[str], np.ndarray]:
    m = bvh.read(path)
    return list(m.skeleton.names), forward_kinematics(m.rotations, m.positions, m.skeleton.parents)[0]


def make(work: Path) -> dict:
    walk = procedural.walk(seconds=4.0, fps=30.0)
    bvh.write(work / "walk.bvh", walk)
    sk = walk.skeleton
    empty_scene()
    scene = bpy.context.scene
    scene.render.fps, scene.frame_start, scene.frame_end = 30, 1, walk.n_frames
    data = bpy.data.armatures.new("Armature")
    arm = bpy.data.objects.new("Armature", data)
    scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    heads = np.zeros((sk.n_joints, 3))
    for j in range(1, sk.n_joints):
        heads[j] = heads[sk.parents[j]] + sk.offsets[j]
    rng = np.random.default_rng(7)
    bones = []
    for j, name in enumerate(sk.names):
        kids = sk.children(j)
        direction = (
            sk.offsets[kids[0]] if kids else np.array([0.0, 8.0, 0.0]) if "Head" in name else sk.offsets[j] * 0.5
        )
        eb = data.edit_bones.new(f"mixamorig:{name}")
        eb.head = Y_UP_TO_BLENDER @ Vector(heads[j] * SCALE)
        eb.tail = Y_UP_TO_BLENDER @ Vector((heads[j] + direction) * SCALE)
        eb.roll = float(rng.uniform(-np.pi, np.pi))  # every bone rolled its own way, as rigs are
        if j:
            eb.parent = bones[sk.parents[j]]
        bones.append(eb)
    bpy.ops.object.mode_set(mode="OBJECT")
    # a skinned body: one box per bone, weighted to it
    verts, faces, groups = [], [], []
    for b in data.bones:
        h, t = b.head_local, b.tail_local
        axis = (t - h).normalized()
        side = axis.orthogonal().normalized() * 0.02
        up = axis.cross(side).normalized() * 0.02
        base = len(verts)
        for end in (h, t):
            for s1, s2 in ((1, 1), (1, -1), (-1, -1), (-1, 1)):
                verts.append(end + side * s1 + up * s2)
        faces += [
            (base + a, base + b_, base + c, base + d)
            for a, b_, c, d in ((0, 1, 2, 3), (4, 7, 6, 5), (0, 4, 5, 1), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 4, 0))
        ]
        groups.append((b.name, range(base, base + 8)))
    mesh = bpy.data.meshes.new("Body")
    mesh.from_pydata([tuple(v) for v in verts], [], faces)
    body = bpy.data.objects.new("Body", mesh)
    scene.collection.objects.link(body)
    body.parent = arm
    body.modifiers.new("Armature", "ARMATURE").object = arm
    for name, idx in groups:
        body.vertex_groups.new(name=name).add(list(idx), 1.0, "REPLACE")
    # the walk keyed through Blender's own pose API: world pose = G (rest-relative, Y-up) @ rest
    g_rot, g_pos = forward_kinematics(walk.rotations, walk.positions, sk.parents)
    arm.animation_data_create()
    arm.animation_data.action = bpy.data.actions.new("walk")
    for t in range(walk.n_frames):
        scene.frame_set(t + 1)
        for j, name in enumerate(sk.names):
            b, pb = data.bones[f"mixamorig:{name}"], arm.pose.bones[f"mixamorig:{name}"]
            g = Y_UP_TO_BLENDER @ Matrix(quat.to_xform(g_rot[t, j]).tolist()) @ Y_UP_TO_BLENDER.transposed()
            m = (g @ b.matrix_local.to_3x3()).to_4x4()
            m.translation = Y_UP_TO_BLENDER @ Vector(g_pos[t, j] * SCALE)
            pb.matrix = m
            bpy.context.view_layer.update()
            pb.keyframe_insert("rotation_quaternion", frame=t + 1)
            if j == 0:
                pb.keyframe_insert("location", frame=t + 1)
    bpy.ops.export_scene.fbx(
        filepath=str(work / "walk.fbx"), bake_anim=True, bake_anim_simplify_factor=0.0, add_leaf_bones=False
    )
    _names, made = world_rest_relative(arm, range(1, walk.n_frames + 1))
    _, truth = bvh_world(work / "walk.bvh")
    # the character as made moves like the BVH (checks this script's own keying)
    return {"frames": walk.n_frames, "keyed_error_deg": float(np.degrees(quat.angle_between(made, truth)).max())}


def imported(path: Path):
    empty_scene()
    bpy.ops.import_scene.fbx(filepath=str(path), anim_offset=0.0)
    arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    meshes = [o.name for o in bpy.context.scene.objects if o.type == "MESH"]
    arm = arms[0]
    first, last = (int(round(x)) for x in arm.animation_data.action.frame_range)
    return arm, range(first, last + 1), meshes


def compare(work: Path, arm, frames) -> dict:
    names, got = world_rest_relative(arm, frames)
    ref_names, ref = bvh_world(work / "ref.bvh")
    order = [names.index(f"mixamorig:{n}") for n in ref_names]
    err = np.degrees(quat.angle_between(got[:, order], ref))
    _, source = bvh_world(work / "walk.bvh")
    return {
        "bones": sorted(names),
        "frames": len(frames),
        "max_error_deg": float(err.max()),
        "p99_error_deg": float(np.percentile(err, 99)),
        "worst_bone": ref_names[int(err.max(0).argmax())],
        "stylised_change_deg": float(np.degrees(quat.angle_between(ref, source)).max()),
    }


def two_takes(work: Path) -> dict:
    """walk.fbx with a second take, the walk mirrored in time ("Back"): two.fbx."""
    arm, frames, _ = imported(work / "walk.fbx")
    walk = arm.animation_data.action
    walk.name = "Walk"
    back = walk.copy()
    back.name = "Back"
    for fcurve in _fcurves(back):
        for key in fcurve.keyframe_points:
            key.co.x = frames.start + frames.stop - 1 - key.co.x
            key.handle_left.x, key.handle_right.x = key.co.x, key.co.x
        fcurve.update()
    bpy.ops.export_scene.fbx(
        filepath=str(work / "two.fbx"),
        bake_anim=True,
        bake_anim_use_all_actions=True,
        bake_anim_simplify_factor=0.0,
        add_leaf_bones=False,
    )
    return {"takes": sorted(a.name for a in bpy.data.actions)}


def still(work: Path) -> dict:
    """walk.fbx without its animation (a character as modelled): still.fbx."""
    imported(work / "walk.fbx")
    for action in list(bpy.data.actions):
        bpy.data.actions.remove(action)
    bpy.ops.export_scene.fbx(filepath=str(work / "still.fbx"), bake_anim=False, add_leaf_bones=False)
    return {"actions": len(bpy.data.actions)}


def _fcurves(action):
    """An action's F-curves (Blender 4.4+ keeps them in slotted layers)."""
    if getattr(action, "layers", None):
        return [
            fc for layer in action.layers for strip in layer.strips for bag in strip.channelbags for fc in bag.fcurves
        ]
    return list(action.fcurves)


def takes_of(path: Path, work: Path) -> dict:
    """Each take of an FBX as Blender reads it: its frames and its largest bone rotation error
    against the BVH run of the walk (``ref.bvh``; 0 for the stylised walk)."""
    empty_scene()
    bpy.ops.import_scene.fbx(filepath=str(path), anim_offset=0.0)
    arm = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    ref_names, ref = bvh_world(work / "ref.bvh")
    out = {}
    for action in bpy.data.actions:
        arm.animation_data.action = action
        first, last = (int(round(x)) for x in action.frame_range)
        names, got = world_rest_relative(arm, range(first, last + 1))
        order = [names.index(f"mixamorig:{n}") for n in ref_names]
        error = np.degrees(quat.angle_between(got[:, order], ref)).max() if len(got) == len(ref) else None
        out[action.name.replace(f"{arm.name}|", "")] = {"frames": last - first + 1, "error_vs_ref_deg": error}
    return {"takes": out, "meshes": [o.name for o in bpy.context.scene.objects if o.type == "MESH"]}


def fbx_avatar(work: Path) -> dict:
    """walk.fbx as the viewer's server reads an FBX avatar: made a GLB by Blender, its humanoid and
    T-pose found; the T-pose set on the GLB's own nodes: where its hands, feet and head are."""
    import pygltflib as gl

    from styleerd.model.stored import load_generator_weights
    from styleerd.serve.uploads import avatar_rig

    folder = work / "upload"
    folder.mkdir(exist_ok=True)
    (folder / "upload.fbx").write_bytes((work / "walk.fbx").read_bytes())
    rig = avatar_rig(folder / "upload.fbx", load_generator_weights(None))
    doc = gl.GLTF2.load_from_bytes(rig["glb"])
    parent = {c: i for i, n in enumerate(doc.nodes) for c in n.children or []}

    def world(i: int):
        n = doc.nodes[i]
        x, y, z, w = rig["tpose"].get(str(i), n.rotation or [0, 0, 0, 1])
        r, t = np.array([w, x, y, z]), np.array(n.translation or [0.0, 0, 0]) * np.array(n.scale or [1.0, 1, 1])
        if i not in parent:
            return r, t
        pr, pt = world(parent[i])
        return quat.mul(pr, r), pt + quat.mul_vec(pr, t)

    return {
        "glb": rig["glb"][:4].decode(),
        "bones": sorted(rig["bones"]),
        "at": {b: world(rig["bones"][b])[1].tolist() for b in ("head", "leftHand", "rightHand", "leftFoot", "hips")},
    }


def main() -> None:
    what, work = sys.argv[1], Path(sys.argv[2])
    if what == "make":
        result = make(work)
    elif what == "two-takes":
        result = two_takes(work)
    elif what == "still":
        result = still(work)
    elif what == "fbx-avatar":
        result = fbx_avatar(work)
    elif what.startswith("takes-of:"):
        result = takes_of(work / what.removeprefix("takes-of:"), work)
    elif what == "compare":
        source, _, source_meshes = imported(work / "walk.fbx")
        source_bones = sorted(b.name for b in source.data.bones)
        arm, frames, meshes = imported(work / "out.fbx")
        result = {
            **compare(work, arm, frames),
            "meshes": meshes,
            "source_meshes": source_meshes,
            "source_bones": source_bones,
        }
    else:
        import styleerd.blender_addon as addon

        arm, frames, _ = imported(work / "walk.fbx")
        original = arm.animation_data.action.name
        addon.register()
        bpy.context.view_layer.objects.active = arm
        arm.styleerd.style = "elderly"  # labels inferred, as the command line's reference run does
        status = bpy.ops.styleerd.stylise_action()
        action = arm.animation_data.action
        result = {
            "status": sorted(status),
            "original": original,
            "action": action.name,
            "actions": sorted(a.name for a in bpy.data.actions),
            "original_kept": bpy.data.actions[original].use_fake_user,
            **compare(work, arm, frames),
        }
        addon.unregister()
    print("RESULT " + json.dumps(result))


if __name__ == "__main__":
    main()
