"""Which joint of a humanoid rig plays which body part, whatever the rig calls its joints.

The way Unity's humanoid set-up and the VRM humanoid do it: names first, read as words
(``CC_Base_L_Thigh``, ``mixamorig:LeftUpLeg``, ``UpperArm.L``, ``thigh_l`` are the left thigh),
then the joint tree and the pose for what the names leave open: the hips are where both legs
and the spine meet, the chest is where the arms branch off, left and right come from where
the feet point, and a limb is followed from its root along its longest branch. Twist, share,
IK, pole, end and other helper bones are recognised by name and left to follow their parents;
fingers and any other joint play no part and are carried through unchanged.
"""

from __future__ import annotations

import itertools
import re

import numpy as np

from styleerd.motion import quat
from styleerd.motion.kinematics import forward_kinematics
from styleerd.motion.skeleton import Skeleton

SIDES = {"l": "left", "left": "left", "r": "right", "right": "right"}
# Tokens that say nothing about the body part (prefixes of rig families).
NOISE = {"cc", "base", "mixamorig", "bip", "bip01", "j", "def", "b", "jnt", "sk", "bn", "bone", "c", "armature"}
# Tokens that mark a helper bone, which follows its parent and plays no part.
HELPER = {"twist", "share", "roll", "ik", "pole", "target", "ctrl", "control", "mch", "helper", "end", "nub"}
# Body part -> the words (tokens joined, side taken out) that name it, most telling first.
PART_NAMES = {
    "hips": ("hips", "pelvis", "hip"),
    "spine": ("spine", "spine1", "waist", "abdomen", "lowerback", "belly"),
    "chest": ("chest", "upperchest", "spine2", "torso", "thorax", "upperback", "spine3"),
    "neck": ("neck", "neck1"),
    "head": ("head",),
    "collar": ("clavicle", "collar", "collarbone"),
    "shoulder": ("upperarm", "arm", "uparm", "humerus"),
    "elbow": ("forearm", "lowerarm", "elbow", "radius", "lowarm"),
    "hand": ("hand", "wrist"),
    "hip": ("upleg", "upperleg", "thigh", "femur", "hip"),
    "knee": ("leg", "lowerleg", "knee", "calf", "shin", "tibia", "lowleg"),
    "foot": ("foot", "ankle"),
    "toe": ("toebase", "toe", "toes", "ball"),
}
CENTRE = ("hips", "spine", "chest", "neck", "head")
LIMBS = {
    "arm": ("collar", "shoulder", "elbow", "hand"),
    "leg": ("hip", "knee", "foot", "toe"),
}
REQUIRED = (
    "hips",
    "chest",
    "head",
    "left_shoulder",
    "left_elbow",
    "left_hand",
    "right_shoulder",
    "right_elbow",
    "right_hand",
    "left_hip",
    "left_knee",
    "left_foot",
    "right_hip",
    "right_knee",
    "right_foot",
)
OPTIONAL = ("spine", "neck", "left_collar", "right_collar", "left_toe", "right_toe")


def tokens(name: str) -> list[str]:
    """A joint name as lower-case words: 'mixamorig:LeftUpLeg' -> ['left', 'up', 'leg'],
    'CC_Base_L_Thigh' -> ['cc', 'base', 'l', 'thigh'], 'spine.001' -> ['spine', '1']."""
    bare = re.split(r"[:|]", name)[-1]
    words = re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+|\d+", bare)
    return [(w.lstrip("0") or "0") if w.isdigit() else w.lower() for w in words]


def side_and_stem(name: str) -> tuple[str | None, str]:
    """('left' | 'right' | None, the name's other telling words joined): 'CC_Base_L_Thigh' ->
    ('left', 'thigh'), 'UpperArm.L' -> ('left', 'upperarm'), 'Spine01' -> (None, 'spine1')."""
    words = [w for w in tokens(name) if w not in NOISE]
    sides = {SIDES[w] for w in words if w in SIDES}
    side = sides.pop() if len(sides) == 1 else None
    return side, "".join(w for w in words if w not in SIDES)


def helpers(skeleton: Skeleton) -> np.ndarray:
    """``[J]`` bool: helper bones (twist, share, IK, pole, end ...) whose whole subtree is
    helpers, so nothing that plays a part hangs below them."""
    named = np.array([bool(HELPER & set(tokens(n))) for n in skeleton.names])
    out = named.copy()
    for j in range(skeleton.n_joints - 1, 0, -1):  # children come after their parents
        if not out[j]:
            out[skeleton.parents[j]] = False
    return out


def pose_positions(skeleton: Skeleton, rotations: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations ``[J, 4]`` and positions ``[J, 3]`` of one pose (local rotations
    ``[J, 4]``; None: the rest pose, every rotation zero) with the rest offsets as translations."""
    rot = quat.identity((skeleton.n_joints,)) if rotations is None else quat.normalize(np.asarray(rotations, float))
    return forward_kinematics(rot, skeleton.offsets.copy(), skeleton.parents)


def ancestors(skeleton: Skeleton, j: int) -> list[int]:
    """``j`` and its ancestors, ``j`` first."""
    out = []
    while j >= 0:
        out.append(j)
        j = int(skeleton.parents[j])
    return out


def between(skeleton: Skeleton, ancestor: int, joint: int) -> list[int] | None:
    """Joints strictly between ``ancestor`` and ``joint`` (root side first); None if
    ``ancestor`` is not an ancestor of ``joint``."""
    up = ancestors(skeleton, joint)[1:]
    return up[: up.index(ancestor)][::-1] if ancestor in up else None


def children_lists(skeleton: Skeleton) -> list[list[int]]:
    """Each joint's children, in one pass (``Skeleton.children`` is one search per joint)."""
    out: list[list[int]] = [[] for _ in range(skeleton.n_joints)]
    for j in range(1, skeleton.n_joints):
        out[int(skeleton.parents[j])].append(j)
    return out


def subtree(children: list[list[int]], j: int) -> list[int]:
    """``j`` and every joint below it."""
    out, stack = [], [j]
    while stack:
        k = stack.pop()
        out.append(k)
        stack.extend(children[k])
    return out


def common_ancestor(skeleton: Skeleton, *joints: int) -> int:
    """The deepest joint that is an ancestor of (or one of) all ``joints``."""
    shared = set(ancestors(skeleton, joints[0]))
    for j in joints[1:]:
        shared &= set(ancestors(skeleton, j))
    return next(j for j in ancestors(skeleton, joints[0]) if j in shared)


def _named(skeleton: Skeleton, usable: np.ndarray) -> dict[str, int]:
    """Parts found by name: for each part the joint whose name is its most telling word, the
    one nearest the root among equals. 'Shoulder' alone is the collar on rigs that name the
    upper arm otherwise (Mixamo, VRM), the upper arm on rigs that name the collar (CMU, 100STYLE)."""
    found: dict[str, tuple[int, int]] = {}  # part -> (rank, joint)
    shoulders: dict[str, int] = {}
    for j, name in enumerate(skeleton.names):
        if not usable[j]:
            continue
        side, stem = side_and_stem(name)
        for base, words in PART_NAMES.items():
            centre = base in CENTRE
            if stem in words and (side is None) == centre:
                part = base if centre else f"{side}_{base}"
                if part not in found or words.index(stem) < found[part][0]:
                    found[part] = (words.index(stem), j)
        if stem == "shoulder" and side is not None and side not in shoulders:
            shoulders[side] = j
    parts = {p: j for p, (_, j) in found.items()}
    for side, j in shoulders.items():
        role = f"{side}_shoulder" if f"{side}_collar" in parts else f"{side}_collar"
        parts.setdefault(role, j)
    return parts


def _main_child(children: list[list[int]], j: int, usable: np.ndarray, P: np.ndarray) -> int | None:
    """The child of ``j`` that its limb goes on through: the usable child with the farthest-
    reaching subtree (fingers and twist bones branch off, the limb goes on)."""
    best, reach = None, -1.0
    for c in children[j]:
        if not usable[c]:
            continue
        sub = [k for k in subtree(children, c) if usable[k]]
        r = float(np.linalg.norm(P[sub] - P[j], axis=-1).max())
        if r > reach:
            best, reach = c, r
    return best


def _walk_down(children: list[list[int]], start: int, usable: np.ndarray, P: np.ndarray, eps: float) -> list[int]:
    """The joints below ``start`` along its main branch, skipping any at the same spot as the
    joint kept before them (a hand's finger-base joint: the hand is what turns the fingers)."""
    out, j = [], start
    while (c := _main_child(children, j, usable, P)) is not None:
        if np.linalg.norm(P[c] - P[out[-1] if out else start]) > eps:
            out.append(c)
        j = c
    return out


def _filled(skeleton: Skeleton, parts: dict[str, int], usable: np.ndarray, P: np.ndarray) -> dict[str, int]:
    """``parts`` with what the tree says where names were silent: the chest where the arms
    branch, spine and neck between their neighbours, a limb's lower parts along its main branch
    from the part above them."""
    parts = dict(parts)
    children = children_lists(skeleton)
    eps = 1e-3 * max(float(np.ptp(P, axis=0).max()), 1e-9)
    arms = [parts.get(f"{s}_collar", parts.get(f"{s}_shoulder")) for s in ("left", "right")]
    if None not in arms:  # the chest is where the arms branch off, whatever is called so
        parts["chest"] = common_ancestor(skeleton, *arms)
    if all(p in parts for p in ("left_hip", "right_hip", "chest")):  # and the hips where legs and spine meet
        parts["hips"] = common_ancestor(skeleton, parts["left_hip"], parts["right_hip"], parts["chest"])
    for part, (above, below) in {"spine": ("hips", "chest"), "neck": ("chest", "head")}.items():
        if part not in parts and above in parts and below in parts:
            inside = between(skeleton, parts[above], parts[below]) or []
            if inside:
                parts[part] = inside[(len(inside) - 1) // 2 if part == "spine" else 0]
    for side in ("left", "right"):
        for chain in LIMBS.values():
            for k, part in enumerate(chain[:-1]):
                key = f"{side}_{part}"
                if key not in parts:
                    continue
                below = [p for p in chain[k + 1 :] if f"{side}_{p}" not in parts and p != "toe"]
                if not below or any(f"{side}_{p}" in parts for p in chain[k + 1 :] if p != "toe"):
                    continue
                down = _walk_down(children, parts[key], usable, P, eps)
                for p, j in zip(below, down):
                    parts[f"{side}_{p}"] = j
    for side in ("left", "right"):
        for mid, (a, b) in {"knee": ("hip", "foot"), "elbow": ("shoulder", "hand")}.items():
            key = f"{side}_{mid}"
            if key not in parts and f"{side}_{a}" in parts and f"{side}_{b}" in parts:
                inside = between(skeleton, parts[f"{side}_{a}"], parts[f"{side}_{b}"]) or []
                if inside:
                    parts[key] = inside[len(inside) // 2]
    return parts


def _by_shape(skeleton: Skeleton, P: np.ndarray, usable: np.ndarray, parts: dict[str, int]) -> None:
    """Every part from the tree and the pose alone (nameless or numbered joints), into
    ``parts`` as they are found: feet are the two groups of low tips, the hips where they meet
    the spine, the arms the two branches off the spine reaching farthest to either side. Raises
    ValueError saying what is missing ("not a humanoid: ..." where legs or spine are), with
    what was found before it left in ``parts``."""
    S = skeleton
    children = children_lists(S)
    leaves = [j for j in range(S.n_joints) if usable[j] and not any(usable[c] for c in children[j])]
    y = P[:, 1]
    floor, top = float(y[usable].min()), float(y[usable].max())
    height = top - floor
    if height <= 0:
        raise ValueError("not a humanoid: the joints have no height (is the rig lying down?)")
    low = [j for j in leaves if y[j] < floor + 0.12 * height]
    groups: list[list[int]] = []
    for j in low:  # tips whose common joint is near the floor belong to one foot
        for g in groups:
            if y[common_ancestor(S, j, g[0])] < floor + 0.3 * height:
                g.append(j)
                break
        else:
            groups.append([j])
    if len(groups) != 2:
        raise ValueError(f"not a humanoid: {len(groups)} groups of joints at the floor (feet), not 2")
    tips = [min(g, key=lambda j: y[j]) for g in groups]
    head_tip = max(leaves, key=lambda j: y[j])
    hips = common_ancestor(S, *tips, head_tip)
    if not (y[head_tip] - y[hips] > 0.2 * height and y[hips] - floor > 0.3 * height):
        raise ValueError("not a humanoid: no spine going up from where the legs meet")
    parts["hips"] = hips
    legs = []
    eps = 1e-3 * height
    for tip in tips:
        path = between(S, hips, tip) + [tip]
        path = [j for k, j in enumerate(path) if k == len(path) - 1 or np.linalg.norm(P[path[k + 1]] - P[j]) > eps]
        foot = next(j for j in path if y[j] < floor + 0.15 * (y[hips] - floor))
        k = path.index(foot)
        if k < 2:
            raise ValueError("not a humanoid: a leg has no knee between the hips and the foot")
        knee = min(path[:k], key=lambda j: abs(y[j] - (y[foot] + 0.5 * (y[hips] - y[foot]))))
        upper = path[: path.index(knee)]
        if not upper:
            raise ValueError("not a humanoid: a leg has no thigh above its knee")
        hip = min(upper, key=lambda j: abs(y[j] - (2 * y[knee] - y[foot])))
        toe = path[k + 1] if k + 1 < len(path) else None
        legs.append((hip, knee, foot, toe))
    forward = sum((P[toe] - P[foot]) * np.array([1.0, 0.0, 1.0]) for _, _, foot, toe in legs if toe is not None)
    if np.linalg.norm(forward) < 1e-9:
        forward = np.array([0.0, 0.0, 1.0])  # no toes: the glTF and BVH convention, facing +Z
    left = np.cross(np.array([0.0, 1.0, 0.0]), forward)
    if (P[legs[0][0]] - P[legs[1][0]]) @ left < 0:
        legs.reverse()
    for side, leg in zip(("left", "right"), legs):
        parts |= {f"{side}_{p}": j for p, j in zip(LIMBS["leg"], leg) if j is not None}
    spine = between(S, hips, head_tip) + [head_tip]
    across = P[tips[0]] - P[tips[1]]
    across[1] = 0.0
    branches = []  # (root, joints, reach along the branch, side: mean offset across the body)
    along = np.zeros(S.n_joints)  # distance from the root along the bones
    for j in range(1, S.n_joints):
        along[j] = along[S.parents[j]] + np.linalg.norm(P[j] - P[S.parents[j]])
    for c in spine:
        for b in children[c]:
            if usable[b] and b not in spine:
                sub = [k for k in subtree(children, b) if usable[k]]
                reach = float(along[sub].max() - along[c])
                side = float(np.mean((P[sub] - P[hips]) @ across) / max(np.linalg.norm(across), 1e-12))
                branches.append((b, sub, reach, side))
    lefts, rights = [b for b in branches if b[3] > 0], [b for b in branches if b[3] < 0]
    if not lefts or not rights:
        raise ValueError("no arms branch off the spine to either side")
    one, other = max(lefts, key=lambda b: b[2]), max(rights, key=lambda b: b[2])
    if min(one[2], other[2]) < 0.15 * height:
        raise ValueError("no two arms reach out to either side of the spine")
    chest = common_ancestor(S, one[0], other[0])
    parts["chest"] = chest
    inside = between(S, hips, chest) or []
    if inside:
        parts["spine"] = inside[(len(inside) - 1) // 2]
    above = spine[spine.index(chest) + 1 :] if chest in spine else []
    heads = [j for j in above if "head" in tokens(S.names[j])]
    if not above:
        raise ValueError("nothing above the chest (no head)")
    parts["head"] = heads[0] if heads else max(above, key=lambda j: y[j])
    if above[0] != parts["head"]:
        parts["neck"] = above[0]
    arms = []
    for b, sub, _, _ in (one, other):
        tip = max(sub, key=lambda j: np.linalg.norm(P[j] - P[chest]))
        path = between(S, chest, tip) + [tip]
        forks = [j for j in path[1:] if sum(usable[c] for c in children[j]) >= 2]
        if forks:
            hand = forks[-1]
        else:
            last = np.linalg.norm(P[tip] - P[path[-2]]) if len(path) > 1 else 0.0
            before = np.linalg.norm(P[path[-2]] - P[path[-3]]) if len(path) > 2 else 0.0
            hand = path[-2] if last < 0.5 * before else tip
        kept = [hand]  # back from the hand, the deeper of two joints at one spot kept
        for j in reversed(path[: path.index(hand)]):
            if np.linalg.norm(P[j] - P[kept[-1]]) > eps:
                kept.append(j)
        if len(kept) < 3:
            raise ValueError("an arm has no elbow between the shoulder and the hand")
        arms.append((kept[3] if len(kept) > 3 else None, kept[2], kept[1], kept[0]))
    if (P[arms[0][3]] - P[arms[1][3]]) @ left < 0:
        arms.reverse()
    for side, arm in zip(("left", "right"), arms):
        parts |= {f"{side}_{p}": j for p, j in zip(LIMBS["arm"], arm) if j is not None}


def body_parts(skeleton: Skeleton, pose: np.ndarray | None = None) -> dict[str, int]:
    """Body part -> joint index: by name (words of any common rig family) and, where names say
    nothing, by the joint tree and the rest pose (or ``pose``, local rotations ``[J, 4]``, where
    the rest is no T- or A-pose). Parts that cannot be found are left out."""
    return _parts_and_problem(skeleton, pose)[0]


def not_humanoid(skeleton: Skeleton, pose: np.ndarray | None = None) -> str | None:
    """Why the joint tree cannot be read as a humanoid's ("not a humanoid: ..." where its legs
    and spine are not a human's; what it lacks otherwise), or None if it can."""
    return _parts_and_problem(skeleton, pose)[1]


def _parts_and_problem(skeleton: Skeleton, pose: np.ndarray | None) -> tuple[dict[str, int], str | None]:
    usable = ~helpers(skeleton)
    P = pose_positions(skeleton)[1]
    parts = _filled(skeleton, _named(skeleton, usable), usable, P)
    if all(p in parts for p in REQUIRED):
        return parts, None
    best: tuple[dict[str, int], str | None] = (parts, None)
    for positions in (P, None if pose is None else pose_positions(skeleton, pose)[1]):
        if positions is None:
            continue
        shaped: dict[str, int] = {}
        try:
            _by_shape(skeleton, positions, usable, shaped)
            problem = None
        except ValueError as e:
            problem = str(e)
        named = {p: j for p, j in parts.items() if p not in shaped and j not in shaped.values()}
        found = _filled(skeleton, shaped | named, usable, positions)
        if problem is None:
            return found, None
        if best[1] is None or len(found) > len(best[0]):
            best = (found, problem)
    return best


def problems(skeleton: Skeleton, parts: dict[str, int], P: np.ndarray | None = None, sides: bool = False) -> list[str]:
    """What is wrong with a part assignment: two parts on one joint; a chain out of order in
    the joint tree (a foot may hang elsewhere, as IK feet do, if it is below its knee); with
    ``sides``, a left part on a joint named for the right, or, on joints named for neither, a
    left collar or shoulder on the right of the hips where the pose stands upright. ``P``
    ``[J, 3]``: the pose's positions (by default the rest)."""
    P = pose_positions(skeleton)[1] if P is None else P
    names, out, seen = skeleton.names, [], {}

    def said(part: str) -> str:
        return f"{part.replace('_', ' ')} {names[parts[part]]!r}"

    for part, j in parts.items():
        if j in seen:
            out.append(f"{seen[j].replace('_', ' ')} and {part.replace('_', ' ')} are both mapped to {names[j]!r}")
        seen[j] = part
    chains = [CENTRE] + [tuple(f"{s}_{p}" for p in chain) for s in ("left", "right") for chain in LIMBS.values()]
    for chain in chains:
        present = [p for p in chain if p in parts]
        for a, b in itertools.pairwise(present):
            below = parts[a] in ancestors(skeleton, parts[b])[1:]
            if not below and not (b.endswith("_foot") and P[parts[b], 1] < P[parts[a], 1]):  # IK feet may
                out.append(f"{said(b)} does not hang below {said(a)} in the joint tree")
    if not sides:
        return out
    for part, j in parts.items():
        side = side_and_stem(names[j])[0]
        if part.split("_")[0] in SIDES.values() and side not in (None, part.split("_")[0]):
            out.append(f"{said(part)} is a {side}-side joint: the bone would cross the body")
    y = P[:, 1]
    need = ("head", "hips", "left_foot", "right_foot", "left_hip", "right_hip")
    if all(p in parts for p in need) and y[parts["head"]] > y[parts["hips"]] > max(
        y[parts["left_foot"]], y[parts["right_foot"]]
    ):
        across = P[parts["left_hip"]] - P[parts["right_hip"]]  # upright: the hips say where left is
        for part in ("collar", "shoulder"):
            left, right = parts.get(f"left_{part}"), parts.get(f"right_{part}")
            unnamed = left is not None and right is not None and side_and_stem(names[left])[0] is None
            if unnamed and (P[left] - P[right]) @ across <= 0:
                out.append(
                    f"{said('left_' + part)} is not left of {said('right_' + part)}: the bones would cross the body"
                )
    return out


def joint_tree(skeleton: Skeleton, limit: int = 120, notes: list[str] | None = None) -> str:
    """The joint tree as indented text (nameless glTF nodes are called ``node<N>``), each joint's
    line followed by its ``notes`` entry where given, at most ``limit`` lines."""
    depth = np.zeros(skeleton.n_joints, int)
    for j in range(1, skeleton.n_joints):
        depth[j] = depth[skeleton.parents[j]] + 1
    notes = notes or [""] * skeleton.n_joints
    lines = [f"  {'  ' * int(d)}{n}{note}" for n, d, note in zip(skeleton.names, depth, notes)]
    if len(lines) > limit:
        lines = lines[:limit] + [f"  ... and {len(lines) - limit} more"]
    return "\n".join(lines)


def eyes_above_head(skeleton: Skeleton) -> float:
    """How far above the head joint (the skull's base on most rigs) the eyes are, as the stylizer's
    ceiling for a hand a posture raises: a sixth of the rest pose's chain from the hips to the head
    (about 9 cm on a 170 cm body); 0 where either is not found."""
    parts = body_parts(skeleton)
    hips, head = parts.get("hips"), parts.get("head")
    if hips is None or head is None:
        return 0.0
    return skeleton.chain_length(hips, head) / 6.0


TWO_BONES = (LIMBS["arm"][1:], LIMBS["leg"][:3])  # shoulder, elbow, hand; hip, knee, foot


def limb_ends(skeleton: Skeleton) -> np.ndarray:
    """``[J]``: for the first joint of each two-bone limb of ``skeleton`` (shoulder, elbow, hand; hip,
    knee, foot: ``body_parts``, where they make one chain and the first joint has no other
    child), the limb's end joint; -1 elsewhere."""
    parts, parents = body_parts(skeleton), skeleton.parents
    out = np.full(skeleton.n_joints, -1, np.int64)
    for side, (first, middle, end) in itertools.product(("left", "right"), TWO_BONES):
        j, k, h = (parts.get(f"{side}_{role}") for role in (first, middle, end))
        if None not in (j, k, h) and parents[h] == k and parents[k] == j and (parents == j).sum() == 1:
            out[j] = h
    return out
