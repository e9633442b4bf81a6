"""A reference host loop for the exported step graph: plain numpy + onnxruntime, no styleerd.

What a game or avatar host does per frame, for one stream on the model's skeleton (retarget
your character to it first): features of the pose, one step of the graph, the stylised pose
back. docs/ONNX.md explains every line; tests/test_onnx_host.py runs this file and compares it
with styleerd's own stylizer.

    python examples/onnx_host.py stylizer.onnx poses.npz out.npz --style elderly [--input-style normal --content walk]

``poses.npz`` holds ``rotations [T, J, 4]`` (local unit quaternions w, x, y, z) and
``positions [T, J, 3]`` (local translations; the root's is its world position), ``fps``;
``out.npz`` gets the stylised ``rotations`` (same layout; root position and translations are
the input's). Each frame runs the graph twice, each run with its own recurrent state: into the
target, and into the input's own style (the identity transfer). Where the identity output is near
the input (the network knows this motion) the output is the network's; where it is far (an action
it never learnt) the input's pose turned, joint by joint, by the target style's posture (the
sidecar's ``posture``: rotation vectors; for a model without one, the change from the identity
output to the target's, input * inv(identity) * target), then turned so that its joints go where
the posture moves the input's (the sidecar's ``posture_offsets``, ``reach``); in between a blend:
as styleerd's stylizer does.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import onnxruntime as ort


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v [..., 3]`` by unit quaternions ``q [..., 4]``."""
    u, w = q[..., 1:], q[..., :1]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


FAMILIAR, UNFAMILIAR = 10.0, 16.0  # degrees: styleerd.model.config's, where the export has no familiar_degrees
RISE, RELEASE = 0.25, 0.1  # a frame: the same, where it has no unfamiliar_rise_release


def from_rotation_vectors(v: np.ndarray) -> np.ndarray:
    """Quaternions of rotation vectors ``[..., 3]`` (angle |v| radians about v)."""
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.concatenate([np.cos(angle / 2), np.sin(angle / 2) * v / np.maximum(angle, 1e-12)], axis=-1)


def qinv(q: np.ndarray) -> np.ndarray:
    return q * [1, -1, -1, -1]


def slerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """From ``a`` (t=0) to ``b`` (t=1) along the shorter arc, per row."""
    b = np.where((a * b).sum(-1, keepdims=True) < 0, -b, b)
    theta = np.arccos(np.clip((a * b).sum(-1, keepdims=True), -1.0, 1.0))
    s = np.sin(theta)
    near = s < 1e-6
    wa = np.where(near, 1 - t, np.sin((1 - t) * theta) / np.where(near, 1.0, s))
    wb = np.where(near, t, np.sin(t * theta) / np.where(near, 1.0, s))
    out = wa * a + wb * b
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation by the smallest angle taking ``a``'s direction to ``b``'s (a zero vector: none)."""
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-12 or nb < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    a, b = a / na, b / nb
    w = 1.0 + a @ b
    if w < 1e-9:  # opposite: a half turn about an axis orthogonal to a
        q = np.concatenate([[0.0], np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])])
    else:
        q = np.concatenate([[w], np.cross(a, b)])
    return q / np.linalg.norm(q)


def limb_elbow(elbow: np.ndarray, end: np.ndarray, upper: float, lower: float, rounds: int) -> np.ndarray:
    """Where a two-bone limb's middle joint goes, from the limb's first joint, given its target
    ``elbow`` and the end's target ``end`` (both from the first joint): the point at ``upper`` from the
    first joint nearest, in the least squares, to its target and to the sphere of radius ``lower``
    about the end's (from which the lower bone reaches it), by ``rounds`` rounds of projections."""
    e = elbow
    for _ in range(rounds):
        e = upper * e / max(np.linalg.norm(e), 1e-12)
        r = e - end
        e = 0.5 * (elbow + end + lower * r / max(np.linalg.norm(r), 1e-12))
    return upper * e / max(np.linalg.norm(e), 1e-12)


def reach(
    rot: np.ndarray,
    pos: np.ndarray,
    given: np.ndarray,
    targets: np.ndarray,
    parents: list[int],
    limb_ends: list[int],
    rounds: int,
) -> np.ndarray:
    """The pose ``rot [J, 4]`` turned so that each joint's children go towards ``targets [J, 3]``
    (global): down the chain, each joint but the root by the shortest arc from its children's
    summed bone vectors to the summed vectors to their targets (no bone turns about itself); the
    first joint of a two-bone limb (``limb_ends[j]``: its end, else -1) towards where ``limb_elbow``
    puts the middle joint. ``given``: the input's global joint positions (the root's is kept)."""
    rot, g_rot, g_pos = rot.copy(), rot.copy(), given.copy()
    for j, p in enumerate(parents):
        if p < 0:
            continue
        g_rot[j] = qmul(g_rot[p], rot[j])
        g_pos[j] = g_pos[p] + qrot(g_rot[p], pos[j])
        kids = [k for k in range(j + 1, len(parents)) if parents[k] == j]
        if kids:
            now = sum(qrot(g_rot[j], pos[k]) for k in kids)
            wanted = sum(targets[k] - g_pos[j] for k in kids)
            if limb_ends[j] >= 0:
                end = limb_ends[j]
                upper, lower = np.linalg.norm(now), np.linalg.norm(pos[end])
                wanted = limb_elbow(wanted, targets[end] - g_pos[j], upper, lower, rounds)
            g_rot[j] = qmul(shortest_arc(now, wanted), g_rot[j])
            rot[j] = qmul(qinv(g_rot[p]), g_rot[j])
    return rot


def forward_kinematics(rot: np.ndarray, pos: np.ndarray, parents: list[int]) -> np.ndarray:
    """Global joint positions ``[J, 3]`` of local rotations and translations."""
    g_rot, g_pos = np.empty_like(rot), np.empty_like(pos)
    for j, p in enumerate(parents):
        if p < 0:
            g_rot[j], g_pos[j] = rot[j], pos[j]
        else:
            g_rot[j] = qmul(g_rot[p], rot[j])
            g_pos[j] = g_pos[p] + qrot(g_rot[p], pos[j])
    return g_pos


class Host:
    """One stream: the state the graph needs between frames, and the features it reads."""

    def __init__(self, graph: Path, style: str, input_style: str, content: str):
        self.side = json.loads(graph.with_suffix(".json").read_text())
        s = self.side
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        self.session = ort.InferenceSession(str(graph), options, providers=["CPUExecutionProvider"])
        self.parents = s["skeleton"]["parents"]
        self.mean, self.std, self.reference = (np.array(s["stats"][k]) for k in ("mean", "std", "reference"))
        r = s["roles"]
        self.left, self.right, self.feet = r["left"], r["right"], r["feet"]
        self.max_foot_speed = s["contact_speed_leg_lengths"] * r["leg_length"]
        one_hot = lambda names, name: np.eye(len(names), dtype=np.float32)[[names.index(name)]]
        self.style, self.content = (
            one_hot(s.get("input_styles", s["styles"]), input_style),
            one_hot(s["contents"], content),
        )
        self.target = one_hot(s["styles"], style)
        self.identity = np.zeros_like(self.target)
        self.identity[:, : self.style.shape[1]] = self.style  # the input's own style, among the targets
        # the posture change from the input's own style to the target (rotation vectors, summed by weight)
        posture = np.array(s["posture"]) if s.get("posture") is not None else None
        self.change = (
            None
            if posture is None
            else from_rotation_vectors(np.einsum("s,sjc->jc", (self.target - self.identity)[0], posture))
        )
        # where the posture moves each joint (in the frame posture_frame names), summed by weight; None: not measured
        offsets = np.array(s["posture_offsets"]) if s.get("posture_offsets") is not None else None
        self.body_frame = s.get("posture_frame") == "body"
        # an older export has no limbs: every joint turned on its own
        self.limb_ends, self.limb_rounds = s.get("limb_ends", [-1] * len(self.parents)), s.get("limb_rounds", 0)
        self.eyes = s.get("eyes_above_head")
        self.familiar_degrees = s.get("familiar_degrees", (FAMILIAR, UNFAMILIAR))
        self.rise, self.release = s.get("unfamiliar_rise_release", (RISE, RELEASE))
        self.hips, self.head = s["roles"].get("hips", 0), s["roles"].get("head", 0)
        self.moved = None if offsets is None else np.einsum("s,sjc->jc", (self.target - self.identity)[0], offsets)
        rows, _, width = s["state_shapes"]["h"]  # [1, N, S H] (LSTM form) or [S, N, H] (plain); N = 1 here
        self.state = {
            k: [np.zeros((rows, 1, width), np.float32), np.zeros((rows, 1, width), np.float32)]
            for k in ("target", "identity")
        }
        self.previous: np.ndarray | None = None  # global joint positions of the last frame
        self.unfamiliar = 0.0  # 0: the network's pose, 1: the input's pose turned by the style's change
        self.facing = np.array([0.0, 0.0, 1.0])

    def features(self, rot: np.ndarray, pos: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
        """The normalised feature vector ``[1, D]`` of this frame and its heading quaternion (its
        global joint positions are kept in ``self.previous``)."""
        rot = rot / np.linalg.norm(rot, axis=-1, keepdims=True)
        g = forward_kinematics(rot, pos, self.parents)
        # facing: across (left hip + left shoulder - right ones) x up, on the ground; heading about +Y
        across = g[self.left].sum(0) - g[self.right].sum(0)
        f = np.array([-across[2], 0.0, across[0]])
        if np.hypot(f[0], f[2]) > 1e-6 * max(1.0, np.linalg.norm(across)):
            self.facing = f / np.hypot(f[0], f[2])
        half = np.arctan2(self.facing[0], self.facing[2]) / 2.0
        heading = np.array([np.cos(half), 0.0, np.sin(half), 0.0])
        inverse = heading * [1, -1, -1, -1]
        local = rot.copy()
        local[0] = qmul(inverse, rot[0])
        local *= np.where(local[:, :1] < 0, -1.0, 1.0)  # w >= 0 ...
        local *= np.where(
            (local * self.reference).sum(-1, keepdims=True) < 0, -1.0, 1.0
        )  # ... then the reference's hemisphere
        moved = self.previous is not None
        previous = self.previous if moved else g
        relative = qrot(inverse, g - g[0])
        velocity = qrot(inverse, g - previous) * fps
        speed = np.linalg.norm(g[self.feet] - previous[self.feet], axis=-1) * fps
        contacts = (speed < self.max_foot_speed).astype(np.float64)  # left foot, left toe, right foot, right toe
        x = np.concatenate([local.ravel(), relative.ravel(), velocity.ravel(), contacts])
        self.previous = g
        return ((x - self.mean) / self.std).astype(np.float32)[None], heading

    def body_axes(self, g: np.ndarray) -> np.ndarray:
        """The body's own axes as rows (left, up, forward) of global joint positions ``g``: up from
        the hips to the head, left from the right hip and shoulder to the left ones."""
        up = g[self.head] - g[self.hips]
        forward = np.cross(g[self.left].sum(0) - g[self.right].sum(0), up)
        axes = np.stack([np.cross(up, forward), up, forward])
        return axes / np.maximum(np.linalg.norm(axes, axis=-1, keepdims=True), 1e-9)

    def step(self, rot: np.ndarray, pos: np.ndarray, fps: float) -> np.ndarray:
        """One frame's local rotations ``[J, 4]`` and translations ``[J, 3]`` -> stylised rotations."""
        first = np.array([[0.0 if self.previous is not None else 1.0]], np.float32)
        x, heading = self.features(rot, pos, fps)
        poses = {}
        for key, target in (("target", self.target), ("identity", self.identity)):
            h, c = self.state[key]
            out, _, h, c = self.session.run(
                None,
                {
                    "features": x,
                    "style": self.style,
                    "content": self.content,
                    "target": target,
                    "first_frame": first,
                    "h": h,
                    "c": c,
                },
            )
            self.state[key] = [h, c]
            out = out[0].astype(np.float64)
            out[0] = qmul(heading, out[0])  # the root back from the heading frame
            poses[key] = out / np.linalg.norm(out, axis=-1, keepdims=True)
        given = rot / np.linalg.norm(rot, axis=-1, keepdims=True)
        d = qmul(qinv(poses["identity"]), given)
        degrees = np.degrees(2 * np.arctan2(np.linalg.norm(d[:, 1:], axis=-1), np.abs(d[:, 0]))).mean()
        lo, hi = self.familiar_degrees
        now = float(np.clip((degrees - lo) / (hi - lo), 0.0, 1.0))
        last = self.unfamiliar  # down by at most release and up by at most rise a frame
        self.unfamiliar = now if first[0, 0] else min(max(now, last - self.release), last + self.rise)
        change = qmul(qinv(poses["identity"]), poses["target"]) if self.change is None else self.change
        turned = qmul(given, change)
        turned /= np.linalg.norm(turned, axis=-1, keepdims=True)
        if self.moved is not None:  # then turned so that the joints go where the posture moves the input's
            g = self.previous
            axes = self.body_axes(g) if self.body_frame else qrot(heading, np.eye(3))  # rows: left, up, forward
            moved = self.moved @ axes
            if self.eyes is not None:  # a limb's end's rise: the smooth minimum of it and the way to the eyes
                for m in (m for m in self.limb_ends if m >= 0 and self.moved[m, 1] > 0):
                    rise, middle = self.moved[m, 1], self.moved[self.parents[m], 1]
                    below = max(self.eyes + (g[self.head] - g[m]) @ axes[1], 0.0)
                    kept = rise * below / (rise**3 + below**3) ** (1 / 3)
                    moved[m] -= (rise - kept) * axes[1]
                    if middle > 0:  # the limb rises as one
                        moved[self.parents[m]] -= middle * (1 - kept / rise) * axes[1]
            turned = reach(turned, pos, g, g + moved, self.parents, self.limb_ends, self.limb_rounds)
        return slerp(poses["target"], turned, self.unfamiliar)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph", type=Path)
    parser.add_argument("poses", type=Path)
    parser.add_argument("output", type=Path)
    parser.add_argument("--style", required=True)
    parser.add_argument("--input-style", default="normal")
    parser.add_argument("--content", default="walk")
    args = parser.parse_args()
    poses = np.load(args.poses)
    host = Host(args.graph, args.style, args.input_style, args.content)
    out = np.stack([host.step(r, p, float(poses["fps"])) for r, p in zip(poses["rotations"], poses["positions"])])
    np.savez(args.output, rotations=out)
    print(f"stylised {len(out)} frames into {args.style}")


if __name__ == "__main__":
    main()
