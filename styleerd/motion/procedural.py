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
    guard: bool = False,
) -> Motion:
    """A plain, neutral walk along a gentle left curve: legs swing from the hips, knees bend in
    the swing phase, arms swing against the legs, the pelvis bobs, sways and twists. With ``guard``
    the arms are held instead in a boxer's guard, the fists at the chin."""
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
        if guard:  # upper arms down, forward and out; forearms up, in and forward: the fists before the chin
            rest, bob = np.array([sign, 0.0, 0.0]), 0.05 * swing[:, None] * [0.0, 0.0, 1.0]
            upper = quat.between(rest, np.array([0.3 * sign, -0.6, 0.6]) + bob)
            rot[:, j(f"{side}Arm")] = upper
            rot[:, j(f"{side}ForeArm")] = quat.mul(
                quat.inv(upper), quat.between(rest, np.array([-0.35 * sign, 0.9, 0.15]))
            )
        else:
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


def _mixamo_side(side: str) -> dict[str, str]:
    return {"L": "Left", "R": "Right"}[side]


def _family_specs() -> dict[str, list[tuple]]:
    """Rig families as (joint, parent, what it carries): a Mixamo joint of the demo skeleton
    (its motion), ("at", joint, offset) a helper or extra joint that follows that joint at a
    rest offset, or None a joint that never moves (an extra root)."""
    fam: dict[str, list[tuple]] = {}

    def limbs(name, parent_of, extra=lambda s, side: []):
        out = []
        for s in "LR":
            side = _mixamo_side(s)
            for mix, parent in parent_of.items():
                new = name(s, mix)
                if new is not None:
                    out.append((new, name(s, parent) if parent not in ("Spine2", "Hips") else parent, f"{side}{mix}"))
            out += extra(s, side)
        return out

    arm = {"Shoulder": "Spine2", "Arm": "Shoulder", "ForeArm": "Arm", "Hand": "ForeArm"}
    leg = {"UpLeg": "Hips", "Leg": "UpLeg", "Foot": "Leg", "ToeBase": "Foot"}
    cc = {
        "Shoulder": "Clavicle", "Arm": "Upperarm", "ForeArm": "Forearm", "Hand": "Hand",
        "UpLeg": "Thigh", "Leg": "Calf", "Foot": "Foot", "ToeBase": "ToeBase",
    }  # fmt: skip

    def cc_extra(s, side):
        x = 1.0 if s == "L" else -1.0
        return [
            (f"CC_Base_{s}_UpperarmTwist01", f"CC_Base_{s}_Upperarm", ("at", f"{side}Arm", (13.0 * x, 0, 0))),
            (f"CC_Base_{s}_ForearmTwist01", f"CC_Base_{s}_Forearm", ("at", f"{side}ForeArm", (12.0 * x, 0, 0))),
            (f"CC_Base_{s}_ElbowShareBone", f"CC_Base_{s}_Forearm", ("at", f"{side}ForeArm", (0.0, 0, 0))),
            (f"CC_Base_{s}_Mid1", f"CC_Base_{s}_Hand", ("at", f"{side}Hand", (9.0 * x, 0, 0))),
            (f"CC_Base_{s}_Mid2", f"CC_Base_{s}_Mid1", ("at", f"{side}Hand", (13.0 * x, 0, 0))),
            (f"CC_Base_{s}_Thumb1", f"CC_Base_{s}_Hand", ("at", f"{side}Hand", (3.0 * x, 0, 4))),
            (f"CC_Base_{s}_ThighTwist01", f"CC_Base_{s}_Thigh", ("at", f"{side}UpLeg", (0.0, -20, 0))),
            (f"CC_Base_{s}_CalfTwist01", f"CC_Base_{s}_Calf", ("at", f"{side}Leg", (0.0, -20, 0))),
            (f"CC_Base_{s}_KneeShareBone", f"CC_Base_{s}_Calf", ("at", f"{side}Leg", (0.0, 0, 0))),
            (f"CC_Base_{s}_ToeBaseShareBone", f"CC_Base_{s}_Foot", ("at", f"{side}Foot", (0.0, -5, 10))),
            (f"CC_Base_{s}_BigToe1", f"CC_Base_{s}_ToeBase", ("at", f"{side}ToeBase", (-2.0 * x, 0, 4))),
            (f"CC_Base_{s}_PinkyToe1", f"CC_Base_{s}_ToeBase", ("at", f"{side}ToeBase", (3.0 * x, 0, 3))),
        ]

    def cc_name(s, mix):
        return f"CC_Base_{s}_{cc[mix]}"

    fam["Character Creator (CC_Base_, twist and share bones, RL_BoneRoot)"] = (
        [
            ("RL_BoneRoot", None, None),
            ("CC_Base_Hip", "RL_BoneRoot", "Hips"),
            ("CC_Base_Pelvis", "CC_Base_Hip", ("at", "Hips", (0.0, 0, 0))),
            ("CC_Base_Waist", "CC_Base_Hip", "Spine"),
            ("CC_Base_Spine01", "CC_Base_Waist", "Spine1"),
            ("CC_Base_Spine02", "CC_Base_Spine01", "Spine2"),
            ("CC_Base_NeckTwist01", "CC_Base_Spine02", "Neck"),
            ("CC_Base_NeckTwist02", "CC_Base_NeckTwist01", ("at", "Neck", (0.0, 5, 0))),
            ("CC_Base_Head", "CC_Base_NeckTwist02", "Head"),
            ("CC_Base_L_Eye", "CC_Base_Head", ("at", "Head", (3.0, 14, 8))),
            ("CC_Base_R_Eye", "CC_Base_Head", ("at", "Head", (-3.0, 14, 8))),
        ]
        + [
            (n, "CC_Base_Pelvis" if p == "CC_Base_Hips" or p == "Hips" else p, c)
            for n, p, c in limbs(lambda s, m: cc_name(s, m), leg, lambda s, side: [])
        ]
        + [(n, "CC_Base_Spine02" if p == "Spine2" else p, c) for n, p, c in limbs(cc_name, arm, cc_extra)]
    )
    asf = {"Shoulder": "Collar", "Arm": "Shoulder", "ForeArm": "Elbow", "Hand": "Wrist",
           "UpLeg": "Hip", "Leg": "Knee", "Foot": "Ankle", "ToeBase": "Toe"}  # fmt: skip

    def asf_extra(s, side):
        x = 1.0 if s == "L" else -1.0
        return [
            (f"{s.lower()}hand", f"{side}Wrist", ("at", f"{side}Hand", (6.0 * x, 0, 0))),
            (f"{s}Fingers", f"{s.lower()}hand", ("at", f"{side}Hand", (12.0 * x, 0, 0))),
            (f"{s}Thumb", f"{side}Wrist", ("at", f"{side}Hand", (3.0 * x, 0, 5))),
        ]

    def asf_name(s, mix):
        return f"{_mixamo_side(s)}{asf[mix]}"

    fam["CMU ASF names (LHipJoint, LeftHip, LeftAnkle, LeftCollar)"] = (
        [
            ("Hips", None, "Hips"),
            ("lowerback", "Hips", "Spine"),
            ("Chest", "lowerback", "Spine1"),
            ("Chest2", "Chest", "Spine2"),
            ("lowerneck", "Chest2", ("at", "Spine2", (0.0, 12, 0))),
            ("Neck", "lowerneck", "Neck"),
            ("Head", "Neck", "Head"),
            ("LHipJoint", "Hips", ("at", "Hips", (0.0, 0, 0))),
            ("RHipJoint", "Hips", ("at", "Hips", (0.0, 0, 0))),
        ]
        + [(n, f"{n[0]}HipJoint" if p == "Hips" else p, c) for n, p, c in limbs(asf_name, leg)]
        + [(n, "Chest2" if p == "Spine2" else p, c) for n, p, c in limbs(asf_name, arm, asf_extra)]
    )
    style100 = {"Shoulder": "Collar", "Arm": "Shoulder", "ForeArm": "Elbow", "Hand": "Wrist",
                "UpLeg": "Hip", "Leg": "Knee", "Foot": "Ankle", "ToeBase": "Toe"}  # fmt: skip
    fam["100STYLE (LeftCollar, LeftShoulder, LeftElbow, LeftWrist, no Spine2)"] = [
        ("Hips", None, "Hips"),
        ("Chest", "Hips", "Spine"),
        ("Chest3", "Chest", "Spine2"),
        ("Neck", "Chest3", "Neck"),
        ("Head", "Neck", "Head"),
    ] + [
        (n, "Chest3" if p == "Spine2" else p, c)
        for n, p, c in limbs(lambda s, m: f"{_mixamo_side(s)}{style100[m]}", {**arm, **leg})
    ]
    robot = {"Shoulder": "Shoulder", "Arm": "UpperArm", "ForeArm": "LowerArm", "UpLeg": "UpperLeg", "Leg": "LowerLeg"}

    def robot_extra(s, side):
        x = 1.0 if s == "L" else -1.0
        return [(f"Palm{k}.{s}", f"LowerArm.{s}", ("at", f"{side}Hand", (0.0, 0, 0))) for k in (1, 2, 3)] + [
            (f"Middle1.{s}", f"Palm2.{s}", ("at", f"{side}Hand", (8.0 * x, 0, 0))),
            (f"Index1.{s}", f"Palm1.{s}", ("at", f"{side}Hand", (7.0 * x, 0, 2))),
            (f"Ring1.{s}", f"Palm3.{s}", ("at", f"{side}Hand", (7.0 * x, 0, -2))),
            (f"Foot.{s}", "Bone", f"{side}Foot"),  # IK foot: under the root, not the leg
            (f"PoleTarget.{s}", "Bone", ("at", "Hips", (9.0 * x, -40, 60))),
        ]

    fam["Blender names, IK feet outside the legs, no toes, no hand joint (RobotExpressive-like)"] = [
        ("Bone", None, None),
        ("Body", "Bone", "Hips"),
        ("Hips", "Body", ("at", "Hips", (0.0, 2, 0))),
        ("Abdomen", "Hips", "Spine"),
        ("Torso", "Abdomen", "Spine2"),
        ("Neck", "Torso", "Neck"),
        ("Head", "Neck", "Head"),
    ] + [
        (n, {"Spine2": "Torso", "Hips": "Body"}.get(p, p), c)
        for n, p, c in limbs(
            lambda s, m: f"{robot[m]}.{s}" if m in robot else None,
            {"Shoulder": "Spine2", "Arm": "Shoulder", "ForeArm": "Arm", "UpLeg": "Hips", "Leg": "UpLeg"},
            robot_extra,
        )
    ]
    vroid = {"Shoulder": "Shoulder", "Arm": "UpperArm", "ForeArm": "LowerArm", "Hand": "Hand",
             "UpLeg": "UpperLeg", "Leg": "LowerLeg", "Foot": "Foot", "ToeBase": "ToeBase"}  # fmt: skip
    fam["VRoid (J_Bip_C_Hips, J_Bip_L_UpperArm, upper chest)"] = [
        ("Root", None, None),
        ("J_Bip_C_Hips", "Root", "Hips"),
        ("J_Bip_C_Spine", "J_Bip_C_Hips", "Spine"),
        ("J_Bip_C_Chest", "J_Bip_C_Spine", "Spine1"),
        ("J_Bip_C_UpperChest", "J_Bip_C_Chest", "Spine2"),
        ("J_Bip_C_Neck", "J_Bip_C_UpperChest", "Neck"),
        ("J_Bip_C_Head", "J_Bip_C_Neck", "Head"),
    ] + [
        (n, {"Spine2": "J_Bip_C_UpperChest", "Hips": "J_Bip_C_Hips"}.get(p, p), c)
        for n, p, c in limbs(lambda s, m: f"J_Bip_{s}_{vroid[m]}", {**arm, **leg})
    ]
    unreal = {"Shoulder": "clavicle", "Arm": "upperarm", "ForeArm": "lowerarm", "Hand": "hand",
              "UpLeg": "thigh", "Leg": "calf", "Foot": "foot", "ToeBase": "ball"}  # fmt: skip

    def unreal_extra(s, side):
        x = 1.0 if s == "L" else -1.0
        s = s.lower()
        return [
            (f"upperarm_twist_01_{s}", f"upperarm_{s}", ("at", f"{side}Arm", (13.0 * x, 0, 0))),
            (f"lowerarm_twist_01_{s}", f"lowerarm_{s}", ("at", f"{side}ForeArm", (12.0 * x, 0, 0))),
            (f"thigh_twist_01_{s}", f"thigh_{s}", ("at", f"{side}UpLeg", (0.0, -20, 0))),
            (f"ik_foot_{s}", "ik_foot_root", ("at", f"{side}Foot", (0.0, 0, 0))),
        ]

    fam["Unreal mannequin (pelvis, spine_01, thigh_l, ball_l, twist and IK bones)"] = [
        ("root", None, None),
        ("ik_foot_root", "root", ("at", "Hips", (0.0, -95, 0))),
        ("pelvis", "root", "Hips"),
        ("spine_01", "pelvis", "Spine"),
        ("spine_02", "spine_01", "Spine1"),
        ("spine_03", "spine_02", "Spine2"),
        ("neck_01", "spine_03", "Neck"),
        ("head", "neck_01", "Head"),
    ] + [
        (n, {"Spine2": "spine_03", "Hips": "pelvis"}.get(p, p), c)
        for n, p, c in limbs(lambda s, m: f"{unreal[m]}_{s.lower()}", {**arm, **leg}, unreal_extra)
    ]
    numbered = {"Shoulder": "arm_joint_{s}__4_", "Arm": "arm_joint_{s}__3_", "ForeArm": "arm_joint_{s}__2_",
                "Hand": "arm_joint_{s}__1_", "UpLeg": "leg_joint_{s}_1", "Leg": "leg_joint_{s}_2",
                "Foot": "leg_joint_{s}_3", "ToeBase": "leg_joint_{s}_5"}  # fmt: skip
    fam["numbered joints (CesiumMan-like: Skeleton_torso_joint_1, leg_joint_L_1)"] = [
        ("Skeleton_torso_joint_1", None, "Hips"),
        ("Skeleton_torso_joint_2", "Skeleton_torso_joint_1", "Spine"),
        ("torso_joint_3", "Skeleton_torso_joint_2", "Spine2"),
        ("Skeleton_neck_joint_1", "torso_joint_3", "Neck"),
        ("Skeleton_neck_joint_2", "Skeleton_neck_joint_1", "Head"),
    ] + [
        (n, {"Spine2": "torso_joint_3", "Hips": "Skeleton_torso_joint_1"}.get(p, p), c)
        for n, p, c in limbs(lambda s, m: "Skeleton_" + numbered[m].format(s=s), {**arm, **leg})
    ]
    fam["Mixamo (mixamorig:), extra Armature root"] = [("Armature", None, None)] + [
        ("mixamorig:" + n, "mixamorig:" + p if p else "Armature", n) for n, p, _ in _JOINTS
    ]
    return fam


def _depth_first(spec: list[tuple]) -> list[tuple]:
    """The joints of a spec in depth-first order, children in the order listed (as BVH lists them)."""
    out: list[tuple] = []

    def visit(parent: str | None) -> None:
        for joint in spec:
            if joint[1] == parent:
                out.append(joint)
                visit(joint[0])

    visit(None)
    return out


def rig_families(motion: Motion | None = None) -> dict[str, tuple[Motion, dict[str, str]]]:
    """The demo walk (or ``motion`` on the demo skeleton) on generated rigs of the naming
    families and quirks users bring (twist, share, IK and helper bones, extra roots, no toes,
    no hand joint, numbered and nameless joints), each with the map {demo joint: the rig's
    joint carrying its motion}. Every joint is where the demo's is, turned as the demo's."""
    from styleerd.motion.kinematics import forward_kinematics

    motion = motion or walk()
    sk, T = motion.skeleton, motion.n_frames
    G, P = forward_kinematics(motion.rotations, motion.positions, sk.parents)
    rest = forward_kinematics(quat.identity((sk.n_joints,)), sk.offsets.copy(), sk.parents)[1]
    specs = _family_specs()
    numbered = specs["numbered joints (CesiumMan-like: Skeleton_torso_joint_1, leg_joint_L_1)"]
    order = np.random.default_rng(7).permutation(len(numbered))
    specs["nameless nodes (node<N>)"] = [
        (f"node{order[k]}", None if p is None else f"node{order[[n for n, _, _ in numbered].index(p)]}", c)
        for k, (_, p, c) in enumerate(numbered)
    ]
    out = {}
    for family, spec in specs.items():
        spec = _depth_first(spec)
        names = [n for n, _, _ in spec]
        parents = np.array([-1 if p is None else names.index(p) for _, p, _ in spec])
        g = np.empty((T, len(spec), 4))
        p = np.empty((T, len(spec), 3))
        p_rest = np.empty((len(spec), 3))
        for k, (_, _, carries) in enumerate(spec):
            if carries is None:
                g[:, k], p[:, k], p_rest[k] = quat.identity(), 0.0, 0.0
            elif isinstance(carries, str):
                j = sk.index(carries)
                g[:, k], p[:, k], p_rest[k] = G[:, j], P[:, j], rest[j]
            else:
                j, off = sk.index(carries[1]), np.array(carries[2], dtype=np.float64)
                g[:, k], p[:, k], p_rest[k] = G[:, j], P[:, j] + quat.mul_vec(G[:, j], off), rest[j] + off
        gp = np.where((parents >= 0)[None, :, None], g[:, np.maximum(parents, 0)], quat.identity((T, len(spec))))
        pp = np.where((parents >= 0)[None, :, None], p[:, np.maximum(parents, 0)], 0.0)
        local = quat.mul(quat.inv(gp), g)
        local_pos = quat.mul_vec(quat.inv(gp), p - pp)
        offsets = p_rest - np.where((parents >= 0)[:, None], p_rest[np.maximum(parents, 0)], 0.0)
        moves = (np.abs(local_pos - offsets).max(axis=0) > 1e-6).any(-1)
        moves[0] = True
        channels = tuple(POSITION_CHANNELS + _ROT if m else _ROT for m in moves)
        skeleton = Skeleton(tuple(names), parents, offsets, channels)
        pos = np.where(moves[None, :, None], local_pos, offsets[None])
        expected = {c: n for n, _, c in spec if isinstance(c, str)}
        out[family] = (Motion(skeleton, quat.normalize(local), pos, motion.fps), expected)
    return out
