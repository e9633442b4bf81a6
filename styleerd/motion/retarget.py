"""Retargeting between humanoid skeletons: joint mapping, T-pose alignment, scale.

Both skeletons are brought into one shared reference pose, a T-pose (Y up, facing +Z, the
character's left along +X, arms out sideways, legs straight down, feet forward), whatever
their rest poses are (T-pose, A-pose, or a rest where every bone lies along its local X as in
Bandai-Namco's data). For each skeleton, ``tpose_rotations`` gives every joint's global
rotation in that T-pose with each bone's full frame fixed, its roll about itself included
(the roll is what a skinned body shows and positions do not): the frames are read off a pose in
which the bones have their natural roll (a T- or A-pose rest, the model's average pose, an
input's first frame; ``joint_map`` says which). A mapped joint then carries its global rotation
over relative to the T-pose:

    G_target[j](t) = G_source[s](t) * inv(T_source[s]) * T_target[j]

so every mapped bone points the same way and is rolled the same way on both skeletons at every
frame. The way back
inverts this exactly for mapped joints; joints with no counterpart keep their own local
rotation (fingers, extra spine or neck joints). Root translation is scaled by the ratio of leg
lengths. BVH world axes are assumed Y up (the convention of CMU, Xia, Mixamo and Bandai data).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

import numba as nb
import numpy as np

from styleerd.motion import quat
from styleerd.motion.humanoid import REQUIRED, ancestors, body_parts, joint_tree, not_humanoid, pose_positions, problems
from styleerd.motion.kinematics import forward_pose
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import Skeleton

# Body parts along the chains they form, root to tip.
CHAINS = (
    ("hips", "spine", "chest", "neck", "head"),
    ("chest", "left_collar", "left_shoulder", "left_elbow", "left_hand"),
    ("chest", "right_collar", "right_shoulder", "right_elbow", "right_hand"),
    ("hips", "left_hip", "left_knee", "left_foot", "left_toe"),
    ("hips", "right_hip", "right_knee", "right_foot", "right_toe"),
)

UP, DOWN, LEFT, RIGHT, FORWARD = np.eye(3)[1], -np.eye(3)[1], np.eye(3)[0], -np.eye(3)[0], np.eye(3)[2]
# Where each part's bone (towards the next part of its chain) points in the T-pose.
TPOSE_DIRECTIONS = {
    "hips": UP,
    "spine": UP,
    "chest": UP,
    "neck": UP,
    "left_collar": LEFT,
    "left_shoulder": LEFT,
    "left_elbow": LEFT,
    "right_collar": RIGHT,
    "right_shoulder": RIGHT,
    "right_elbow": RIGHT,
    "left_hip": DOWN,
    "left_knee": DOWN,
    "left_foot": FORWARD,
    "right_hip": DOWN,
    "right_knee": DOWN,
    "right_foot": FORWARD,
}
# Parts whose twist is fixed by a second, sideways direction (left minus right -> +X): the
# first part of each side's chain that does not sit on the part itself.
ACROSS = {
    "hips": (("left_hip",), ("right_hip",)),
    "chest": (("left_collar", "left_shoulder"), ("right_collar", "right_shoulder")),
}


BODY_PARTS = ("legs", "torso", "head", "arms")


def part_joints(skeleton: Skeleton) -> dict[str, np.ndarray]:
    """Joints per body part (``BODY_PARTS``): legs from the hip joints down, arms from the
    collars (or shoulders) out, head from the neck (or head) up, torso the rest (root, spine,
    chest). Every joint is in exactly one part."""
    parts = body_parts(skeleton)
    start = {
        "legs": ["left_hip", "right_hip"],
        "arms": [next(p for p in (f"{s}_collar", f"{s}_shoulder") if p in parts) for s in ("left", "right")],
        "head": ["neck" if "neck" in parts else "head"],
    }
    owner = np.full(skeleton.n_joints, -1)
    for j in range(skeleton.n_joints):  # parents come first: a joint is in its part, or in its parent's
        for k, part in enumerate(BODY_PARTS):
            if any(parts[role] == j for role in start.get(part, ())):
                owner[j] = k
        if owner[j] < 0:
            p = skeleton.parents[j]
            owner[j] = owner[p] if p >= 0 else BODY_PARTS.index("torso")
    return {part: np.nonzero(owner == k)[0] for k, part in enumerate(BODY_PARTS)}


class UnmappedSkeleton(ValueError):
    """Body parts no joint was found for: the message names them, shows the skeleton's joint tree and
    says how to name them; ``brief``, the same without the tree (for where the tree is shown already)."""

    ADVICE = (
        "Name them with --joint-map MAP.json, a JSON object of model joint -> your joint; --write-joint-map "
        "MAP.json writes one with the best guesses filled in"
    )

    def __init__(self, missing: str, skeleton: Skeleton):
        tree = joint_tree(skeleton)
        super().__init__(f"{missing} Its joints (nameless glTF nodes are called node<N>):\n{tree}\n{self.ADVICE}")
        self.brief = f"{missing} {self.ADVICE}"


@dataclass(frozen=True)
class JointMap:
    """How a source skeleton maps onto a target skeleton."""

    source: Skeleton
    target: Skeleton
    pairs: tuple[tuple[int, int], ...]  # (target joint, source joint), target order
    source_tpose: np.ndarray  # [Js, 4] global rotations of the source in the canonical T-pose
    target_tpose: np.ndarray  # [Jt, 4]
    scale: float  # target units per source unit (ratio of leg lengths)
    source_reference: str = "rest pose"  # which pose fixed the source's bone frames (see ``joint_map``)
    wants_first_frame: bool = False  # the source's rest is no T- or A-pose and no first frame was given

    @cached_property
    def joints(self) -> tuple[np.ndarray, np.ndarray]:
        """(target joints, source joints) of the pairs, as index arrays."""
        t_idx, s_idx = (np.array(x) for x in zip(*self.pairs))
        return t_idx, s_idx

    @cached_property
    def to_target_offsets(self) -> np.ndarray:
        """Per pair, what turns the source joint's global rotation into the target's."""
        t_idx, s_idx = self.joints
        return quat.mul(quat.inv(self.source_tpose[s_idx]), self.target_tpose[t_idx])

    @cached_property
    def to_source_offsets(self) -> np.ndarray:
        t_idx, s_idx = self.joints
        return quat.mul(quat.inv(self.target_tpose[t_idx]), self.source_tpose[s_idx])

    @cached_property
    def target_only(self) -> list[tuple[int, int, np.ndarray]]:
        """Target joints with no counterpart, parents first: (joint, parent, the T-pose rotation
        relative to the parent, or the global one for a root)."""
        mapped = set(self.joints[0].tolist())
        out = []
        for j in range(self.target.n_joints):
            if j not in mapped:
                p = int(self.target.parents[j])
                rel = quat.mul(quat.inv(self.target_tpose[p]), self.target_tpose[j]) if p >= 0 else self.target_tpose[j]
                out.append((j, p, rel))
        return out

    @cached_property
    def target_only_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``target_only`` as arrays: joints, parents, rotations ``[M, 4]``."""
        only = self.target_only
        return (
            np.array([j for j, _, _ in only], np.int64),
            np.array([p for _, p, _ in only], np.int64),
            np.array([r for _, _, r in only]).reshape(-1, 4),
        )

    @cached_property
    def unmapped_source(self) -> np.ndarray:
        """Source joints with no counterpart, parents first (skeletons list parents first)."""
        return np.array(sorted(set(range(self.source.n_joints)) - set(self.joints[1].tolist())), np.int64)

    def source_legs(self) -> list[list[int]]:
        """[[hip, knee, ankle] of the left leg, the same of the right], as source joints."""
        parts, source_of = body_parts(self.target), dict(self.pairs)
        return [[source_of[parts[f"{side}_{p}"]] for p in ("hip", "knee", "foot")] for side in ("left", "right")]

    def describe(self) -> str:
        """The mapping as text, a line per model joint, then the joints that keep their own motion."""
        lines = [f"  {self.target.names[t]:>14} <- {self.source.names[s]}" for t, s in self.pairs]
        unmapped = [n for j, n in enumerate(self.source.names) if j not in {s for _, s in self.pairs}]
        if unmapped:
            lines.append(f"  keep their own motion: {', '.join(unmapped)}")
        lines.append(f"  bone frames (direction and roll) of the input taken from: {self.source_reference}")
        return "\n".join(lines)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-300)


def _frame(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    """Orthonormal frame [3, 3] (columns) whose first axis is ``primary`` and whose second
    lies in the plane of ``primary`` and ``secondary``."""
    a = _unit(primary)
    b = _unit(secondary - a * np.dot(a, secondary))
    return np.stack([a, b, np.cross(a, b)], -1)


def _bone(P: np.ndarray, parts: dict[str, int], part: str, shared: set[str]) -> np.ndarray | None:
    """The part's bone in pose positions ``P``: to the next shared part of its chain that does
    not sit on the same spot (zero-length joints such as CMU's LHipJoint are skipped)."""
    eps = 1e-6 * max(1.0, float(np.abs(P - P[0]).max()))
    j = parts[part]
    tips = [parts[c] for c in _down_chain(part, shared) if np.linalg.norm(P[parts[c]] - P[j]) > eps]
    return P[tips[0]] - P[j] if tips else None


def _across(P: np.ndarray, parts: dict[str, int], part: str, shared: set[str]) -> np.ndarray | None:
    """Left minus right at the hips (the hip joints) or the chest (collars or shoulders)."""
    eps = 1e-6 * max(1.0, float(np.abs(P - P[0]).max()))
    sides = [
        [parts[p] for p in side if p in shared and np.linalg.norm(P[parts[p]] - P[parts[part]]) > eps]
        for side in ACROSS[part]
    ]
    return P[sides[0][0]] - P[sides[1][0]] if all(sides) else None


def _body_frames(P: np.ndarray, parts: dict[str, int], shared: set[str]) -> dict[str, np.ndarray] | None:
    """World rotation [3, 3] that turns the hips' and the chest's frames (up along the spine,
    left across) into the T-pose's, in pose positions ``P``; None if a bone is degenerate."""
    out = {}
    for part in ("hips", "chest"):
        up, across = _bone(P, parts, part, shared), _across(P, parts, part, shared)
        if up is None or across is None or np.linalg.norm(np.cross(_unit(up), _unit(across))) < 0.2:
            return None
        out[part] = _frame(UP, LEFT) @ _frame(up, across).T
    return out


# The elbow's hinge (upper arm x forearm, both pointing away from the body) in the T-pose with
# the palms down: a bending elbow brings the forearm forward.
HINGES = {"left_shoulder": np.cross(LEFT, FORWARD), "right_shoulder": np.cross(RIGHT, FORWARD)}


def _elbow_hinge(
    P: np.ndarray, parts: dict[str, int], shoulder: str, shared: set[str], min_degrees: float = 20.0
) -> np.ndarray | None:
    """The unit hinge axis of a bent elbow in pose positions ``P`` (None if the elbow is
    nearly straight there, as in a T-pose, so its plane says nothing)."""
    elbow = shoulder.replace("shoulder", "elbow")
    upper, fore = _bone(P, parts, shoulder, shared), (_bone(P, parts, elbow, shared) if elbow in shared else None)
    if upper is None or fore is None:
        return None
    axis = np.cross(_unit(upper), _unit(fore))
    return _unit(axis) if np.linalg.norm(axis) > np.sin(np.radians(min_degrees)) else None


def _roll_onto(v: np.ndarray, target: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The rotation [3, 3] about unit ``axis`` that turns ``v`` (perpendicular to it, or
    nearly) onto ``target``."""
    a = v - axis * np.dot(v, axis)
    angle = np.arctan2(np.dot(np.cross(a, target), axis), np.dot(a, target))
    return quat.to_xform(quat.from_angle_axis(angle, axis))


def tpose_rotations(
    skeleton: Skeleton, parts: dict[str, int], shared: set[str], pose: np.ndarray | None = None
) -> np.ndarray:
    """Global rotations ``[J, 4]`` of the skeleton in the canonical T-pose, each bone's full
    frame fixed (its direction and its roll about itself), found from a reference pose of the
    skeleton (local rotations ``pose [J, 4]``; None: the rest pose) in which the bones have
    their natural roll (knees and feet forward; palms down in a T-pose, towards the body with
    the arms down).

    The hips and the chest are turned so that their bone points up and their left-right line
    points left (+X). Down each chain, a part's bone is carried along with the turn of the part
    above it and then swung the shortest way onto its T-pose direction: a bent knee or elbow is
    straightened about its own hinge, so the roll follows the body's. A bone runs to the next
    part of its chain that both skeletons have (``shared``); parts without one (head, hands,
    toes) and joints that play no part keep their local rotation of the reference pose."""
    G, P = pose_positions(skeleton, pose)
    Gm = quat.to_xform(G)
    body = _body_frames(P, parts, shared)
    turn: dict[str, np.ndarray] = {}  # part -> world rotation [3, 3] from the reference pose to the T-pose
    for chain in CHAINS:
        for above, part in itertools.pairwise(chain):
            for p in (above, part) if above not in turn else (part,):
                if (
                    p in turn
                    or p not in shared
                    or p not in TPOSE_DIRECTIONS
                    or (bone := _bone(P, parts, p, shared)) is None
                ):
                    continue
                if p in ("hips", "chest") and body is not None:
                    turn[p] = body[p]
                    continue
                carried = next((turn[a] for a in reversed(chain[: chain.index(p)]) if a in turn), np.eye(3))
                turn[p] = quat.to_xform(quat.between(carried @ bone, TPOSE_DIRECTIONS[p])) @ carried
                if p.endswith("shoulder") and (hinge := _elbow_hinge(P, parts, p, shared)) is not None:
                    turn[p] = _roll_onto(turn[p] @ hinge, HINGES[p], TPOSE_DIRECTIONS[p]) @ turn[p]
    by_joint = {parts[p]: m for p, m in turn.items()}
    # a part hanging outside its chain (an IK foot under the root) goes with the part above it
    detached = {
        parts[b]: parts[a]
        for chain in CHAINS
        for a, b in itertools.pairwise([p for p in chain if p in shared])
        if parts[a] not in ancestors(skeleton, parts[b])
    }
    T = np.empty((skeleton.n_joints, 3, 3))
    for second in (False, True) if detached else (False,):  # the detached ones once the parts above them are known
        for j in range(skeleton.n_joints):  # parents first
            p = detached.get(j, int(skeleton.parents[j])) if second else int(skeleton.parents[j])
            if j in by_joint:
                T[j] = by_joint[j] @ Gm[j]
            else:  # the reference pose's local rotation, on the parent's T-pose frame
                T[j] = T[p] @ Gm[p].T @ Gm[j] if p >= 0 else Gm[j]
    return quat.from_xform(T)


def _down_chain(part: str, shared: set[str]) -> list[str]:
    """The shared parts below ``part`` on its main chain (for hips and chest: the spine;
    legs and arms branch off sideways)."""
    chain = next(c for c in CHAINS if part in c[:-1])
    return [p for p in chain[chain.index(part) + 1 :] if p in shared]


def natural_rest(skeleton: Skeleton, parts: dict[str, int], shared: set[str]) -> bool:
    """Whether the rest pose is a T-pose or an A-pose, so its bones' rolls are the natural
    ones: spine up, legs down, feet forward, arms out to the sides (up to 60 degrees down),
    hips and chest facing the same way. A rest such as Bandai-Namco's (every bone along its
    parent's X) or one with rolled joint frames is not."""
    _, P = pose_positions(skeleton)
    body = _body_frames(P, parts, shared)
    if body is None or quat.angle_between(quat.from_xform(body["hips"]), quat.from_xform(body["chest"])) > np.radians(
        30
    ):
        return False
    limits = {
        "spine": 40,
        "neck": 40,
        "left_hip": 40,
        "left_knee": 40,
        "right_hip": 40,
        "right_knee": 40,
        "left_foot": 60,
        "right_foot": 60,
        "left_shoulder": 60,
        "left_elbow": 60,
        "right_shoulder": 60,
        "right_elbow": 60,
    }
    for part, limit in limits.items():
        if part in shared and (bone := _bone(P, parts, part, shared)) is not None:
            aligned = body["hips" if part in ("spine",) or part.endswith(("hip", "knee", "foot")) else "chest"] @ bone
            if np.degrees(np.arccos(np.clip(np.dot(_unit(aligned), TPOSE_DIRECTIONS[part]), -1, 1))) > limit:
                return False
    up = body["hips"].T @ UP  # the rest's up in the world: BVH data is Y up
    return bool(np.dot(up, UP) > np.cos(np.radians(40)))


def same_rest_frames(target: Skeleton, source: Skeleton, pairs: tuple[tuple[int, int], ...]) -> bool:
    """Whether the source's rest pose is the target's up to scale (same bone directions from
    the hips for every mapped joint): the same rig, renamed or rescaled, whose joint frames are
    the target's and need no turning."""
    _, Pt = pose_positions(target)
    _, Ps = pose_positions(source)
    (t0, s0), rest = pairs[0], pairs[1:]
    for t, s in rest:
        a, b = Pt[t] - Pt[t0], Ps[s] - Ps[s0]
        if np.linalg.norm(a) < 1e-9 or np.linalg.norm(b) < 1e-9:
            continue
        if np.dot(_unit(a), _unit(b)) < np.cos(np.radians(3)):
            return False
    return True


def leg_length(skeleton: Skeleton, parts: dict[str, int]) -> float:
    """Hip to knee to foot of the left leg in the skeleton's rest pose, in its units."""
    _, P = pose_positions(skeleton)
    hip, knee, foot = (parts[f"left_{p}"] for p in ("hip", "knee", "foot"))
    return float(np.linalg.norm(P[knee] - P[hip]) + np.linalg.norm(P[foot] - P[knee]))


def _source_frames(
    source: Skeleton, parts: dict[str, int], shared: set[str], first_pose: np.ndarray | None
) -> tuple[np.ndarray, str, bool]:
    """The source's T-pose rotations, what they came from, and whether a first frame is still
    wanted: a T- or A-pose rest, else the first frame (a rest such as every bone along its
    parent's X, or joint frames rolled in the rig, says nothing about the bones' natural roll)."""
    if natural_rest(source, parts, shared):
        return tpose_rotations(source, parts, shared), "the rest pose (a T- or A-pose)", False
    if first_pose is None:
        return (
            tpose_rotations(source, parts, shared),
            "the rest pose, though it is no T- or A-pose (no first frame given yet): bone rolls may be off",
            True,
        )
    return (
        tpose_rotations(source, parts, shared, first_pose),
        "the first frame (the rest pose is no T- or A-pose)",
        False,
    )


def joint_map(
    target: Skeleton,
    source: Skeleton,
    explicit: dict[str, str] | None = None,
    target_pose: np.ndarray | None = None,
    source_pose: np.ndarray | None = None,
) -> JointMap:
    """Map ``source`` onto ``target`` automatically (names and topology); ``explicit``
    ({target joint: source joint}) overrides or completes it. Raises ValueError naming the
    body parts that cannot be found.

    Each skeleton's bone frames come from a pose in which its bones have their natural roll:
    its rest pose when that is a T-pose or an A-pose, otherwise the pose given (local rotations
    ``[J, 4]``: the model's average pose for the model, the first frame of the motion for an
    input), otherwise the rest pose as it is. A source whose rest pose is the target's up to
    scale (the same rig renamed) shares the target's frames exactly."""
    tp, sp = body_parts(target), body_parts(source, source_pose)
    if explicit:
        for t_name, s_name in explicit.items():
            if not s_name:
                continue  # left blank (as --write-joint-map leaves what it could not guess): found automatically
            if t_name not in target.names:
                raise ValueError(
                    f"joint map: {t_name!r} is not a joint of the model skeleton ({', '.join(target.names)})"
                )
            if s_name not in source.names:
                raise ValueError(f"joint map: {s_name!r} is not a joint of the input skeleton")
            t = target.index(t_name)
            part = next((p for p, j in tp.items() if j == t), None)
            if part is None:
                raise ValueError(f"joint map: model joint {t_name!r} plays no body part")
            sp[part] = source.index(s_name)
        P = None if source_pose is None else pose_positions(source, source_pose)[1]
        wrong = problems(source, sp, P, sides=True)
        if wrong:
            raise ValueError(f"joint map refused: {'; '.join(wrong)}")
    missing = [p for p in REQUIRED if p not in sp]
    if missing:
        why = not_humanoid(source, source_pose)
        if why and why.startswith("not a humanoid"):
            raise ValueError(f"{why}; only humanoid skeletons can be mapped onto the model")
        named = [
            f"{p.replace('_', ' ')} (model joint {target.names[tp[p]]})" if p in tp else p.replace("_", " ")
            for p in missing
        ]
        because = f" ({why})" if why else ""
        raise UnmappedSkeleton(f"cannot map the skeleton: no joint found for {', '.join(named)}{because}.", source)
    wrong = problems(source, sp)
    if wrong:
        raise ValueError(f"cannot map the skeleton: {'; '.join(wrong)}; name the joints with --joint-map")
    if tp["hips"] != 0:
        raise ValueError(f"the model skeleton's root {target.names[0]!r} is not its hips")
    shared = {p for p in tp if p in sp}
    pairs = tuple(sorted((tp[p], sp[p]) for p in shared))
    for name, length in (("input", leg_length(source, sp)), ("model", leg_length(target, tp))):
        if not np.isfinite(length) or length <= 1e-9:
            raise ValueError(f"the {name} skeleton's legs have no length (hip, knee and foot at one spot)")
    scale = leg_length(target, tp) / leg_length(source, sp)
    target_t = tpose_rotations(target, tp, shared, None if natural_rest(target, tp, shared) else target_pose)
    if same_rest_frames(target, source, pairs):
        source_t = quat.identity((source.n_joints,))  # only the mapped joints' are ever used: the target's frames
        t_idx, s_idx = (np.array(x) for x in zip(*pairs))
        source_t[s_idx] = target_t[t_idx]
        reference, wants_first_frame = "the model's own frames (the same rig)", False
    else:
        source_t, reference, wants_first_frame = _source_frames(source, sp, shared, source_pose)
    return JointMap(source, target, pairs, source_t, target_t, scale, reference, wants_first_frame)


def guessed_joint_map(target: Skeleton, source: Skeleton, source_pose: np.ndarray | None = None) -> dict[str, str]:
    """Every model joint that plays a body part -> the source joint found for it, or "" where
    none was: a joint map to edit and pass back (``--write-joint-map``)."""
    tp, sp = body_parts(target), body_parts(source, source_pose)
    return {target.names[j]: source.names[sp[p]] if p in sp else "" for p, j in tp.items()}


def to_target(motion: Motion, jm: JointMap) -> Motion:
    """The source motion on the target skeleton (target rest offsets, scaled root path)."""
    src, tgt = jm.source, jm.target
    t_idx, s_idx = jm.joints
    rot, pos = np.empty((motion.n_frames, tgt.n_joints, 4)), np.empty((motion.n_frames, tgt.n_joints, 3))
    _to_target_kernel(
        np.ascontiguousarray(motion.rotations),
        np.ascontiguousarray(motion.positions),
        src.parents,
        tgt.parents,
        t_idx,
        s_idx,
        jm.to_target_offsets,
        *jm.target_only_arrays,
        tgt.offsets,
        jm.scale,
        rot,
        pos,
    )
    return Motion(tgt, rot, pos, motion.fps)


@nb.njit(cache=True)
def _to_target_kernel(
    rot,
    pos,
    s_parents,
    t_parents,
    t_idx,
    s_idx,
    offsets,
    only_joint,
    only_parent,
    only_rel,
    t_offsets,
    scale,
    out_rot,
    out_pos,
):
    """Per frame: source FK; mapped target joints' globals = source global x offset; the others
    their T-pose relation to their parent (parents first); then local rotations; rest offsets
    with the scaled root path (pairs are sorted by target joint; the hips, joint 0, are mapped)."""
    g_rot, g_pos, glob = np.empty((rot.shape[1], 4)), np.empty((rot.shape[1], 3)), np.empty((out_rot.shape[1], 4))
    for n in range(rot.shape[0]):
        forward_pose(rot[n], pos[n], s_parents, g_rot, g_pos)
        for i in range(len(t_idx)):
            _mul_into(glob, t_idx[i], g_rot[s_idx[i]], offsets[i])
        for m in range(len(only_joint)):
            _below_parent(glob, only_joint[m], only_parent[m], only_rel[m])
        _local_pose(glob, t_parents, out_rot[n], False)
        out_pos[n] = t_offsets
        for k in range(3):
            out_pos[n, 0, k] = g_pos[s_idx[0], k] * scale


@nb.njit(cache=True)
def _mul_into(glob, j, a, b):
    """``glob[j] = a b`` (quaternions ``[4]``)."""
    glob[j, 0], glob[j, 1], glob[j, 2], glob[j, 3] = quat.mul_scalars(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])


@nb.njit(cache=True)
def _below_parent(glob, j, p, local):
    """Joint j's global rotation from its parent p's (already set) and its ``local`` one."""
    if p < 0:
        glob[j] = local
    else:
        _mul_into(glob, j, glob[p], local)


@nb.njit(cache=True)
def _local_pose(glob, parents, out, unit):
    """Local rotations of one pose's global ones (``unit``: normalised)."""
    for j in range(glob.shape[0]):
        p = parents[j]
        if p < 0:
            w, x, y, z = glob[j, 0], glob[j, 1], glob[j, 2], glob[j, 3]
        else:
            w, x, y, z = quat.mul_scalars(
                glob[p, 0], -glob[p, 1], -glob[p, 2], -glob[p, 3], glob[j, 0], glob[j, 1], glob[j, 2], glob[j, 3]
            )
        norm = max(np.sqrt(w * w + x * x + y * y + z * z), 1e-12) if unit else 1.0
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = w / norm, x / norm, y / norm, z / norm


def to_source(target_motion: Motion, jm: JointMap, source_motion: Motion) -> Motion:
    """Put a target-skeleton motion back on the source skeleton: mapped joints take its
    global rotations, every other joint keeps ``source_motion``'s local rotation, and all
    translations (the root path included) are ``source_motion``'s."""
    src, tgt = jm.source, jm.target
    t_idx, s_idx = jm.joints
    rot = np.empty((target_motion.n_frames, src.n_joints, 4))
    _to_source_kernel(
        np.ascontiguousarray(target_motion.rotations),
        np.ascontiguousarray(target_motion.positions),
        tgt.parents,
        src.parents,
        t_idx,
        s_idx,
        jm.to_source_offsets,
        jm.unmapped_source,
        np.ascontiguousarray(source_motion.rotations),
        rot,
    )
    return Motion(src, rot, source_motion.positions.copy(), target_motion.fps, source_motion.euler_hint)


@nb.njit(cache=True)
def _to_source_kernel(rot, pos, t_parents, s_parents, t_idx, s_idx, offsets, unmapped, source_rot, out_rot):
    g_rot, g_pos, glob = np.empty((rot.shape[1], 4)), np.empty((rot.shape[1], 3)), np.empty((out_rot.shape[1], 4))
    for n in range(rot.shape[0]):
        forward_pose(rot[n], pos[n], t_parents, g_rot, g_pos)
        for i in range(len(t_idx)):
            _mul_into(glob, s_idx[i], g_rot[t_idx[i]], offsets[i])
        for s in unmapped:
            _below_parent(glob, s, s_parents[s], source_rot[n, s])
        _local_pose(glob, s_parents, out_rot[n], True)
