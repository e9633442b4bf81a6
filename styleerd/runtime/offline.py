"""Stylise whole motions and BVH files: exactly the streaming path, frame by frame."""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from styleerd.atomic import atomic_write, atomic_write_text, check_output
from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights
from styleerd.motion import bvh, quat
from styleerd.motion.gltf import (
    GLTF_INPUTS,
    GltfMotion,
    read_gltf_character,
    read_gltf_clips,
    read_gltf_file,
    write_glb,
    write_gltf_animations,
    write_vrma,
)
from styleerd.motion.humanoid import joint_tree
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import (
    JointMap,
    UnmappedSkeleton,
    body_parts,
    guessed_joint_map,
    joint_map,
    to_source,
    to_target,
)
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.cleanup import FootLock
from styleerd.runtime.stylizer import StreamStylizer


def stylise_motion(
    model: GeneratorWeights,
    motion: Motion,
    input_style: str | None,
    content: str | None,
    target: dict[str, float],
    backend: str = "numpy",
) -> Motion:
    """The motion in the target style(s): joint rotations from the network, root trajectory
    (position and facing) and joint translations from the input. Labels left None are
    inferred online."""
    return run_stream(StreamStylizer(model, input_style, content, target, fps=motion.fps, backend=backend), motion)


def run_stream(stylizer: StreamStylizer, motion: Motion) -> Motion:
    """Feed a motion on the model's skeleton through a stylizer, one frame at a time."""
    out = np.empty_like(motion.rotations)
    for t in range(motion.n_frames):
        out[t] = stylizer.step(motion.rotations[t : t + 1], motion.positions[t : t + 1])[0][0]
    return Motion(motion.skeleton, out, motion.positions.copy(), motion.fps)


def map_skeleton(
    skeleton: Skeleton,
    model: GeneratorWeights,
    explicit: dict[str, str] | None = None,
    where: str = "input",
    first_pose: np.ndarray | None = None,
) -> JointMap:
    """The mapping of a skeleton onto the model's, or a clear error naming what is missing.
    The model's bone frames come from its average pose; the input's from its rest pose when
    that is a T- or A-pose, else from ``first_pose`` (local rotations of its first frame)."""
    try:
        return joint_map(model.skeleton, skeleton, explicit, model.stats().reference, first_pose)
    except ValueError as e:
        raise StyleERDError(f"{where}: {e}") from None


def write_guessed_joint_map(source: str | Path, output: str | Path, model: GeneratorWeights) -> tuple[int, int]:
    """Write the joint map the automatic mapping finds for ``source`` (BVH, glTF, GLB, VRM: a
    VRM humanoid first), every model joint that plays a body part with its best guess ("" where
    none was found), as JSON to edit and pass back with ``--joint-map``; (joints guessed,
    joints in the map)."""
    check_output(output, source)
    named: dict[str, str] = {}
    if Path(source).suffix.lower() in GLTF_INPUTS:
        character = read_gltf_character(source)
        motion, named = character.motion, humanoid_joint_map(model, character, None)
    else:
        header, chunks = bvh.stream(source, 1)
        motion = bvh.motion_from_channels(header.skeleton, next(chunks), header.fps)
    guessed = guessed_joint_map(model.skeleton, motion.skeleton, motion.rotations[0]) | named
    atomic_write_text(output, json.dumps(guessed, indent=2) + "\n")
    return sum(bool(v) for v in guessed.values()), len(guessed)


@dataclass(frozen=True)
class TransferOptions:
    """What a transfer does: the target weights, the input's labels (None: inferred online),
    the joint map (model joint -> input joint) completing the automatic one, foot cleanup, the
    step backend, a simple skinned body on .glb outputs, and body parts with targets of their
    own."""

    target: dict[str, float]
    input_style: str | None = None
    content: str | None = None
    explicit_map: dict[str, str] | None = None
    cleanup: bool = True
    backend: str = "numpy"
    mesh: bool = False
    parts: str | dict | None = None  # body parts with their own target (``stylizer.part_targets``)
    root_speed: bool = False  # the root's ground speed from the network (``StreamStylizer``), not the input's
    pose: str = (
        "input"  # the input's pose plus the style's posture, or "network": the network's pose (``StreamStylizer``)
    )
    animation: str = "all"  # glTF/VRM input: the animation to stylise (its name), or every one
    keep_original: bool = False  # glTF/VRM output: the input's animations kept, the stylised ones added as NAME-STYLE


@dataclass
class TransferReport:
    """What a file transfer did: frames written, their rate, and the labels inferred at the end."""

    frames: int
    fps: float
    labels: tuple[str, str] | None  # (style, content) at the last frame, when inferred
    clips: int = 1  # animations stylised (a glTF/VRM input's)


def _stylised_stream(
    header: bvh.Header,
    chunks: Iterator[np.ndarray],
    model: GeneratorWeights,
    fps: float,
    options: TransferOptions,
    report: Callable[[str], None] | None,
) -> tuple[Iterator[np.ndarray], StreamStylizer]:
    """The stylised channel values of a stream of frames, chunk by chunk, and its stylizer
    (for the labels it inferred): the checks, the mapping (bone frames from the first frame
    where the rest pose is no T- or A-pose), the streaming path."""
    if header.n_frames == 0:
        raise StyleERDError(f"{header.path}: the motion has no frames")
    if not 10 <= header.fps <= 480:
        raise StyleERDError(f"{header.path}: {header.fps:.6g} fps is outside [10, 480]")
    first = next(chunks)
    first_pose = bvh.motion_from_channels(header.skeleton, first[:1], header.fps).rotations[0]
    o = options
    jm = map_skeleton(header.skeleton, model, o.explicit_map, str(header.path), first_pose)
    if report:
        report(f"joint mapping (model <- input):\n{jm.describe()}")
    stylizer = StreamStylizer(
        model,
        o.input_style,
        o.content,
        o.target,
        fps=fps,
        backend=o.backend,
        parts=o.parts,
        root_speed=o.root_speed,
        pose=o.pose,
    )
    lock = FootLock(header.skeleton, 1, header.fps, legs=jm.source_legs()) if o.cleanup else None
    return _checked(
        _stylised_rows(header, itertools.chain([first], chunks), jm, stylizer, lock, fps), header.path
    ), stylizer


def transfer_motion(
    motion: Motion,
    model: GeneratorWeights,
    fps: float,
    options: TransferOptions,
    report: Callable[[str], None] | None = None,
    labels: list | None = None,
    where: str = "<motion>",
) -> Motion:
    """``transfer_file`` on a motion in memory: the stylised motion on the input's skeleton,
    same frames and fps. ``labels`` receives the (style, content) inferred at the last frame."""
    header = bvh.Header(motion.skeleton, motion.n_frames, motion.fps, where)
    rows, stylizer = _stylised_stream(header, iter([bvh.channel_values(motion)]), model, fps, options, report)
    out = bvh.motion_from_channels(motion.skeleton, np.concatenate(list(rows)), motion.fps)
    inferred = _inferred_labels(stylizer, report)
    if inferred and labels is not None:
        labels.append(inferred)
    return out


def transfer_file(
    source: str | Path,
    output: str | Path,
    model: GeneratorWeights,
    fps: float,
    options: TransferOptions,
    report: Callable[[str], None] | None = None,
    chunk: int = 1024,
) -> TransferReport:
    """BVH in -> BVH (or binary glTF) out in the target style, on any humanoid skeleton
    (retargeted to the model's and back, at the model's frame rate ``fps`` and back): same
    skeleton, channel layout, fps, frame count and root trajectory as the input; joints the
    model does not have keep their motion. Labels left None are inferred online; with
    ``options.cleanup``, feet planted in the input are pinned in the output (on the input's skeleton).
    ``report`` receives the joint mapping and the labels used.

    The file is streamed through in chunks of ``chunk`` frames, so memory stays bounded
    however long it is (a .glb output is built in memory; with ``options.mesh`` it carries a
    simple skinned body). Nothing is written unless the whole transfer succeeded."""
    kind = Path(output).suffix.lower()
    check_output(output, source)
    if kind == ".vrma" and Path(source).suffix.lower() != ".vrma":
        return _transfer_to_vrma(Path(source), Path(output), model, fps, options, report)
    if Path(source).suffix.lower() in GLTF_INPUTS:
        return _transfer_gltf(Path(source), Path(output), model, fps, options, report)
    if kind not in (".bvh", ".glb"):
        raise StyleERDError(
            f"{output}: from a BVH input the output must be .bvh, .glb or .vrma (.fbx with styleerd[blender]); a "
            ".vrm is a character: put the motion on one with --onto AVATAR.vrm"
        )
    header, chunks = bvh.stream(source, chunk)
    rows, stylizer = _stylised_stream(header, chunks, model, fps, options, report)
    if kind == ".bvh":

        def write(tmp: str) -> None:
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(bvh.format_header(header.skeleton, header.n_frames, header.fps))
                f.writelines(bvh.format_frames(values) for values in rows)

        atomic_write(output, write)
    else:
        motion = bvh.motion_from_channels(header.skeleton, np.concatenate(list(rows)), header.fps)
        write_glb(output, motion, mesh=options.mesh, name=Path(source).stem)
    return TransferReport(header.n_frames, header.fps, _inferred_labels(stylizer, report))


def _inferred_labels(stylizer: StreamStylizer, report: Callable[[str], None] | None) -> tuple[str, str] | None:
    """The (style, content) the labeller inferred at the last frame, reported; None when both
    labels were given. Also reported: how unfamiliar the motion was to the network (pose "input")."""
    if report and stylizer.pose == "input" and stylizer.frames[0]:
        share = stylizer.unfamiliar_sum[0] / stylizer.frames[0]
        report(
            f"unfamiliar to the network: {100 * share:.0f} % (0: its own pose, as on motion like its training data; "
            "100: the input's pose turned by the style's change, as on actions it never learnt)"
        )
    if stylizer.labeller is None:
        return None
    labels = stylizer.inferred_labels()[0]
    if report:
        report(
            f"input labels at the last frame: style {labels[0]}, content {labels[1]} (inferred online where not given)"
        )
        if stylizer.labeller.familiar is not None and not stylizer.known_style[0] and stylizer.frames[0]:
            share = stylizer.unread_sum[0] / stylizer.frames[0]
            report(
                f"the input's style unlike any the labeller learnt: {100 * share:.0f} % of frames, read as neutral "
                "there (another performer's motion, mostly; give --input-style if you know it)"
            )
    return labels


def style_tag(target: dict[str, float]) -> str:
    """A target as a name's suffix: its styles by weight, joined ('elderly', 'elderly+feminine')."""
    return "+".join(k for k, w in sorted(target.items(), key=lambda kw: -kw[1]) if w > 0) or "neutral"


def _transfer_gltf(
    source: Path, output: Path, model: GeneratorWeights, fps: float, options: TransferOptions, report
) -> TransferReport:
    """A glTF/GLB/VRM character in: its first skin's skeleton and its animations (every one,
    or ``options.animation``), VRM humanoid bones named for the mapping; out as the same file
    with each animation stylised under its own name (.glb, .vrm; with ``keep_original`` beside
    the input's, named NAME-STYLE) or, for one animation, as a BVH of its skeleton."""
    kind = output.suffix.lower()
    if kind not in (".bvh", ".glb", ".vrm") and not (kind == ".vrma" == source.suffix.lower()):
        raise StyleERDError(f"{output}: from a glTF input the output must be .glb, .vrm, .vrma or .bvh")
    clips = read_gltf_clips(source, None if options.animation == "all" else [options.animation])
    if kind == ".bvh" and len(clips) > 1:
        raise StyleERDError(
            f"{output}: a BVH holds one animation and {source.name} has {len(clips)} "
            f"({', '.join(n for n, _ in clips)[:300]}); pick one with --animation NAME, or write .glb"
        )
    src = clips[0][1]
    explicit = humanoid_joint_map(model, src, options.explicit_map)
    lines: list[str] = []
    out = []
    for k, (name, clip) in enumerate(clips):
        said = report if k == 0 else None  # the mapping is the same for every clip: said once
        if report and len(clips) > 1:
            report(f"animation {name!r} ({k + 1} of {len(clips)}, {clip.motion.n_frames} frames)")
        motion = transfer_motion(
            clip.motion,
            model,
            fps,
            replace(options, explicit_map=explicit or None),
            said,
            labels=lines,
            where=f"{source} (animation {name!r})",
        )
        out.append((f"{name}-{style_tag(options.target)}" if options.keep_original else name, motion))
    if kind == ".bvh":
        bvh.write(output, out[0][1])
    else:
        write_gltf_animations(output, src, out, options.keep_original)
    frames = sum(m.n_frames for _, m in out)
    return TransferReport(frames, out[0][1].fps, lines[-1] if lines else None, len(out))


def humanoid_joint_map(
    model: GeneratorWeights, character: GltfMotion, explicit: dict[str, str] | None
) -> dict[str, str]:
    """The joint map a VRM humanoid gives (model joint -> its bone), completed by ``explicit``."""
    model_parts = body_parts(model.skeleton)
    out = {model.skeleton.names[model_parts[p]]: name for p, name in character.parts.items() if p in model_parts}
    return out | (explicit or {})


def source_clips(
    source: Path, model: GeneratorWeights, options: TransferOptions
) -> tuple[list[tuple[str, Motion]], dict[str, str] | None]:
    """The motions of a file (a BVH's, or a glTF/GLB/VRM/VRMA's or an FBX's animations: every one
    or ``options.animation``) and the joint map to use (a VRM humanoid's, completed by the options')."""
    if source.suffix.lower() == ".fbx":
        from styleerd.runtime.fbx import fbx_clips  # imports bpy: only for FBX

        return [(name, m) for name, _, m, _ in fbx_clips(source, options.animation)[1]], options.explicit_map
    if source.suffix.lower() in GLTF_INPUTS:
        clips = read_gltf_clips(source, None if options.animation == "all" else [options.animation])
        return [(name, c.motion) for name, c in clips], humanoid_joint_map(model, clips[0][1], options.explicit_map)
    return [(source.stem, bvh.read(source))], options.explicit_map


def describe_input(
    source: Path, model: GeneratorWeights, explicit: dict[str, str] | None = None, brief: bool = False
) -> tuple[str, bool]:
    """What ``transfer`` reads from a file (BVH, glTF, GLB, VRM, VRMA or FBX): its animations
    (frames, rate, length), its joint tree (a BVH's with each joint's channels), and its joint
    mapping onto the model's (a VRM humanoid's first, completed by ``explicit``), or why there is
    none; ``brief``: the first line and whether it maps, each in a line. With it, whether the file
    maps. A BVH is read in chunks, so a file of any length takes bounded memory."""
    suffix, channels = source.suffix.lower(), None
    if suffix in GLTF_INPUTS or suffix == ".fbx":
        if suffix == ".fbx":
            clips, named = source_clips(source, model, TransferOptions({}, explicit_map=explicit))
            kind, rest = "FBX", clips[0][1]
        else:  # a character may have no animation: its rest pose is what is mapped
            character, animations = read_gltf_file(source)
            kind = {".vrm": "VRM", ".vrma": "VRM Animation"}.get(suffix, "glTF")
            kind += ", a VRM humanoid" if character.parts else ""
            clips, named = [(n, c.motion) for n, c in animations], humanoid_joint_map(model, character, explicit)
            rest = clips[0][1] if clips else character.motion
        skeleton, first_pose = rest.skeleton, rest.rotations[0]
        lines = [f"{source}: {kind}, {skeleton.n_joints} joints, {len(clips)} animation(s)"]
        details = [f"  {n!r}: {m.n_frames} frames at {m.fps:.6g} fps ({m.n_frames / m.fps:.2f} s)" for n, m in clips]
        details += [] if clips else ["  no animation: a character to put a motion on (transfer --onto)"]
    else:
        header, chunks = bvh.stream(source)
        first = next(chunks, np.empty((0, 0)))
        n_frames = len(first) + sum(len(chunk) for chunk in chunks)  # every frame checked, in bounded memory
        skeleton, fps, named, channels = header.skeleton, header.fps, explicit, header.skeleton.channels
        first_pose = bvh.motion_from_channels(skeleton, first[:1], fps).rotations[0] if len(first) else None
        lines = [
            f"{source}: {n_frames} frames at {fps:.6g} fps ({n_frames / fps:.2f} s), {skeleton.n_joints} joints, "
            + f"{sum(len(c) for c in channels)} channels"
        ]
        details = []
    if not brief:
        notes = None if channels is None else [f"  [{' '.join(c)}]" for c in channels]
        lines += [*details, "skeleton:", joint_tree(skeleton, skeleton.n_joints, notes)]
    try:  # map_skeleton's mapping; a refusal without the joint tree again
        jm = joint_map(model.skeleton, skeleton, named, model.stats().reference, first_pose)
        lines.append("  maps onto the model" if brief else f"joint mapping (model <- input):\n{jm.describe()}")
    except UnmappedSkeleton as e:
        lines.append(f"{'  ' if brief else ''}no joint mapping onto the model: {e.brief}")
    except ValueError as e:
        lines.append(f"{'  ' if brief else ''}no joint mapping onto the model: {e}")
    else:
        return "\n".join(lines), True
    return "\n".join(lines), False


def stylised_on_model(
    motion: Motion, model: GeneratorWeights, fps: float, options: TransferOptions, where: str, report, labels: list
) -> tuple[Motion, JointMap]:
    """A motion stylised (as ``transfer_motion``: feet cleaned on its own skeleton) and put on
    the model's skeleton, with its joint map."""
    styled = transfer_motion(motion, model, fps, options, report, labels, where)
    jm = map_skeleton(motion.skeleton, model, options.explicit_map, where, motion.rotations[0])
    return to_target(styled, jm), jm


def _transfer_to_vrma(
    source: Path, output: Path, model: GeneratorWeights, fps: float, options: TransferOptions, report
) -> TransferReport:
    """One clip stylised and written as a VRM Animation (``write_vrma``), for any VRM avatar."""
    motions, explicit = source_clips(source, model, options)
    if len(motions) > 1:
        raise StyleERDError(f"{output}: a VRM Animation holds one clip; pick one with --animation NAME")
    lines: list[str] = []
    on_model, jm = stylised_on_model(
        motions[0][1], model, fps, replace(options, explicit_map=explicit or None), str(source), report, lines
    )
    reference = model.stats().reference
    write_vrma(output, on_model, jm.target_tpose, reference, body_parts(model.skeleton), name=motions[0][0])
    return TransferReport(on_model.n_frames, on_model.fps, lines[-1] if lines else None)


def transfer_onto(
    source: Path,
    avatar: Path,
    output: Path,
    model: GeneratorWeights,
    fps: float,
    options: TransferOptions,
    report: Callable[[str], None] | None = None,
) -> TransferReport:
    """A motion (BVH, or every animation of a glTF/GLB/VRM/VRMA/FBX, or ``options.animation``)
    stylised and put on another character, ``avatar`` (glTF, GLB, VRM, FBX; animated or not): its
    mapped joints turn as the stylised motion's, scaled to its leg length, its other joints keep
    their rest pose. Written into a copy of the avatar (.glb, .vrm: meshes, materials, spring
    bones, expressions kept, one animation per clip) or, for one clip, as a BVH of its skeleton
    (a .vrma output is any avatar's: ``transfer_file``'s)."""
    kind = output.suffix.lower()
    if kind == ".vrma":  # a VRM Animation fits any avatar: the motion is written as one
        if report:
            report(f"a .vrma plays on any VRM avatar: written for none in particular ({avatar.name} not read)")
        return transfer_file(source, output, model, fps, options, report)
    if avatar.suffix.lower() == ".fbx" or kind == ".fbx":
        from styleerd.runtime.fbx import transfer_onto_fbx  # imports bpy: only for FBX

        if avatar.suffix.lower() != ".fbx":
            raise StyleERDError(f"{output}: an .fbx output is written onto an FBX character (--onto CHARACTER.fbx)")
        return transfer_onto_fbx(source, avatar, output, model, options, report)
    if kind not in (".glb", ".vrm", ".bvh"):
        raise StyleERDError(f"{output}: with --onto the output must be .glb, .vrm, .vrma, .fbx or .bvh")
    check_output(output, source, avatar)
    motions, explicit = source_clips(source, model, options)
    if kind == ".bvh" and len(motions) > 1:
        raise StyleERDError(f"{output}: a BVH holds one animation; pick one with --animation NAME, or write .glb")
    character = read_gltf_character(avatar)
    rest = character.motion
    onto = map_skeleton(
        rest.skeleton, model, humanoid_joint_map(model, character, None), str(avatar), rest.rotations[0]
    )
    out, label = stylised_onto(motions, explicit, rest, onto, model, fps, options, source, avatar, report)
    if kind == ".bvh":
        bvh.write(output, out[0][1])
    else:
        write_gltf_animations(output, character, out)
    return TransferReport(sum(m.n_frames for _, m in out), out[0][1].fps, label, len(out))


def stylised_onto(
    motions: list[tuple[str, Motion]],
    explicit: dict[str, str] | None,
    rest: Motion,
    onto: JointMap,
    model: GeneratorWeights,
    fps: float,
    options: TransferOptions,
    source: Path,
    avatar: Path,
    report: Callable[[str], None] | None,
) -> tuple[list[tuple[str, Motion]], tuple[str, str] | None]:
    """Each (name, motion) stylised and put on a character (``on_avatar``: ``rest`` its rest pose,
    ``onto`` its map onto the model), and the labels inferred at the last frame."""
    if report:
        report(f"onto {avatar.name} (model -> avatar):\n{onto.describe()}")
    labels: list = []
    out = []
    for k, (name, motion) in enumerate(motions):
        on_model, _ = stylised_on_model(
            motion,
            model,
            fps,
            replace(options, explicit_map=explicit or None),
            str(source),
            report if k == 0 else None,
            labels,
        )
        out.append((name, on_avatar(on_model, onto, rest)))
    return out, labels[-1] if labels else None


def on_avatar(on_model: Motion, onto: JointMap, rest: Motion) -> Motion:
    """A motion on the model's skeleton put on an avatar (``onto`` maps the avatar onto the
    model; ``rest``: the avatar's rest pose, one frame): mapped joints take the motion's global
    rotations, the others their rest; the hips follow the model's path scaled to the avatar's
    legs, raised or lowered once for the whole clip so that its feet meet the floor of its
    rest pose as often as the input's meet theirs (the 5th percentile of the lowest foot).
    Offline: the level is the clip's, not frame by frame."""
    T, sk = on_model.n_frames, rest.skeleton
    base = Motion(sk, np.repeat(rest.rotations[:1], T, 0), np.repeat(rest.positions[:1], T, 0), on_model.fps)
    out = to_source(on_model, onto, base)
    hips = dict(onto.pairs)[0]  # the avatar's joint playing the model's root
    parent = int(sk.parents[hips])
    if parent >= 0:  # the joints above the hips (an armature's root bone), which the hips' path is put under
        g, p = forward_kinematics(out.rotations[:, :hips], out.positions[:, :hips], sk.parents[:hips])
    world = on_model.positions[:, 0] / onto.scale
    feet = [j for part, j in body_parts(sk, rest.rotations[0]).items() if part.endswith(("_foot", "_toe"))]

    def place(world: np.ndarray) -> np.ndarray:
        return world if parent < 0 else quat.mul_vec(quat.inv(g[:, parent]), world - p[:, parent])

    out.positions[:, hips] = place(world)
    lowest = forward_kinematics(out.rotations, out.positions, sk.parents)[1][:, feet, 1].min(1)
    floor = forward_kinematics(rest.rotations[:1], rest.positions[:1], sk.parents)[1][0, feet, 1].min()
    world[:, 1] += floor - np.percentile(lowest, 5)
    out.positions[:, hips] = place(world)
    return out


def _checked(rows: Iterator[np.ndarray], source) -> Iterator[np.ndarray]:
    for values in rows:
        if not np.isfinite(values).all():
            raise StyleERDError(f"{source}: the transfer produced non-finite values; nothing written")
        yield values


def _stylised_rows(
    header: bvh.Header,
    chunks: Iterator[np.ndarray],
    jm: JointMap,
    stylizer: StreamStylizer,
    lock: FootLock | None,
    fps: float,
) -> Iterator[np.ndarray]:
    """Output channel values, chunk by chunk, of the source frames streamed in: retarget each
    frame, resample to the model's rate (slerp between the two source frames around each
    model frame), stylise, take each source frame's own pose turned by the style's change
    (per joint, the stylised rotation against the model frame's input) slerped between the two
    model frames around it, retarget back, clean the feet. Resampling the change rather than
    the stylised poses keeps what the input has between model frames (a 120 fps take's detail,
    a cut from a rest pose into the motion). Only the few frames that interpolation still needs
    are kept. Equal to doing the same to the whole motion at once (tested)."""
    T, fs = header.n_frames, header.fps
    same = bool(np.isclose(fps, fs, rtol=1e-5, atol=0.0))  # as motion.resample decides
    step_in, step_out = fs / fps, fps / fs
    J = T if same else (int(np.floor((T - 1) / step_in + 1e-6)) + 1 if T > 1 else 1)

    def around(x: float, n: int) -> tuple[int, float]:
        """The frame pair (i0, i0 + 1) around position x in n frames, and the weight of i0 + 1."""
        if n == 1:
            return 0, 0.0
        i0 = min(int(np.floor(x)), n - 2)
        return i0, x - i0

    def model_input(j: int) -> tuple[int, float]:
        return (j, 0.0) if same else around(j * step_in, T)

    def model_output(k: int) -> tuple[int, float]:
        return (k, 0.0) if same else around(min(k * step_out, J - 1), J)

    def mix(frames: dict, i0: int, w: float) -> tuple[np.ndarray, np.ndarray]:
        rot, pos = frames[i0][:2]
        if w == 0.0 and (same or i0 + 1 not in frames):
            return rot, pos
        rot1, pos1 = frames[i0 + 1][:2]
        return quat.slerp(rot, rot1, np.full(len(rot), w)), pos * (1 - w) + pos1 * w

    src: dict[int, tuple] = {}  # source frame -> (model-skeleton rotations, positions, source frame)
    out: dict[int, tuple] = {}  # model frame -> stylised (rotations, positions)
    i, j, k = -1, 0, 0
    for values in chunks:
        bad = bvh.channel_problem(header.skeleton, values)
        if bad is not None:
            raise StyleERDError(f"{header.path}: frame {i + 1 + bad[0]}: {bad[1]}; nothing written")
        motion = bvh.motion_from_channels(header.skeleton, values, fs)
        on_model = to_target(motion, jm)
        rows = []
        for r in range(len(values)):
            i += 1
            src[i] = (on_model.rotations[r], on_model.positions[r], motion[r : r + 1])
            while j < J and (model_input(j)[0] + (0 if same or T == 1 else 1)) <= i:
                rot, pos = mix(src, *model_input(j))
                styled, styled_pos = stylizer.step(rot[None], pos[None])
                change = styled[0] if same else quat.mul(quat.inv(rot), styled[0])
                out[j] = (change, styled_pos[0, 0] - pos[0])  # and the root's move by its stylised speed (model units)
                j += 1
            while k < T and (model_output(k)[0] + (0 if same or J == 1 else 1)) < j and k <= i:
                i0, w = model_output(k)
                change, root_move = mix(out, i0, w)
                rot, pos, frame = src[k]
                rot = change if same else quat.mul(rot, change)
                back = to_source(Motion(jm.target, rot[None], pos[None], fs), jm, frame)
                if stylizer.root_speed:
                    back.positions[0, 0] += root_move / jm.scale
                if lock is not None:
                    back.rotations, back.positions = lock.step(
                        back.rotations, back.positions, frame.rotations, frame.positions
                    )
                rows.append(bvh.channel_values(back)[0])
                k += 1
            keep_src = min(k, model_input(j)[0] if j < J else k)
            for key in [key for key in src if key < keep_src]:
                del src[key]
            keep_out = model_output(k)[0] if k < T else j
            for key in [key for key in out if key < keep_out]:
                del out[key]
        if rows:
            yield np.stack(rows)
    if k != T:
        raise StyleERDError(f"{header.path}: internal error: {k} of {T} frames stylised")
