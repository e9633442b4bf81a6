"""A procedural walk on a Mixamo-named, T-pose skeleton: the demo's bundled input, made by the
project itself (no dataset clip is shipped). Y up, facing +Z, centimetres."""

from __future__ import annotations

import numpy as np

from styleerd.motion import quat
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import POSITION_CHANNELS, Skeleton

_JOINTS = [  # name, parent, rest offset (T-pose)
    ("Hips", None, (0, 95, 0)),
    ("Spine", "Hips", (0, 10, 0)),
    ("Spine1", "Spine", (0, 10, 0)),
    ("Spine2", "Spine1", (0, 10, 0)),
    ("Neck", "Spine2", (0, 15, 0)),
    ("Head", "Neck", (0, 10, 0)),
    ("LeftShoulder", "Spine2", (4, 12, 0)),
    ("LeftArm", "LeftShoulder", (12, 0, 0)),
    ("LeftForeArm", "LeftArm", (27, 0, 0)),
    ("LeftHand", "LeftForeArm", (24, 0, 0)),
    ("RightShoulder", "Spine2", (-4, 12, 0)),
    ("RightArm", "RightShoulder", (-12, 0, 0)),
    ("RightForeArm", "RightArm", (-27, 0, 0)),
    ("RightHand", "RightForeArm", (-24, 0, 0)),
    ("LeftUpLeg", "Hips", (9, -5, 0)),
    ("LeftLeg", "LeftUpLeg", (0, -42, 0)),
    ("LeftFoot", "LeftLeg", (0, -42, 0)),
    ("LeftToeBase", "LeftFoot", (0, -6, 13)),
    ("RightUpLeg", "Hips", (-9, -5, 0)),
    ("RightLeg", "RightUpLeg", (0, -42, 0)),
    ("RightFoot", "RightLeg", (0, -42, 0)),
    ("RightToeBase", "RightFoot", (0, -6, 13)),
]
_ROT = ("Zrotation", "Xrotation", "Yrotation")


def tpose_skeleton() -> Skeleton:
    """A 22-joint Mixamo-named humanoid in a T-pose, in centimetres (the demo's and tests' skeleton)."""
    names = [n for n, _, _ in _JOINTS]
    return Skeleton(
        names=tuple(names),
        parents=np.array([-1 if p is None else names.index(p) for _, p, _ in _JOINTS]),
        offsets=np.array([o for _, _, o in _JOINTS], dtype=np.float64),
        channels=tuple(POSITION_CHANNELS + _ROT if p is None else _ROT for _, p, _ in _JOINTS),
        end_sites=(
            (names.index("Head"), np.array([0, 12.0, 0])),
            (names.index("LeftHand"), np.array([10.0, 0, 0])),
            (names.index("RightHand"), np.array([-10.0, 0, 0])),
            (names.index("LeftToeBase"), np.array([0, 0, 6.0])),
            (names.index("RightToeBase"), np.array([0, 0, 6.0])),
        ),
    )


def with_extra_joints(skeleton: Skeleton, extra: int, chain: int = 20) -> Skeleton:
    """``skeleton`` with ``extra`` more joints under its root, in chains of ``chain`` (hair,
    cloth, props: what production rigs add), for tests and benchmarks of large skeletons."""
    names, parents, offsets = list(skeleton.names), list(skeleton.parents), list(skeleton.offsets)
    for k in range(extra):
        parents.append(0 if k % chain == 0 else len(names) - 1)
        names.append(f"X{k}")
        offsets.append(np.array([0.0, 1.0, 0.0]))
    return Skeleton(
        tuple(names), np.array(parents), np.array(offsets), skeleton.channels + (_ROT,) * extra, skeleton.end_sites
    )


def _rx(deg):
    return quat.from_angle_axis(np.radians(deg), np.array([1.0, 0, 0]))


def _ry(deg):
    return quat.from_angle_axis(np.radians(deg), np.array([0, 1.0, 0]))


def _rz(deg):
    return quat.from_angle_axis(np.radians(deg), np.array([0, 0, 1.0]))


def walk(
    seconds: float = 6.0,
    fps: float = 60.0,
    steps_per_second: float = 1.8,
    speed: float = 125.0,
    turn_degrees_per_second: float = 12.0,
) -> Motion:
    """A plain, neutral walk along a gentle left curve: legs swing from the hips, knees bend in
    the swing phase, arms swing against the legs, the pelvis bobs, sways and twists."""
    sk = tpose_skeleton()
    T = int(round(seconds * fps))
    t = np.arange(T) / fps
    phase = np.pi * steps_per_second * t  # one full cycle = two steps
    s, c = np.sin(phase), np.cos(phase)
    rot = quat.identity((T, sk.n_joints))
    j = sk.index
    heading = np.radians(turn_degrees_per_second) * t
    rot[:, j("Hips")] = quat.mul(_ry(np.degrees(heading) + 5 * s), _rz(2.5 * c))
    rot[:, j("Spine")] = _ry(-3 * s)
    rot[:, j("Spine2")] = _ry(-3 * s)
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        swing = sign * s  # +1: this leg forward
        forward_motion = sign * c  # > 0 while this leg swings forward
        rot[:, j(f"{side}UpLeg")] = _rx(-24 * swing - 6 * np.maximum(forward_motion, 0))
        rot[:, j(f"{side}Leg")] = _rx(8 + 45 * np.maximum(forward_motion, 0) ** 1.5)
        rot[:, j(f"{side}Foot")] = _rx(-6 * swing)
        rot[:, j(f"{side}Arm")] = quat.mul(_rx(-22 * -swing), _rz(-sign * 78))  # arms down, swing against the leg
        rot[:, j(f"{side}ForeArm")] = _ry(-sign * (20 + 15 * np.maximum(-swing, 0)))  # elbows bend forward
    pos = np.broadcast_to(sk.offsets, (T, sk.n_joints, 3)).copy()
    radius = speed / max(np.radians(turn_degrees_per_second), 1e-9)
    pos[:, 0, 0] = radius * (1 - np.cos(heading)) if turn_degrees_per_second else 0.0
    pos[:, 0, 2] = radius * np.sin(heading) if turn_degrees_per_second else speed * t
    pos[:, 0, 1] = 95 - 1.5 + 1.5 * np.cos(2 * phase)
    return Motion(sk, quat.normalize(rot), pos, fps)


def with_rest_frames(
    motion: Motion, frames: np.ndarray, names: tuple[str, ...] | None = None, scale: float = 1.0
) -> Motion:
    """The same movement on a rig whose joints have other rest frames: ``frames [J, 4]`` is each
    joint's new frame relative to its old one (the old rest is identity everywhere), so every
    joint's global rotation becomes ``G_j * frames_j``, every offset ``inv(frames_parent) *
    offset``, and the joint positions stay (times ``scale``: other units). Renamed by ``names``."""
    sk = motion.skeleton
    parent_frames = np.where(
        (sk.parents >= 0)[:, None], frames[np.maximum(sk.parents, 0)], quat.identity((sk.n_joints,))
    )
    offsets = quat.mul_vec(quat.inv(parent_frames), sk.offsets) * scale
    local = quat.mul(quat.mul(quat.inv(parent_frames), motion.rotations), frames)
    pos = np.broadcast_to(offsets, motion.positions.shape).copy()
    pos[:, 0] = motion.positions[:, 0] * scale
    ends = tuple((j, quat.mul_vec(quat.inv(frames[j]), o) * scale) for j, o in sk.end_sites)
    skeleton = Skeleton(names or sk.names, sk.parents, offsets, sk.channels, ends)
    return Motion(skeleton, quat.normalize(local), pos, motion.fps)


_BLENDER = {"Hips": "hips", "Spine": "spine", "Spine1": "spine.001", "Spine2": "chest", "Neck": "neck", "Head": "head"}
for _side, _s in (("Left", "L"), ("Right", "R")):
    _BLENDER.update(
        {
            f"{_side}Shoulder": f"shoulder.{_s}",
            f"{_side}Arm": f"upper_arm.{_s}",
            f"{_side}ForeArm": f"forearm.{_s}",
            f"{_side}Hand": f"hand.{_s}",
            f"{_side}UpLeg": f"thigh.{_s}",
            f"{_side}Leg": f"shin.{_s}",
            f"{_side}Foot": f"foot.{_s}",
            f"{_side}ToeBase": f"toe.{_s}",
        }
    )


def rig_variants(motion: Motion | None = None, seed: int = 0) -> dict[str, Motion]:
    """The demo walk (or ``motion`` on the same skeleton) on rigs that differ from it the way
    users' rigs do: an A-pose rest, metres, Blender names and proportions, and joint frames
    rolled about their own bones (which the rest pose cannot show). Every one moves exactly
    like the original: same joint positions (up to units) and bone orientations."""
    motion = motion or walk()
    sk = motion.skeleton
    J, j = sk.n_joints, sk.index
    out = {"Mixamo T-pose, centimetres": motion}
    a_pose = quat.identity((J,))
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        for name in (f"{side}Arm", f"{side}ForeArm", f"{side}Hand"):
            a_pose[j(name)] = _rz(sign * 45)
    out["A-pose, centimetres"] = with_rest_frames(motion, a_pose)
    out["Mixamo T-pose, metres"] = with_rest_frames(motion, quat.identity((J,)), scale=0.01)
    blender = with_rest_frames(motion, quat.identity((J,)), tuple(_BLENDER[n] for n in sk.names), scale=0.01)
    lengths = np.array(
        [1.2 if "Leg" in n or "Foot" in n else 0.85 if "Arm" in n or "Spine" in n else 1.0 for n in sk.names]
    )
    body = Skeleton(
        blender.skeleton.names,
        sk.parents,
        blender.skeleton.offsets * lengths[:, None],
        sk.channels,
        blender.skeleton.end_sites,
    )
    pos = np.broadcast_to(body.offsets, motion.positions.shape).copy()
    pos[:, 0] = blender.positions[:, 0] * 1.2  # the hips ride higher on longer legs
    out["Blender names and proportions, metres"] = Motion(body, blender.rotations, pos, motion.fps)
    rng = np.random.default_rng(seed)
    rolled = quat.identity((J,))
    for k in range(J):
        kids = sk.children(k)
        along = sk.offsets[kids[0]] if kids else sk.offsets[k]
        rolled[k] = quat.from_angle_axis(rng.uniform(-np.pi, np.pi), along / np.linalg.norm(along))
    out["joint frames rolled about their bones"] = with_rest_frames(motion, rolled)
    return out
