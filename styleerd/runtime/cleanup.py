"""Online foot cleanup: where the input's foot is planted, pin the output's foot.

Contacts come from the input: a foot is planted while the input's ankle moves slower than
``contact_speed`` leg lengths per second (the features' causal rule), or while the input's body
(between the hips) stands still and its foot is flat on its floor (ankle and toe within
``floor_band`` leg lengths of the lowest they have been): a walk in place, as game libraries ship
them, whose planted feet move back under a still body as on a treadmill. Either only where the leg
can bear weight: its ankle at least ``leg_down`` leg lengths below its hip (a bow), or
``squat_down`` under an upright body (hips to head within 60 degrees of the world's up: a squat). A
kicker's foot slowing in the air, or a swimmer's, is no contact. A contact is read from the input
ankle's move into the frame, so when one begins the input's foot has stood still since the frame
before; the anchor is the output ankle's ground position on that frame (as it was given out), at the
input ankle's height (a style that bends the legs would otherwise plant feet in or above the input's
floor), so the output's foot stands from the same frame as the input's (anchored on the new frame,
the first move of every contact slid). While the contact lasts, two-bone IK (hip, knee) holds the
output ankle on the anchor moved as the input's ankle has moved since (on frames it moved faster
than a still foot: pinned where the input's foot is still, carried back where it walks in place);
when it ends, the target slides from there back to the raw ankle over ``release_frames`` frames, so
nothing pops. Where a planted foot's target is out of its leg's reach (a style that bends the body,
a heel rising far behind it), the pelvis drops (straight down, at most ``max_drop`` leg lengths, by
the translation of the first joint above the legs that has one: the root, or the hips under a still
reference node) until the leg reaches; it rises back at ``rise_speed`` leg lengths a second once the
feet no longer need it, so the body never pops (on a stream's first frame it starts where the legs
need it). Where the output's own legs hold its planted feet above their anchors (a style that bends
the knees: an elderly stance, an active performer's bounce on the spot), the pelvis drops too, until
the lower of them stands on its anchor; where they reach below them (a bouncing input taken to a
calm style), it rises as far, within as much and as long as the legs reach (``keep_bend``). The legs
keep the output's bend, where IK alone would bend or straighten them to the input's hip height and
carry the input's style over. A planted foot the output holds higher than the most drop is one it
swings (its own step), and IK alone brings it down.
The floor: no output ankle, and no toe (the ankle's first child), goes lower than the input's own
ankle and toe have been so far (their running minimum); an ankle that would is lifted by the same IK,
and a toe that would is raised by pitching the foot up about the ankle (lifting the ankle for a toe
bent a nearly straight leg's knee far forward, the shin tilting the toe down again as it rose).
Where the input's body (between the hips) moves farther in one frame than ``cut_speed`` leg lengths
a second allow (a cut: a rest pose before the take, a respawn), the stream starts afresh there, as
at its first frame: no foot is held where the body was before the jump.
Frame t uses frames <= t only. Works on any skeleton with named legs (BodyRoles).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from styleerd.motion import quat
from styleerd.motion.ik import limb_ik
from styleerd.motion.kinematics import forward_pose, forward_positions
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import body_parts
from styleerd.motion.skeleton import Skeleton

# a foot that can bear weight: its ankle LEG_DOWN leg lengths under its hip, or SQUAT_DOWN under a body
# whose up (hips to head) has a cosine of at least UPRIGHT with the world's (eval.actions measures so too)
LEG_DOWN, SQUAT_DOWN, UPRIGHT = 0.5, 0.2, 0.5


class FootLock:
    def __init__(
        self,
        skeleton: Skeleton,
        n_streams: int = 1,
        fps: float = 30.0,
        contact_speed: float = 0.25,
        floor_band: float = 0.05,
        release_frames: int = 4,
        legs: list[list[int]] | None = None,
        max_drop: float = 0.06,
        fall_speed: float = 0.5,
        rise_speed: float = 0.1,
        leg_down: float = LEG_DOWN,
        squat_down: float = SQUAT_DOWN,
        upright: float = UPRIGHT,
        keep_bend: bool = True,
        cut_speed: float = 25.0,
    ):
        """``legs``: [[hip, knee, ankle] of the left leg, the same of the right] (default: found
        by joint names and topology, as retargeting finds them)."""
        self.skeleton, self.fps = skeleton, fps
        parts = body_parts(skeleton)
        if legs is None:
            legs = [[parts[f"{side}_{p}"] for p in ("hip", "knee", "foot")] for side in ("left", "right")]
        self.legs = np.array(legs)
        self.head = parts.get("head", -1)  # -1: none found
        self.upright = upright  # the cosine of the body's up (hips to head) with the world's, at least
        self.keep_bend = keep_bend  # the pelvis also drops or rises to the output's own planted legs (above)
        self.across = (self.legs[0, 0], self.legs[1, 0])
        parents = skeleton.parents
        self.toes = np.array(
            [next(iter(skeleton.children(a)), -1) for _, _, a in self.legs], np.int64
        )  # -1: a foot without a toe joint
        # IK sets hip and knee rotations directly: the leg must be one hip-knee-ankle chain
        self.enabled = all(parents[k] == h and parents[a] == k for h, k, a in self.legs)
        P = forward_positions(quat.identity((skeleton.n_joints,)), skeleton.offsets, skeleton.parents)
        self.reach = np.array(
            [np.linalg.norm(P[k] - P[h]) + np.linalg.norm(P[a] - P[k]) for h, k, a in self.legs]
        )  # each leg's length, hip to ankle, straight
        leg = self.reach[0]
        self.max_speed, self.floor_band, self.cut_speed = contact_speed * leg, floor_band * leg, cut_speed * leg
        self.leg_down, self.squat_down = leg_down * leg, squat_down * leg
        above = [int(parents[self.legs[0, 0]])]  # the joint both thighs hang from, and those above it
        while above[-1] > 0:
            above.append(int(parents[above[-1]]))
        # the joint lowered: its translation must be written out (a BVH position channel); none, no drop
        self.lowered = next((j for j in reversed(above) if j >= 0 and skeleton.has_positions(j)), -1)
        max_drop = max_drop if self.lowered >= 0 else 0.0
        self.max_drop, self.fall, self.rise = max_drop * leg, fall_speed * leg / fps, rise_speed * leg / fps
        self.n, self.release_frames = n_streams, max(1, release_frames)
        self.previous = np.zeros((n_streams, 2, 3))  # input ankles of the last frame (once started)
        self.anchor = np.zeros((n_streams, 2, 3))  # where a planted foot is held (while planted)
        self.placed = np.zeros((n_streams, 2, 3))  # output ankles as the last frame gave them (once started)
        self.previous_body = np.zeros((n_streams, 3))  # the input's point between the hips at the last frame
        self.since_release = np.full((n_streams, 2), self.release_frames)  # frames since a contact ended
        self.planted = np.zeros((n_streams, 2), dtype=bool)
        self.started = np.zeros(n_streams, dtype=bool)
        self.floor = np.zeros((n_streams, 2, 2))  # per side, the lowest the input's ankle and toe have been
        self.drop = np.zeros(n_streams)  # how far the pelvis is lowered now (below zero: raised)

    def reset(self, streams=None) -> None:
        """Forget the past of some (default all) streams."""
        rows = slice(None) if streams is None else np.asarray(streams, dtype=int)
        self.since_release[rows], self.planted[rows], self.started[rows] = self.release_frames, False, False
        self.drop[rows] = 0.0

    def step(
        self,
        rotations: np.ndarray,
        positions: np.ndarray,
        input_rotations: np.ndarray,
        input_positions: np.ndarray,
        rows=None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Output frame ``rotations [N, J, 4]`` (local) with ``positions [N, J, 3]``, and the
        input frame it came from -> cleaned local rotations and positions (the root lowered or raised
        where the legs need it); of every stream, or of the streams ``rows`` only."""
        f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)
        out, out_pos = f64(rotations).copy(), f64(positions).copy()
        state = np.arange(self.n)[slice(None) if rows is None else np.asarray(rows, dtype=int)]
        _foot_lock_kernel(
            out_pos,
            f64(input_rotations),
            f64(input_positions),
            state,
            self.skeleton.parents,
            self.legs,
            self.toes,
            self.reach,
            int(self.lowered),
            float(self.max_drop),
            float(self.fall),
            float(self.rise),
            self.across[0],
            self.across[1],
            float(self.fps),
            float(self.max_speed),
            float(self.cut_speed),
            float(self.leg_down),
            float(self.squat_down),
            int(self.head),
            float(self.upright),
            float(self.floor_band),
            int(self.release_frames),
            bool(self.enabled),
            bool(self.keep_bend),
            self.previous,
            self.previous_body,
            self.anchor,
            self.placed,
            self.since_release,
            self.planted,
            self.started,
            self.floor,
            self.drop,
            out,
        )
        return out, out_pos


@nb.njit(cache=True)
def _foot_lock_kernel(
    positions,
    in_rot,
    in_pos,
    state,
    parents,
    legs,
    toes,
    reach,
    lowered,
    max_drop,
    fall,
    rise,
    across_l,
    across_r,
    fps,
    max_speed,
    cut_speed,
    leg_down,
    squat_down,
    head,
    upright,
    floor_band,
    release,
    enabled,
    keep_bend,
    previous,
    previous_body,
    anchor,
    placed,
    since_release,
    planted,
    started,
    floor,
    drop,
    out,
):
    """Per stream (row ``state[i]`` of the state arrays): contacts from the input's ankles and hips,
    anchors (carried by the input ankle's moves while planted) and release weights, the input's
    floor, the pelvis's drop, then IK of each leg with a weight and a lift (``out``: local
    rotations, and ``positions``: local positions whose root is lowered or raised, cleaned in place)."""
    J = out.shape[1]
    g_rot, g_pos = np.empty((J, 4)), np.empty((J, 3))
    hip_g, knee_g, target, left = np.empty(4), np.empty(4), np.empty(3), np.empty(3)
    weight, now, moved = np.empty(2), np.empty(2, np.bool_), np.empty((2, 3))
    for i in range(len(state)):
        r = state[i]
        forward_pose(in_rot[i], in_pos[i], parents, g_rot, g_pos)
        body = 0.5 * (g_pos[legs[0, 0]] + g_pos[legs[1, 0]])  # between the hips: a root may be a still reference node
        if started[r] and np.sqrt(np.sum((body - previous_body[r]) ** 2)) * fps > cut_speed:  # a cut: start afresh
            started[r], planted[r, 0], planted[r, 1], drop[r] = False, False, False, 0.0
            since_release[r, 0], since_release[r, 1] = release, release
        body_still = (
            np.sqrt((body[0] - previous_body[r, 0]) ** 2 + (body[2] - previous_body[r, 2]) ** 2) * fps < max_speed
            if started[r]
            else True
        )
        previous_body[r] = body
        standing = True  # not lying (a swimmer), bent over or upside down; a body without a head: upright
        if head >= 0:  # scalars: no array made per stream
            ux, uy, uz = g_pos[head, 0] - body[0], g_pos[head, 1] - body[1], g_pos[head, 2] - body[2]
            standing = uy >= upright * np.sqrt(ux * ux + uy * uy + uz * uz)
        for side in range(2):
            ankle = g_pos[legs[side, 2]].copy()
            before = previous[r, side].copy() if started[r] else ankle
            still = np.sqrt(np.sum((ankle - before) ** 2)) * fps < max_speed
            below = g_pos[legs[side, 0], 1] - ankle[1]  # how far the ankle is under its hip
            bears = below >= leg_down or (standing and below >= squat_down)  # a foot that can bear weight
            moved[side] = (ankle - before) * (0.0 if still else 1.0)
            previous[r, side] = ankle
            toe_y = g_pos[toes[side], 1] if toes[side] >= 0 else ankle[1]
            floor[r, side, 0] = min(floor[r, side, 0], ankle[1]) if started[r] else ankle[1]
            floor[r, side, 1] = min(floor[r, side, 1], toe_y) if started[r] else toe_y
            flat = ankle[1] - floor[r, side, 0] < floor_band and toe_y - floor[r, side, 1] < floor_band
            now[side] = bears and (still or (body_still and flat))
        fresh, started[r] = not started[r], True  # a first frame (or a cut's) has no drop to ease from
        forward_pose(out[i], positions[i], parents, g_rot, g_pos)
        for side in range(2):
            if now[side] and not planted[r, side]:  # a contact begins: held where it was, at the input's height
                anchor[r, side] = g_pos[legs[side, 2]] if fresh else placed[r, side]
                anchor[r, side, 1] = previous[r, side, 1]
            elif now[side]:  # planted: carried as the input's foot moves along its floor
                anchor[r, side] += moved[side]
            since = 0 if now[side] else (1 if planted[r, side] else min(since_release[r, side] + 1, release))
            planted[r, side], since_release[r, side] = now[side], since
            weight[side] = 1.0 if now[side] else 1.0 - since / release
        if not enabled:
            for side in range(2):
                placed[r, side] = g_pos[legs[side, 2]]
            continue
        need = 0.0  # the pelvis drop that lets each planted leg reach its target, nearly straight
        if keep_bend:  # and that puts the lower planted foot of the output's own legs on its anchor, their bend kept
            sink = np.inf
            for side in range(2):
                above = g_pos[legs[side, 2], 1] - anchor[r, side, 1]
                if weight[side] >= 1.0 and above <= max_drop:  # higher: a foot the output swings, not bends over
                    sink = min(sink, above)
            if sink < np.inf:
                need = sink  # below zero: the output's legs stand lower than the input's, and the pelvis rises
        for side in range(2):
            if weight[side] > 0.0:
                ankle, hip = legs[side, 2], legs[side, 0]
                target[:] = g_pos[ankle] + weight[side] * (anchor[r, side] - g_pos[ankle])
                ground2 = (target[0] - g_pos[hip, 0]) ** 2 + (target[2] - g_pos[hip, 2]) ** 2
                length = 0.999 * reach[side]
                above = g_pos[hip, 1] - target[1]
                over = above - np.sqrt(length * length - ground2) if ground2 < length * length else above
                need = max(need, over)
        low, high = (-np.inf, np.inf) if fresh else (drop[r] - rise, drop[r] + fall)
        drop[r] = max(min(need, max_drop, high), low, -max_drop if keep_bend else 0.0)
        if drop[r] != 0.0:  # straight down (or up) in the world, in the lowered joint's parent's frame
            p = parents[lowered]
            dx, dy, dz = (
                (0.0, -drop[r], 0.0)
                if p < 0
                else quat.mul_vec_scalars(g_rot[p, 0], -g_rot[p, 1], -g_rot[p, 2], -g_rot[p, 3], 0.0, -drop[r], 0.0)
            )
            positions[i, lowered, 0] += dx
            positions[i, lowered, 1] += dy
            positions[i, lowered, 2] += dz
            forward_pose(out[i], positions[i], parents, g_rot, g_pos)
        left[:] = g_pos[across_l] - g_pos[across_r]
        for side in range(2):  # the planted feet on their anchors
            if weight[side] > 0.0:
                ankle = legs[side, 2]
                target[:] = g_pos[ankle] + weight[side] * (anchor[r, side] - g_pos[ankle])
                _leg_to(out[i], parents, legs[side], g_pos, g_rot, target, left, hip_g, knee_g)
        forward_pose(out[i], positions[i], parents, g_rot, g_pos)
        lifted = False
        for side in range(2):  # then each ankle above its floor (a toe below its own is pitched up below)
            ankle = legs[side, 2]
            lift = floor[r, side, 0] - g_pos[ankle, 1]
            if lift > 1e-9:
                target[:] = g_pos[ankle]
                target[1] += lift
                _leg_to(out[i], parents, legs[side], g_pos, g_rot, target, left, hip_g, knee_g)
                lifted = True
        if lifted:
            forward_pose(out[i], positions[i], parents, g_rot, g_pos)
        for side in range(2):  # the ankles as this frame gives them (pitching a toe up below keeps them)
            placed[r, side] = g_pos[legs[side, 2]]
        for side in range(2):  # a toe still below its floor: the foot pitched up about the ankle, to the floor
            ankle, toe = legs[side, 2], toes[side]
            if toe >= 0 and floor[r, side, 1] - g_pos[toe, 1] > 1e-9:
                _toe_to(
                    out[i], parents[ankle], ankle, g_pos[toe] - g_pos[ankle], floor[r, side, 1] - g_pos[ankle, 1], g_rot
                )


@nb.njit(cache=True)
def _leg_to(out, parents, leg, g_pos, g_rot, target, left, hip_g, knee_g):
    """Two-bone IK of one leg (hip, knee, ankle) towards ``target``: its hip and knee local rotations in ``out``."""
    hip, knee, ankle = leg[0], leg[1], leg[2]
    limb_ik(g_pos[hip], g_pos[knee], g_pos[ankle], target, g_rot[hip], g_rot[knee], left, 1e-4, hip_g, knee_g)
    p = parents[hip]
    if p < 0:
        out[hip] = hip_g
    else:
        out[hip, 0], out[hip, 1], out[hip, 2], out[hip, 3] = quat.mul_scalars(
            g_rot[p, 0], -g_rot[p, 1], -g_rot[p, 2], -g_rot[p, 3], hip_g[0], hip_g[1], hip_g[2], hip_g[3]
        )
    out[knee, 0], out[knee, 1], out[knee, 2], out[knee, 3] = quat.mul_scalars(
        hip_g[0], -hip_g[1], -hip_g[2], -hip_g[3], knee_g[0], knee_g[1], knee_g[2], knee_g[3]
    )


@nb.njit(cache=True)
def _toe_to(out, parent, ankle, toe, height, g_rot):
    """Turn the ``ankle`` (local rotation in ``out``; ``g_rot``: the global rotations) so that its toe,
    at ``toe`` from it, is ``height`` above it, pointing the same way on the ground."""
    length = np.sqrt(np.sum(toe**2))
    y = min(max(height, -length), length)
    ground = np.sqrt(toe[0] ** 2 + toe[2] ** 2)
    h = np.sqrt(max(length * length - y * y, 0.0))
    dx, dz = (toe[0] / ground, toe[2] / ground) if ground > 1e-9 else (0.0, 0.0)
    rw, rx, ry, rz = quat.between_scalars(toe[0], toe[1], toe[2], dx * h, y, dz * h)
    a = g_rot[ankle]
    gw, gx, gy, gz = quat.mul_scalars(rw, rx, ry, rz, a[0], a[1], a[2], a[3])
    p = g_rot[parent]
    out[ankle, 0], out[ankle, 1], out[ankle, 2], out[ankle, 3] = quat.mul_scalars(
        p[0], -p[1], -p[2], -p[3], gw, gx, gy, gz
    )


def clean_feet(output: Motion, source: Motion) -> Motion:
    """A whole output motion cleaned frame by frame (the same values as streaming it)."""
    lock = FootLock(output.skeleton, 1, output.fps)
    rot = np.empty_like(output.rotations)
    pos = np.empty_like(output.positions)
    for t in range(output.n_frames):
        r, p = lock.step(
            output.rotations[t : t + 1],
            output.positions[t : t + 1],
            source.rotations[t : t + 1],
            source.positions[t : t + 1],
        )
        rot[t], pos[t] = r[0], p[0]
    return Motion(output.skeleton, rot, pos, output.fps, output.euler_hint)
