"""VMC protocol bridge (OSC over UDP, python-osc): receive an avatar's bones, stylise them,
send them on. Sits between a Performer (VSeeFace, Virtual Motion Capture, a game) and a
Marionette (EVMC4U, VMC4UE, ...).

Received: ``/VMC/Ext/Root/Pos`` and ``/VMC/Ext/Bone/Pos`` (name, position xyz, rotation
xyzw: local to the parent bone, Unity's left-handed axes: x right, y up, z forward). Unity
humanoid bone names (HumanBodyBones) make the skeleton; its rest pose is the avatar's normalised
T-pose (identity local rotations, as VRM rigs are), its bone offsets those of the first frame.
The skeleton is mapped onto the model's by names like any BVH skeleton.

Sent: for every complete frame, one bundle with the Root/Pos as received and a Bone/Pos per
bone (positions as received, rotations stylised; fingers, eyes and bones the model lacks keep
their input rotation). Every other message (blend shapes, ``/VMC/Ext/OK``, ``/VMC/Ext/T``, ...)
is passed on unchanged.

Frames: the first frame is known complete when the next ``Root/Pos`` arrives (that fixes the
bone set); after that a frame is stylised as soon as all its bones have arrived, so a sender
that bundles a frame (the usual case) gets each frame back with no delay. When the performer
switches to an avatar with other bones, frames stop completing: after ``REMAP_AFTER`` such
frames the bridge maps the new bone set.

Bad input never stops the bridge: a datagram that is not OSC, or a Root/Bone message whose
arguments are not a name and seven finite numbers, is counted and dropped (one summary line per
interval); a first frame that makes no humanoid (no Hips, orphan bones) is dropped and the next
one tried; ``run_bridge`` keeps at most ``BACKLOG`` datagrams waiting, dropping the oldest.
"""

from __future__ import annotations

import socket
import time
from collections import deque

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.osc_packet import OscPacket, ParseError

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.motion import quat
from styleerd.motion.motion import Motion
from styleerd.motion.skeleton import POSITION_CHANNELS, Skeleton
from styleerd.runtime.channels import ChannelStylizer
from styleerd.runtime.stylizer import part_targets, target_weights

ROOT, BONE = "/VMC/Ext/Root/Pos", "/VMC/Ext/Bone/Pos"
REMAP_AFTER = 3  # incomplete frames in a row (an avatar with other bones) before the bones are mapped again
BACKLOG = 512  # datagrams waiting to be read, at most: the oldest go first
LIMIT = 1e6  # metres or quaternion components: anything larger is garbage

# Unity HumanBodyBones -> possible parents, nearest first (optional bones may be absent)
_TORSO = {
    "Hips": (),
    "Spine": ("Hips",),
    "Chest": ("Spine", "Hips"),
    "UpperChest": ("Chest", "Spine", "Hips"),
    "Neck": ("UpperChest", "Chest", "Spine"),
    "Head": ("Neck", "UpperChest", "Chest", "Spine"),
    "Jaw": ("Head",),
}
_LEFT = {
    "LeftEye": ("Head",),
    "LeftShoulder": ("UpperChest", "Chest", "Spine"),
    "LeftUpperArm": ("LeftShoulder", "UpperChest", "Chest", "Spine"),
    "LeftLowerArm": ("LeftUpperArm",),
    "LeftHand": ("LeftLowerArm",),
    "LeftUpperLeg": ("Hips",),
    "LeftLowerLeg": ("LeftUpperLeg",),
    "LeftFoot": ("LeftLowerLeg",),
    "LeftToes": ("LeftFoot",),
}
for _finger in ("Thumb", "Index", "Middle", "Ring", "Little"):
    _LEFT[f"Left{_finger}Proximal"] = ("LeftHand",)
    _LEFT[f"Left{_finger}Intermediate"] = (f"Left{_finger}Proximal",)
    _LEFT[f"Left{_finger}Distal"] = (f"Left{_finger}Intermediate",)
UNITY_PARENTS = {
    **_TORSO,
    **_LEFT,
    **{k.replace("Left", "Right"): tuple(p.replace("Left", "Right") for p in v) for k, v in _LEFT.items()},
}


def unity_position(p: np.ndarray) -> np.ndarray:
    """Unity (left-handed) <-> right-handed position: mirror x. Its own inverse."""
    return p * np.array([-1.0, 1.0, 1.0])


def unity_rotation(q: np.ndarray) -> np.ndarray:
    """Unity quaternion (x, y, z, w), left-handed -> ours (w, x, y, z), right-handed (x
    mirrored: M R M with M = diag(-1, 1, 1) keeps the x component, negates y and z)."""
    q = np.asarray(q, dtype=np.float64)
    return np.stack([q[..., 3], q[..., 0], -q[..., 1], -q[..., 2]], axis=-1)


def rotation_to_unity(q: np.ndarray) -> np.ndarray:
    """The inverse of ``unity_rotation``."""
    return np.stack([q[..., 1], -q[..., 2], -q[..., 3], q[..., 0]], axis=-1)


def humanoid_skeleton(bones: dict[str, np.ndarray]) -> Skeleton:
    """A skeleton from Unity humanoid bones and their local positions (right-handed),
    parents before children; bones of unknown names are left out."""
    names = [b for b in UNITY_PARENTS if b in bones]
    if "Hips" not in names:
        raise StyleERDError("VMC: no 'Hips' bone received; a humanoid avatar sends Hips, Spine, legs, arms and Head")
    parents = []
    for b in names:
        present = [p for p in UNITY_PARENTS[b] if p in bones]
        parents.append(names.index(present[0]) if present else (-1 if b == "Hips" else None))
    orphans = [b for b, p in zip(names, parents) if p is None]
    if orphans:
        raise StyleERDError(f"VMC: bones without their parent bone: {', '.join(orphans)}")
    rot = ("Zrotation", "Xrotation", "Yrotation")
    return Skeleton(
        tuple(names),
        np.array(parents),
        np.array([bones[b] for b in names]),
        tuple(POSITION_CHANNELS + rot if p < 0 else rot for p in parents),
    )


class VMCBridge:
    """Datagrams in, datagrams out (no sockets here: ``run_bridge`` owns them)."""

    def __init__(
        self,
        model: GeneratorWeights,
        target: dict[str, float],
        fps: float = 30.0,
        cleanup: bool = True,
        report=print,
        parts: str | dict | None = None,
        root_speed: bool = False,
    ):
        self.model, self.target, self.fps, self.cleanup, self.report = model, target, fps, cleanup, report
        self.root_speed = root_speed  # the hips move at the style's pace (their path drifts from the performer's)
        self.parts = part_targets(
            model, parts
        )  # body parts with targets of their own (checked now, not at the first frame)
        self.stylizer: ChannelStylizer | None = None
        self.skeleton: Skeleton | None = None
        self.root: list | None = None  # the last Root/Pos arguments
        self.bones: dict[str, tuple] = {}  # bone -> (position xyz, rotation xyzw) received for this frame
        self.frames = self.rejected = self.malformed = self.remapped = 0
        self.incomplete = 0  # frames in a row whose bones did not match the skeleton's

    def set_target(self, target: dict[str, float]) -> None:
        self.target = target
        if self.stylizer is not None:
            self.stylizer.stylizer.set_target(target)

    def feed(self, datagram: bytes) -> list[bytes]:
        """One received datagram -> the datagrams to send on."""
        try:
            messages = [m.message for m in OscPacket(datagram).messages]
        except (
            ParseError,
            RecursionError,
            ValueError,
            TypeError,
            OverflowError,
            IndexError,
            UnicodeError,
        ):  # python-osc meets any of these in junk
            self.malformed += 1
            return []
        passed, frames = [], []
        for msg in messages:
            if msg.address in (ROOT, BONE):
                params = _pose_params(msg.params)
                if params is None:
                    self.malformed += 1
                elif msg.address == ROOT:
                    frames += self._frame_boundary()
                    self.root = params
                elif params[0] in UNITY_PARENTS:
                    self.bones[params[0]] = (np.array(params[1:4], float), np.array(params[4:8], float))
                    if (
                        self.skeleton is not None
                        and len(self.bones) >= len(self.skeleton.names)
                        and all(b in self.bones for b in self.skeleton.names)
                    ):
                        frames += self._frame()
            else:
                passed.append(msg)
        out = []
        if passed:
            bundle = OscBundleBuilder(IMMEDIATELY)
            for msg in passed:
                bundle.add_content(msg)
            out.append(bundle.build().dgram)
        return out + frames

    def _frame_boundary(self) -> list[bytes]:
        """A Root/Pos starts a frame: the bones gathered since the last one are the first frame
        (which fixes the skeleton), or an incomplete frame (counted: an avatar with other bones
        is mapped afresh after ``REMAP_AFTER`` of them)."""
        if not self.bones or self.root is None:
            return []
        if self.skeleton is not None:
            self.incomplete += 1
            if self.incomplete < REMAP_AFTER:
                self.bones = {}
                return []
            self.remapped += 1
            self.report(f"VMC: the avatar's bones changed ({len(self.bones)} bones now); mapping them again")
        return self._start()

    def _start(self) -> list[bytes]:
        """The first frame fixes the bone set and the skeleton; one that makes no humanoid (or
        cannot be mapped) is dropped, and the next frame is tried."""
        try:
            skeleton = humanoid_skeleton({b: unity_position(p) for b, (p, _) in self.bones.items()})
            stylizer = ChannelStylizer(
                self.model,
                skeleton,
                self.target,
                fps=self.fps,
                cleanup=self.cleanup,
                parts=self.parts,
                root_speed=self.root_speed,
            )
        except StyleERDError as e:
            self.rejected += 1
            self.report(f"{e}; waiting for the next frame")
            self.bones, self.skeleton, self.stylizer = {}, None, None
            return []
        self.skeleton, self.stylizer, self.incomplete = skeleton, stylizer, 0
        self.report(
            f"VMC: {len(self.skeleton.names)} bones; joint mapping (model <- avatar):\n{self.stylizer.map.describe()}"
        )
        return self._frame()

    def _frame(self) -> list[bytes]:
        sk = self.skeleton
        pos = np.stack([unity_position(self.bones[b][0]) for b in sk.names])
        rot = quat.normalize(np.stack([unity_rotation(self.bones[b][1]) for b in sk.names]))
        local = sk.offsets.copy()
        local[0] = pos[0]
        self.bones, self.incomplete = {}, 0
        try:
            out = self.stylizer.step_pose(Motion(sk, rot[None], local[None], self.fps))
        except StyleERDError:
            self.rejected += 1  # NaN/inf: the frame is dropped, the stream state is unchanged
            return []
        self.frames += 1
        bundle = OscBundleBuilder(IMMEDIATELY)
        bundle.add_content(_message(ROOT, self.root))
        for j, name in enumerate(sk.names):
            p = unity_position(out.positions[0, j])  # the input's, but the hips' with root_speed
            q = rotation_to_unity(out.rotations[0, j])
            bundle.add_content(_message(BONE, [name, *map(float, p), *map(float, q)]))
        return [bundle.build().dgram]


def _pose_params(params) -> list | None:
    """A Root/Bone message's arguments checked: a name and seven finite numbers of sane size
    (position xyz, rotation xyzw; extra arguments are kept as they came), else None."""
    params = list(params)
    if len(params) < 8 or not isinstance(params[0], str) or len(params[0]) > 64:
        return None
    numbers = params[1:8]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers):
        return None
    if not all(np.isfinite(v) and abs(v) < LIMIT for v in map(float, numbers)):
        return None
    if sum(float(v) ** 2 for v in numbers[3:]) < 1e-12:  # a zero quaternion is no rotation
        return None
    return params


def _message(address: str, params: list):
    builder = OscMessageBuilder(address)
    for value in params:
        builder.add_arg(value)
    return builder.build()


def run_bridge(
    listen: int,
    send: int,
    style: str | None,
    intensity: float,
    mix: dict[str, float] | None,
    host: str = "127.0.0.1",
    fps: float = 30.0,
    parts: str | None = None,
    model_name: str | None = None,
    root_speed: bool = False,
) -> None:
    """``styleerd vmc``: receive on ``host:listen``, send the stylised stream to ``host:send``."""
    if listen == send:
        raise StyleERDError(f"VMC: --send {send} is --listen {listen}: the bridge would receive what it sends, forever")
    import logging

    logging.getLogger("pythonosc").setLevel(logging.ERROR)  # junk is counted, not printed line by line
    model = load_generator_weights(model_name)
    target = target_weights(model, style, intensity, mix)
    bridge = VMCBridge(
        model, target, fps, report=lambda text: print(text, flush=True), parts=parts, root_speed=root_speed
    )
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)  # room for frames that arrive while the first is set up
    try:
        rx.bind((host, listen))
    except OSError as e:
        raise StyleERDError(f"VMC: cannot listen on {host}:{listen} ({e.strerror})") from None
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    print(
        f"styleerd vmc: receiving VMC on {host}:{listen}, sending the stylised stream to {host}:{send}, target "
        f"{target}",
        flush=True,
    )
    last, dropped, waiting = time.time(), 0, deque(maxlen=BACKLOG)
    try:
        while True:
            rx.setblocking(True)
            waiting.append(rx.recvfrom(65536)[0])
            rx.setblocking(False)
            try:  # everything that has arrived meanwhile, the oldest dropped past BACKLOG
                while True:
                    if len(waiting) == BACKLOG:
                        dropped += 1
                    waiting.append(rx.recvfrom(65536)[0])
            except BlockingIOError:
                pass
            while waiting:
                for out in bridge.feed(waiting.popleft()):
                    tx.sendto(out, (host, send))
            if time.time() - last > 5:
                last = time.time()
                print(
                    f"frames {bridge.frames}, rejected {bridge.rejected}, malformed {bridge.malformed}, remapped "
                    f"{bridge.remapped}, "
                    f"dropped (backlog over {BACKLOG}) {dropped}",
                    flush=True,
                )
    finally:
        rx.close()
        tx.close()
