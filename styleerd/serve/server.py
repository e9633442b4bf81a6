"""``styleerd serve``: the real-time style server (protocol: docs/PROTOCOL.md) and the
browser viewer it serves.

Each connection is one stream with its own stylizer state, held as a slot of a pool: one
``ChannelStylizer`` per (skeleton, fps, cleanup). One stepping task runs, again and again, one
batched step per pool over every stream that has a frame waiting, so many streams cost little
more than one. Frames of a stream are answered one for one, in order.

Bounds: a stream may have ``queue`` frames waiting to be stylised; past that, a client ahead of
real time (more frames than its frame rate allows since its hello) is told and closed, while a
client in time whose frames wait because the server is behind may have up to ``OVERLOAD`` x
``queue`` (then 1013: the server is overloaded). At most ``queue`` stylised frames may be
unsent (a client that stops reading is told and closed): memory per stream is bounded. A hello's
skeleton has at most ``max_joints`` joints, and its setup (parsing, mapping, a new pool) runs
in a worker thread, one at a time, so a heavy hello never stalls the streams being stepped.

Who may connect: a browser page only from the server's own origin (or ``origins``), and only
under a host name the server answers to (so a rebound DNS name cannot reach a loopback
server); a private stream is watched or steered only with the token its ``ready`` carries.

A connection may instead be a live viewer (``watch``) or a page's file (``upload``: a glTF motion
or a GLB avatar, at most ``MAX_UPLOAD`` bytes, read by ``serve.uploads`` on a thread in a folder
of its own, ``UPLOADS_AT_ONCE`` at a time), answered once and closed.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import mimetypes
import multiprocessing
import secrets
import signal
import socket
import struct
import tempfile
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from http import HTTPStatus
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np
from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from styleerd.errors import StyleERDError
from styleerd.model.stored import GeneratorWeights, load_generator_weights
from styleerd.motion import bvh, quat
from styleerd.motion.gltf import guess_metres_per_unit, humanoid_pose, tpose_positions, vrm_bones
from styleerd.motion.kinematics import bone_fronts, forward_kinematics
from styleerd.motion.motion import Motion
from styleerd.motion.retarget import body_parts, to_target
from styleerd.motion.skeleton import Skeleton
from styleerd.runtime.channels import ChannelStylizer
from styleerd.runtime.onnx_export import sidecar, step_graph
from styleerd.runtime.stylizer import POSES, label_vector, part_targets, target_weights
from styleerd.serve.clips import DemoClips, reference_clip
from styleerd.serve.connection import Message, MessageConnection, send_now
from styleerd.serve.uploads import AVATARS, MOTIONS, avatar_rig, motion_bvh

STATIC = Path(__file__).parent / "static"
SEQ = struct.Struct("<I")  # binary frames start with the frame's sequence number

# close codes (RFC 6455)
GOING_AWAY, INVALID_DATA, POLICY, INTERNAL, TRY_LATER = (
    1001,
    1007,
    1008,
    1011,
    1013,
)  # 1009 (too big) is websockets' own
HELLO_TIMEOUT_S = 10.0
MAX_UPLOAD = 32 << 20  # bytes of a motion or avatar file a page uploads (a Mixamo GLB with its mesh is 2-20 MB)
UPLOADS_AT_ONCE = 2  # files read at a time: each takes a core for up to seconds
UPLOAD_WAIT_S, CONVERT_S = 30.0, 120.0  # the longest wait for the next piece of a file, and for its reading
OVERLOAD = 4  # x queue: frames a client in real time may have waiting while the server is behind
log = logging.getLogger("styleerd.serve")
MAX_TOKEN = 200  # characters of a watcher's token (a stream's own is 22)
SEND_BUFFER = 1 << 16  # bytes of kernel send buffer per connection


@dataclass
class ServeConfig:
    host: str = "127.0.0.1"
    port: int = 8765
    max_streams: int = 256  # open streams, all pools together
    max_watchers: int = 64  # live viewers at once (each costs every stream it follows a copy of its frames)
    max_message: int = 1 << 20  # bytes; a larger message closes its connection with 1009
    queue: int = 64  # per stream: frames waiting to be stylised, and stylised frames unsent
    batch_wait: float = 0.004  # seconds a frame may wait for other streams' frames to share its step
    backend: str = "numba"  # about 0.7x numpy's engine CPU a frame at 40 and 200 clients (docs/DEPLOY.md)
    threads: int = 1  # of each pool's batched step (numba's kernels, or numpy/onnx shards of the streams)
    data: str | None = None  # data folder for the viewer's real demo clips (optional)
    max_joints: int = 512  # joints of a hello's skeleton (a humanoid has 20 to 100)
    origins: tuple[str, ...] = ()  # browser origins allowed besides the server's own ("*": any)
    hosts: tuple[str, ...] = ()  # host names answered besides the bound address and, on loopback, localhost
    model: str | None = None  # a model file or name (default: the shipped model)
    loop: str = "auto"  # the event loop: uvloop where installed ("auto"), or "uvloop", or "asyncio"
    server_id: str = ""  # this process's name behind a balancer: private tokens start "ID.", so watchers reach it


class ClientError(Exception):
    """What is wrong with a client's message: sent to it as an error, then closed with ``code``."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


@dataclass(eq=False)
class Stream:
    id: int
    name: str
    ws: MessageConnection
    pool: Pool
    rows: np.ndarray  # the pool's slots of this connection's streams (a hello's ``streams``: a crowd on one connection)
    binary: bool
    positions: bool  # send joint positions of input and output with every frame
    fronts: bool = False  # and, after them, the bones' fronts (their roll)
    pending: deque = field(default_factory=deque)  # (seq, channel values, arrival time) waiting to be stylised
    watchers: set = field(default_factory=set)
    frames: int = 0
    opened: float = field(default_factory=time.perf_counter)
    private: bool = False  # not listed; watched or steered only with ``token``
    token: str = ""
    closing: bool = False  # refused: its frames are no longer stylised
    humanoid: bool = False  # also receive the VRM humanoid pose of input and output (an avatar to drive)
    confidence: bool = False  # binary: also receive each frame's unfamiliar and unread (JSON replies always carry them)

    @property
    def count(self) -> int:
        return len(self.rows)


@dataclass(eq=False)
class Watcher:
    """A viewer in live mode: receives input and output joint positions of a stream."""

    ws: MessageConnection
    name: str | None  # the stream name it follows; None: any stream
    outbox: asyncio.Queue
    stream: Stream | None = None
    fronts: bool = False  # also receive the bones' fronts
    token: str = ""  # a private stream's token, to watch it
    humanoid: bool = False  # also receive the VRM humanoid pose of input and output
    index: int = 0  # which of a connection's streams it shows


class Pool:
    """The streams of one skeleton, frame rate, cleanup and root-speed settings and body-part
    targets: a slot each in one ChannelStylizer, stepped together."""

    def __init__(
        self,
        model: GeneratorWeights,
        skeleton: Skeleton,
        fps: float,
        cleanup: bool,
        capacity: int,
        backend: str,
        key: tuple,
        parts: dict | None = None,
        root_speed: bool = False,
        pose: str = "input",
        threads: int = 1,
    ):
        neutral = model.config.neutral_style
        self.stylizer = ChannelStylizer(
            model,
            skeleton,
            {neutral: 1.0},
            neutral,
            model.config.contents[0],
            fps,
            capacity,
            cleanup=cleanup,
            backend=backend,
            parts=parts,
            root_speed=root_speed,
            pose=pose,
            threads=threads,
        )
        self.skeleton, self.parts = skeleton, parts or {}
        self.fronts = bone_fronts(skeleton)  # rest fronts of the bones, for viewers that show their roll
        self.model_parts = body_parts(model.skeleton)
        rest = Motion(model.skeleton, quat.identity((1, model.skeleton.n_joints)), model.skeleton.offsets[None], fps)
        self.metres = guess_metres_per_unit(rest)  # of the model's units, for an avatar's metres
        self.free = list(range(capacity - 1, -1, -1))
        self.streams: dict[int, Stream] = {}  # by stream id
        self.key = (
            key  # (skeleton header, fps, cleanup, parts, root speed, pose): streams that share all six share the pool
        )

    def humanoid_layout(self) -> dict:
        """What a client needs to drive a VRM avatar with the frames' humanoid pose: the bone
        of each model joint (VRM names), their parents, the hips' height in the T-pose (metres)."""
        tpose = self.stylizer.map.target_tpose
        model = self.stylizer.map.target
        return {
            "bones": vrm_bones(model, self.model_parts),
            "parents": [int(p) for p in model.parents],
            "hips_height": round(
                float(tpose_positions(model, tpose, self.stylizer.model.stats().reference)[0, 1]) * self.metres, 5
            ),
        }

    def humanoid_pose(self, values: np.ndarray) -> np.ndarray:
        """``[N, J * 4 + 3]`` float32 per stream: every model joint's rotation away from the
        T-pose relative to its parent's (x, y, z, w: a VRM normalized bone), then the hips'
        position in metres, of channel values ``[N, channels]`` on this pool's skeleton."""
        jm = self.stylizer.map
        on_model = to_target(bvh.motion_from_channels(self.skeleton, values, self.stylizer.fps), jm)
        local, pos = humanoid_pose(on_model, jm.target_tpose)
        return np.concatenate([local[..., [1, 2, 3, 0]].reshape(len(values), -1), pos[:, 0] * self.metres], -1).astype(
            "<f4"
        )


def _skeleton_from_text(text: str, fps: float, max_joints: int) -> Skeleton:
    """The skeleton of a BVH hierarchy (anything from MOTION on is ignored)."""
    hierarchy = text.split("MOTION")[0].rstrip()
    joints = hierarchy.count("JOINT") + hierarchy.count("ROOT")  # counted before parsing anything large
    if joints > max_joints:
        raise ClientError(POLICY, f"the skeleton has {joints} joints; this server takes at most {max_joints}")
    return bvh.parse(f"{hierarchy}\nMOTION\nFrames: 0\nFrame Time: {1.0 / fps:.9f}\n", "handshake skeleton").skeleton


def _origin_allowed(origin: str | None, host: str, allowed: tuple[str, ...]) -> bool:
    """A browser's ``Origin``: the server's own (same scheme-less host:port as ``Host``) or one
    listed; clients that are not browsers send none."""
    if origin is None or "*" in allowed or origin in allowed:
        return True
    parts = urlsplit(origin)
    return parts.scheme in ("http", "https") and parts.netloc.lower() == host.lower()


def _host_names(bound: str, extra: tuple[str, ...]) -> set[str] | None:
    """Host names the server answers to (None: any): the bound address, the loopback names and
    ``extra``. A loopback server so refuses a page whose DNS name was rebound to 127.0.0.1."""
    names = {h.lower().strip("[]") for h in extra}
    if bound in ("", "0.0.0.0", "::"):
        return names or None  # every interface: any name, unless names are given
    return names | {"localhost", "127.0.0.1", "::1", bound.lower().strip("[]")}


def _number(msg: dict, key: str, default: float, low: float, high: float) -> float:
    value = msg.get(key, default)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not low <= value <= high:
        raise ClientError(POLICY, f"{key!r} must be a number in [{low:g}, {high:g}], got {value!r}")
    return float(value)


class StyleServer:
    def __init__(self, config: ServeConfig, model: GeneratorWeights | None = None):
        self.config = config
        self.model = model or load_generator_weights(config.model)
        self.uploads = 0  # files being read (``_upload``)
        self.clips = DemoClips(self.model, config.data)
        self._engine: dict[str, bytes] | None = None  # the in-browser step's graph and JSON, made on first request
        self._references: dict[tuple[str, str], bytes] = {}
        self.pools: dict[tuple, Pool] = {}
        self.streams: dict[int, Stream] = {}
        self.watchers: set[Watcher] = set()
        self.next_id = 0
        self.due = asyncio.Event()
        self.setup = asyncio.Lock()  # one hello set up at a time, off the event loop
        self.host_names = _host_names(config.host, config.hosts)
        self.token_prefix = f"{config.server_id}." if config.server_id else ""
        self.started = time.time()
        self.rate_mark = (time.perf_counter(), 0)  # (when, frames): the frames/s of /metrics since the last look
        self.steps = 0
        self.frames = 0
        self.step_cpu = 0.0  # CPU seconds (every thread) in the stylizer's steps: the engine's share of the server's
        self.refusals: Counter[int] = Counter()  # close code -> connections refused or ended with it

    def warm_up(self) -> None:
        """One stream of the model's skeleton stepped twice: the first step in a process loads
        the compiled kernels and the labeller (about 0.2 s), which would otherwise stall the
        first client's frames and everyone else's with them."""
        pool = self._pool(None, 30.0, True, {}, False, "input")
        frame = np.zeros((1, pool.stylizer.n_channels))
        for _ in range(2):
            pool.stylizer.step(frame, np.array([0]))

    # ---- the handshake and the per-connection loop ----

    def _target(self, msg: dict) -> dict[str, float]:
        mix, style = msg.get("mix"), msg.get("style")
        if style is not None and not isinstance(style, str):
            raise ClientError(POLICY, f"'style' must be a style name, got {style!r}")
        if mix is not None and (
            not isinstance(mix, dict) or not all(isinstance(v, (int, float)) for v in mix.values())
        ):
            raise ClientError(POLICY, f"'mix' must be an object of style -> weight, got {mix!r}")
        try:
            weights = target_weights(self.model, style, _number(msg, "intensity", 1.0, 0.0, 2.0), mix)
            label_vector(self.model.config.styles, weights, "style")  # names the valid styles
            return weights
        except StyleERDError as e:
            raise ClientError(POLICY, str(e)) from None

    def _open_rows(self) -> int:
        return sum(s.count for s in self.streams.values())

    def _check_room(self, count: int) -> None:
        if self._open_rows() + count > self.config.max_streams:
            raise ClientError(TRY_LATER, f"the server is full ({self.config.max_streams} streams); try again later")

    async def _open_stream(self, ws: MessageConnection, msg: dict) -> Stream:
        count = msg.get("streams", 1)
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= self.config.max_streams:
            raise ClientError(
                POLICY, f"'streams' must be an integer in [1, {self.config.max_streams}], got {str(count)[:20]}"
            )
        self._check_room(count)
        fps = _number(msg, "fps", 30.0, 10.0, 480.0)
        if msg.get("preset") != "model" and not isinstance(msg.get("skeleton"), str):
            raise ClientError(POLICY, "the hello needs 'skeleton' (a BVH HIERARCHY text) or 'preset': 'model'")
        labels = {}
        for key, names in (("input_style", self.model.config.input_styles), ("content", self.model.config.contents)):
            value = msg.get(key)
            if value is not None and value not in names:
                raise ClientError(POLICY, f"unknown {key} {value!r}; valid: {', '.join(names)}")
            labels[key] = value
        target = self._target(msg)
        fmt = msg.get("format", "binary")
        if fmt not in ("binary", "json"):
            raise ClientError(POLICY, f"'format' must be 'binary' or 'json', got {fmt!r}")
        cleanup = bool(msg.get("cleanup", True))
        root_speed = msg.get("root_speed", False)
        if not isinstance(root_speed, bool):
            raise ClientError(POLICY, f"'root_speed' must be true or false, got {root_speed!r}")
        pose = msg.get("pose", "input")
        if pose not in POSES:
            raise ClientError(POLICY, f"'pose' must be one of {', '.join(POSES)}, got {pose!r}"[:300])
        try:  # body parts with targets of their own: fixed for the stream (its pool's)
            parts = part_targets(self.model, msg.get("parts"))
        except StyleERDError as e:
            raise ClientError(POLICY, str(e)) from None
        async with self.setup:  # the worker thread shares the interpreter with the stepping: one at a time
            pool = await asyncio.to_thread(
                self._pool,
                msg.get("skeleton") if msg.get("preset") != "model" else None,
                fps,
                cleanup,
                parts,
                root_speed,
                pose,
            )
        self._check_room(count)  # others came in while this one was set up
        pool = self.pools.setdefault(pool.key, pool)  # registered here, on the event loop
        rows = np.array([pool.free.pop() for _ in range(count)])
        pool.stylizer.reset(rows)
        pool.stylizer.configure(rows, labels["input_style"], labels["content"], target)
        self.next_id += 1
        name = msg.get("name")
        stream = Stream(
            self.next_id,
            name[:200] if isinstance(name, str) and name else f"stream-{self.next_id}",
            ws,
            pool,
            rows,
            fmt == "binary",
            bool(msg.get("positions", False)),
            bool(msg.get("fronts", False)),
            private=bool(msg.get("private", False)),
            token=self.token_prefix + secrets.token_urlsafe(16),
            humanoid=bool(msg.get("humanoid", False)),
            confidence=bool(msg.get("confidence", False)),
        )
        pool.streams[stream.id] = stream
        self.streams[stream.id] = stream
        try:  # from here the stream holds a slot: anything that fails gives it back
            for w in self.watchers:
                if w.stream is None and self._follows(w, stream):
                    self._attach(w, stream)
        except BaseException:
            self._close_stream(stream)
            raise
        log.info(
            "stream %d %r opened (%d on the connection): %d joints, %g fps, target %s",
            stream.id,
            stream.name,
            count,
            pool.skeleton.n_joints,
            fps,
            target,
        )
        return stream

    def _pool(self, text: str | None, fps: float, cleanup: bool, parts: dict, root_speed: bool, pose: str) -> Pool:
        """The pool of a hello's skeleton: the existing one, or a new one (not yet registered).
        Runs in a worker thread: reads ``self.pools``, never changes it."""
        try:
            skeleton = self.model.skeleton if text is None else _skeleton_from_text(text, fps, self.config.max_joints)
            key = (
                bvh.format_header(skeleton, 0, fps),
                fps,
                cleanup,
                json.dumps(parts, sort_keys=True),
                root_speed,
                pose,
            )
            existing = self.pools.get(key)
            if existing is not None:
                return existing
            return Pool(
                self.model,
                skeleton,
                fps,
                cleanup,
                self.config.max_streams,
                self.config.backend,
                key,
                parts,
                root_speed,
                pose,
                self.config.threads,
            )
        except StyleERDError as e:
            raise ClientError(POLICY, str(e)) from None

    def _close_stream(self, stream: Stream) -> None:
        log.info(
            "stream %d %r closed after %d frames (%s)", stream.id, stream.name, stream.frames, stream.ws.close_code
        )
        self.streams.pop(stream.id, None)
        pool = stream.pool
        if pool.streams.pop(stream.id, None) is not None:
            pool.free.extend(int(r) for r in stream.rows)
        if not pool.streams:  # a skeleton nobody streams any more holds no memory
            self.pools = {k: p for k, p in self.pools.items() if p is not pool}
        for w in list(stream.watchers):
            w.stream = None
            _offer(w.outbox, json.dumps({"type": "ended", "stream": stream.name}))

    def _ready(self, stream: Stream) -> dict:
        sk, c = stream.pool.skeleton, self.model.config
        private = {"token": stream.token} if stream.private else {}
        return {
            "type": "ready",
            "stream": stream.name,
            "id": stream.id,
            "streams": stream.count,
            **({"server": self.config.server_id} if self.config.server_id else {}),
            **private,
            "channels": stream.pool.stylizer.n_channels,
            "fps": stream.pool.stylizer.fps,
            "joints": list(sk.names),
            "parents": [int(p) for p in sk.parents],
            "styles": list(c.styles),
            "input_styles": list(c.input_styles),
            "contents": list(c.contents),
            "neutral": c.neutral_style,
            "target": self._weights(stream),
            "parts": stream.pool.parts,
            "root_speed": stream.pool.stylizer.stylizer.root_speed,
            **({"humanoid": stream.pool.humanoid_layout()} if stream.humanoid else {}),
            "pose": stream.pool.stylizer.stylizer.pose,
            "mapping": stream.pool.stylizer.map.describe(),
            "queue": self.config.queue,
        }

    def _weights(self, stream: Stream, index: int = 0) -> dict[str, float]:
        w = stream.pool.stylizer.stylizer.blend.end[stream.rows[index]]
        return {s: round(float(x), 6) for s, x in zip(self.model.config.styles, w) if x}

    async def handle(self, ws: MessageConnection) -> None:
        stream = None
        sock = ws.transport.get_extra_info("socket")
        if sock is not None:  # a small kernel buffer: a client that stops reading is noticed in seconds, not megabytes
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        try:
            try:
                first = await asyncio.wait_for(ws.next_message(), HELLO_TIMEOUT_S)
            except TimeoutError:
                raise ClientError(POLICY, f"no hello within {HELLO_TIMEOUT_S:g} s") from None
            msg = _json(first)
            if msg.get("type") == "watch":
                return await self._watch(ws, msg)
            if msg.get("type") == "upload":
                return await self._upload(ws, msg)
            if msg.get("type") != "hello":
                raise ClientError(
                    POLICY, f"the first message must be a hello, a watch or an upload, got type {msg.get('type')!r}"
                )
            stream = await self._open_stream(ws, msg)
            await ws.send(json.dumps(self._ready(stream)))
            ws.deliver_to(functools.partial(self._deliver, stream))
            await ws.wait_closed()
        except ClientError as e:
            log.info("refused %s: %d %s", ws.remote_address, e.code, e)
            self.refusals[e.code] += 1
            await _refuse(ws, e.code, str(e))
        except ConnectionClosed:
            pass
        except Exception as e:  # a bug: this connection ends with a message, the others go on
            log.exception("connection %s failed", ws.remote_address)
            self.refusals[INTERNAL] += 1
            await _refuse(ws, INTERNAL, f"internal error ({type(e).__name__}); the server goes on")
        finally:
            if stream is not None:
                self._close_stream(stream)

    def _deliver(self, stream: Stream, message: Message) -> None:
        """A stream's message, as its connection parses it: a fault ends this connection only."""
        if stream.closing:
            return
        try:
            self._receive(stream, message)
        except ClientError as e:
            log.info("refused %s: %d %s", stream.ws.remote_address, e.code, e)
            self._fail(stream, e.code, str(e))
        except Exception as e:  # a bug: this connection ends with a message, the others go on
            log.exception("connection %s failed", stream.ws.remote_address)
            self._fail(stream, INTERNAL, f"internal error ({type(e).__name__}); the server goes on")

    def _send(self, stream: Stream, message: Message) -> None:
        """A reply to a stream's client, written now; a client that leaves ``queue`` frames' replies unread ends."""
        frame_reply = SEQ.size + 4 * stream.pool.stylizer.n_channels * stream.count  # the least a frame's reply is
        if not send_now(stream.ws, message, self.config.queue * max(len(message), frame_reply)) and not stream.closing:
            self._fail(
                stream, POLICY, f"more than {self.config.queue} stylised frames unsent: the client does not read"
            )

    def _receive(self, stream: Stream, message: Message) -> None:
        n, count = stream.pool.stylizer.n_channels, stream.count
        if isinstance(message, bytes):
            if len(message) != SEQ.size + 4 * n * count:
                each = f"{count} x " if count > 1 else ""
                raise ClientError(
                    POLICY,
                    f"a binary frame is 4 + {each}4 x {n} = {SEQ.size + 4 * n * count} bytes (sequence number + "
                    f"{each}{n} float32 channel values), got {len(message)}",
                )
            values = np.frombuffer(message, "<f4", offset=SEQ.size).reshape(count, n)
            self._enqueue(stream, SEQ.unpack_from(message)[0], values)
            return
        msg = _json(message)
        kind = msg.get("type")
        if kind == "frame":
            self._enqueue(stream, _sequence_number(msg.get("seq", stream.frames)), _frame_values(msg, n, count))
        elif kind == "set":
            self._set_target(stream, msg)
        elif kind == "reset":
            stream.pending.clear()
            stream.pool.stylizer.reset(stream.rows)
            self._send(stream, json.dumps({"type": "reset"}))
        elif kind == "stats":
            self._send(stream, json.dumps(self.stats(stream)))
        else:
            raise ClientError(POLICY, f"unknown message type {kind!r}; valid: frame, set, reset, stats")

    def _enqueue(self, stream: Stream, seq: int, values: np.ndarray) -> None:
        if stream.closing:
            return
        if len(stream.pending) >= self.config.queue:
            # whose fault: a client ahead of real time, or a server behind it (never the client's)
            ahead = stream.frames - stream.pool.stylizer.fps * (time.perf_counter() - stream.opened)
            if ahead > self.config.queue:
                raise ClientError(
                    POLICY,
                    f"more than {self.config.queue} frames waiting, {ahead:.0f} ahead of real time: send no faster "
                    "than the stream's frame rate",
                )
            if len(stream.pending) >= OVERLOAD * self.config.queue:
                raise ClientError(
                    TRY_LATER,
                    f"more than {OVERLOAD * self.config.queue} frames waiting: the server is overloaded; try again "
                    "later",
                )
        stream.pending.append((seq, values, time.perf_counter()))
        stream.frames += 1
        self.due.set()

    def stats(self, asking: Stream | None = None) -> dict:
        """The server's figures; private streams other than the asker's own are not counted (their
        number is nobody else's business)."""
        streams = sum(s.count for s in self.streams.values() if not s.private or s is asking)
        return {
            "type": "stats",
            "streams": streams,
            "frames": self.frames,
            "steps": self.steps,
            "cpu_seconds": time.process_time(),
            "step_cpu_seconds": self.step_cpu,
            "pools": len(self.pools),
        }

    def metrics(self) -> str:
        """The Prometheus text exposition of this process's figures."""
        now = time.perf_counter()
        then, frames_then = self.rate_mark
        self.rate_mark = (now, self.frames)
        label = f'{{server="{self.config.server_id}"}}' if self.config.server_id else ""
        rows = [
            ("streams", "gauge", "open streams (every stream of a connection counts)", self._open_rows()),
            ("connections", "gauge", "open stream connections", len(self.streams)),
            ("watchers", "gauge", "live viewers", len(self.watchers)),
            ("pools", "gauge", "pools (skeleton and settings) being stepped", len(self.pools)),
            (
                "queue_depth",
                "gauge",
                "frames waiting to be stylised",
                sum(len(s.pending) for s in self.streams.values()),
            ),
            ("frames_total", "counter", "frames stylised", self.frames),
            ("steps_total", "counter", "batched steps", self.steps),
            (
                "frames_per_second",
                "gauge",
                "frames stylised a second since the last scrape",
                (self.frames - frames_then) / max(now - then, 1e-9),
            ),
            ("step_cpu_seconds_total", "counter", "CPU seconds in batched steps (the engine)", self.step_cpu),
            ("cpu_seconds_total", "counter", "CPU seconds of the process", time.process_time()),
            ("uptime_seconds", "gauge", "seconds since the process started serving", time.time() - self.started),
        ]
        lines = []
        for name, kind, text, value in rows:
            lines += [
                f"# HELP styleerd_{name} {text}",
                f"# TYPE styleerd_{name} {kind}",
                f"styleerd_{name}{label} {value!r}",
            ]
        lines += [
            "# HELP styleerd_refusals_total connections refused or ended, by close code",
            "# TYPE styleerd_refusals_total counter",
        ]
        server = f'server="{self.config.server_id}",' if self.config.server_id else ""
        lines += [f'styleerd_refusals_total{{{server}code="{code}"}} {n}' for code, n in sorted(self.refusals.items())]
        return "\n".join(lines) + "\n"

    # ---- stepping ----

    async def step_forever(self) -> None:
        while True:
            await self.due.wait()
            self.due.clear()
            while True:
                work = [(pool, [s for s in pool.streams.values() if s.pending]) for pool in self.pools.values()]
                work = [(pool, streams) for pool, streams in work if streams]
                if not work:
                    break
                # a step costs about a millisecond whatever its batch: while other streams' frames are
                # on their way, wait for them (at most batch_wait) and step them together, or small
                # steps back to back take the whole core and leave none for the sockets
                oldest = min(s.pending[0][2] for _, streams in work for s in streams)
                wait = oldest + self.config.batch_wait - time.perf_counter()
                if wait > 0 and sum(len(streams) for _, streams in work) < len(self.streams):
                    await asyncio.sleep(wait)
                    continue
                for pool, streams in work:
                    try:
                        self._step(pool, streams)
                    except Exception:  # a bug anywhere in a step ends only that step's streams, never the stepping task
                        log.exception("step failed for streams %s", [s.id for s in streams])
                        for stream in streams:
                            if not stream.closing:
                                self._fail(stream, INTERNAL, "internal error while stylising this stream")
                await asyncio.sleep(0)  # let replies go out and frames come in

    def _step(self, pool: Pool, streams: list[Stream]) -> None:
        """One frame of each of ``streams`` (each its connection's rows) in one batched step;
        each connection's reply is one message."""
        items = [s.pending.popleft() for s in streams]
        values = np.concatenate([v for _, v, _ in items])
        if not bvh.channel_values_ok(values).all():  # NaN, inf or absurd values (the check transfer makes): refused
            for stream, (seq, v, _) in zip(streams, items):
                bad = bvh.channel_problem(pool.skeleton, v)
                if bad is not None:
                    member = f" of stream {bad[0]}" if stream.count > 1 else ""
                    self._fail(stream, INVALID_DATA, f"frame {seq}{member}: {bad[1]}")
            kept = [(s, item) for s, item in zip(streams, items) if not s.closing]
            if not kept:
                return
            streams, items = [s for s, _ in kept], [item for _, item in kept]
            values = np.concatenate([v for _, v, _ in items])
        rows = np.concatenate([s.rows for s in streams])
        ends = np.cumsum([s.count for s in streams])
        spans = [slice(int(e) - s.count, int(e)) for s, e in zip(streams, ends)]
        cpu = time.process_time()
        try:
            out = pool.stylizer.step(values, rows)
        except StyleERDError:  # a frame the stylizer refuses (no state changed): find it, end only its connection
            out = np.full_like(values, np.nan)
            for stream, span, (seq, _, _) in zip(streams, spans, items):
                try:
                    out[span] = pool.stylizer.step(values[span], rows[span])
                except StyleERDError as e:
                    self._fail(stream, INVALID_DATA, f"frame {seq}: {e}")
        except Exception:  # a bug must not stop every other stream: these streams end, the server goes on
            log.exception("step failed for streams %s", [s.id for s in streams])
            for stream in streams:
                self._fail(stream, INTERNAL, "internal error while stylising this stream")
            return
        finally:
            self.step_cpu += time.process_time() - cpu
        self.steps += 1
        self.frames += len(rows)
        starts = [span.start for span in spans]
        good = np.logical_and.reduceat(np.isfinite(out).all(axis=1), starts).tolist()  # per connection
        for stream, ok, (seq, _, _) in zip(streams, good, items):
            if not ok and not stream.closing:
                self._fail(stream, INTERNAL, f"frame {seq}: the stylised frame is not finite")
        wanted = np.zeros(len(rows), bool)  # rows whose joint positions someone wants
        posed = np.zeros(len(rows), bool)  # and whose humanoid pose
        for stream, span, ok in zip(streams, spans, good):
            if ok and (stream.positions or stream.watchers):
                wanted[span] = True
            if ok and (stream.humanoid or any(w.humanoid for w in stream.watchers)):
                posed[span] = True
        positions = humanoid = None  # [4 or 2, rows, ...] for the rows that want them
        if wanted.any():
            positions = np.zeros((4, len(rows), pool.skeleton.n_joints, 3), np.float32)
            seen, seen_fronts = _joint_positions(pool.skeleton, values[wanted], pool.stylizer.fps, pool.fronts)
            made, made_fronts = _joint_positions(pool.skeleton, out[wanted], pool.stylizer.fps, pool.fronts)
            positions[:, wanted] = seen, made, seen_fronts, made_fronts
        if posed.any():
            seen_pose, made_pose = pool.humanoid_pose(values[posed]), pool.humanoid_pose(out[posed])
            humanoid = np.zeros((2, len(rows), seen_pose.shape[1]), "<f4")
            humanoid[:, posed] = seen_pose, made_pose
        out32 = out.astype("<f4")
        for stream, span, ok, (seq, _, _) in zip(streams, spans, good, items):
            if not ok:
                continue
            pos = None if positions is None else positions[:, span]
            pose = None if humanoid is None else humanoid[:, span]
            if stream.binary:
                parts = [SEQ.pack(seq), out32[span].tobytes()]
                if stream.positions:
                    parts += [p.tobytes() for p in (pos if stream.fronts else pos[:2])]
                if stream.humanoid:
                    parts += [h.tobytes() for h in pose]
                if stream.confidence:
                    parts.append(self._confidence(stream).tobytes())
                message = b"".join(parts)
            else:
                message = json.dumps(self._json_reply(stream, seq, out[span], pos, pose))
            self._send(stream, message)
            for w in stream.watchers:
                k = span.start + w.index
                shown = [p[k] for p in (positions if w.fronts else positions[:2])]
                shown += [h[k] for h in humanoid] if w.humanoid else []
                _offer(w.outbox, SEQ.pack(seq) + b"".join(a.tobytes() for a in shown), drop_oldest=True)

    def _json_reply(
        self, stream: Stream, seq: int, out: np.ndarray, pos: np.ndarray | None, pose: np.ndarray | None
    ) -> dict:
        """A JSON connection's reply to one frame: for one stream, each field as one frame's list;
        for several, as a list of one per stream."""

        def listed(a: np.ndarray, digits: int) -> list:
            values = np.round(a, digits).tolist()
            return values if stream.count > 1 else values[0]

        reply = {"type": "frame", "seq": seq, "values": listed(out, 6)}
        stylizer = stream.pool.stylizer.stylizer
        if stylizer.pose == "input":  # how far the network's own pose was left for the input's
            reply["unfamiliar"] = listed(stylizer.unfamiliar[stream.rows], 3)
        if _reads_style(stylizer, stream.rows):
            reply["unread"] = listed(stylizer.unread[stream.rows], 3)  # how far the input's style went unread (neutral)
        if stream.positions:
            reply["input_positions"], reply["output_positions"] = listed(pos[0], 4), listed(pos[1], 4)
            if stream.fronts:
                reply["input_fronts"], reply["output_fronts"] = listed(pos[2], 4), listed(pos[3], 4)
        if stream.humanoid:
            reply["input_humanoid"], reply["output_humanoid"] = (listed(h, 5) for h in pose)
        return reply

    @staticmethod
    def _confidence(stream: Stream) -> np.ndarray:
        """A binary reply's last block, ``float32 [K][2]``: per stream its frame's unfamiliar and
        unread, each 0 where it is not measured (``pose`` "network"; the input's style given)."""
        stylizer, rows = stream.pool.stylizer.stylizer, stream.rows
        out = np.zeros((len(rows), 2), "<f4")
        if stylizer.pose == "input":
            out[:, 0] = stylizer.unfamiliar[rows]
        if _reads_style(stylizer, rows):
            out[:, 1] = stylizer.unread[rows]
        return out

    def _fail(self, stream: Stream, code: int, message: str) -> None:
        """End a stream from the stepping task: its frames stop here, the client is told."""
        stream.closing = True
        stream.pending.clear()
        self.refusals[code] += 1
        asyncio.ensure_future(_refuse(stream.ws, code, message))

    # ---- live viewers ----

    @staticmethod
    def _follows(watcher: Watcher, stream: Stream) -> bool:
        # as bytes: compare_digest raises on a str with non-ASCII characters
        if stream.private and not secrets.compare_digest(watcher.token.encode(), stream.token.encode()):
            return False
        return watcher.index < stream.count and (watcher.name is None or watcher.name == stream.name)

    def _set_target(self, stream: Stream, msg: dict) -> None:
        """A ``set``: a new target for the connection's streams, or for those listed in ``streams``
        (their indices on the connection)."""
        which = msg.get("streams", list(range(stream.count)))
        if not (
            isinstance(which, list)
            and which
            and all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < stream.count for i in which)
        ):
            raise ClientError(
                POLICY, f"a set's 'streams' must be a list of this connection's stream indices, 0 to {stream.count - 1}"
            )
        stream.pool.stylizer.stylizer.set_target(self._target(msg), stream.rows[which])
        reply = {"type": "target", "weights": self._weights(stream, which[0])}
        if stream.count > 1:
            reply["streams"] = which
        reply = json.dumps(reply)
        self._send(stream, reply)
        for w in stream.watchers:
            _offer(w.outbox, reply, drop_oldest=True)

    def _attach(self, watcher: Watcher, stream: Stream) -> None:
        watcher.stream = stream
        stream.watchers.add(watcher)
        sk = stream.pool.skeleton
        _offer(
            watcher.outbox,
            json.dumps(
                {
                    "type": "watching",
                    "stream": stream.name,
                    "joints": list(sk.names),
                    "parents": [int(p) for p in sk.parents],
                    "target": self._weights(stream, watcher.index),
                    "index": watcher.index,
                    **({"humanoid": stream.pool.humanoid_layout()} if watcher.humanoid else {}),
                }
            ),
            drop_oldest=True,
        )

    async def _watch(self, ws: MessageConnection, msg: dict) -> None:
        name, token, index = msg.get("stream"), msg.get("token", ""), msg.get("index", 0)
        if len(self.watchers) >= self.config.max_watchers:
            raise ClientError(
                TRY_LATER, f"this server has its {self.config.max_watchers} live viewers; try again later"
            )
        if not isinstance(token, str) or len(token) > MAX_TOKEN:
            raise ClientError(
                POLICY, f"'token' must be the text a private stream's 'ready' carried (at most {MAX_TOKEN} characters)"
            )
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < self.config.max_streams:
            raise ClientError(POLICY, "'index' is which of a connection's streams to watch: an integer from 0")
        watcher = Watcher(
            ws,
            name if isinstance(name, str) else None,
            asyncio.Queue(self.config.queue),
            fronts=bool(msg.get("fronts", False)),
            token=token,
            humanoid=bool(msg.get("humanoid", False)),
            index=index,
        )
        self.watchers.add(watcher)
        sender = None
        try:  # the watcher is released however its connection ends
            candidates = [s for s in self.streams.values() if self._follows(watcher, s)]
            await ws.send(
                json.dumps({"type": "waiting", "streams": [s.name for s in self.streams.values() if not s.private]})
            )
            if candidates:
                self._attach(watcher, candidates[-1])
            sender = asyncio.create_task(_send_loop(ws, watcher.outbox))
            while True:  # a viewer may steer the style of the stream it watches
                msg = _json(await ws.next_message())
                if msg.get("type") != "set":
                    raise ClientError(POLICY, f"a watcher may send only 'set' messages, got type {msg.get('type')!r}")
                if watcher.stream is not None:  # the stream it shows, unless it lists others
                    self._set_target(watcher.stream, {"streams": [watcher.index], **msg})
        finally:
            self.watchers.discard(watcher)
            if watcher.stream is not None:
                watcher.stream.watchers.discard(watcher)
            if sender is not None:
                sender.cancel()

    async def _upload(self, ws: MessageConnection, msg: dict) -> None:
        """A page's file, announced (``purpose``: motion or avatar, ``name``, ``bytes``) and sent in
        binary pieces of at most ``max_message``: read (``serve.uploads``) and answered with one
        message, ``{"type": purpose, ...}``; the connection then closes."""
        purpose, name, size = msg.get("purpose"), msg.get("name"), msg.get("bytes")
        kinds = {"motion": MOTIONS, "avatar": AVATARS}
        if purpose not in kinds:
            raise ClientError(POLICY, "an upload's 'purpose' is 'motion' or 'avatar'")
        if not isinstance(name, str) or not 0 < len(name) <= 255:
            raise ClientError(POLICY, "an upload's 'name' is the file's name (at most 255 characters)")
        suffix = Path(name.replace("\\", "/")).suffix.lower()
        if suffix not in kinds[purpose]:
            what = "an avatar" if purpose == "avatar" else "a motion"
            raise ClientError(POLICY, f"{name[:80]!r}: {what} to upload is a {' or '.join(kinds[purpose])} file")
        if isinstance(size, bool) or not isinstance(size, int) or not 0 < size <= MAX_UPLOAD:
            raise ClientError(POLICY, f"an upload's 'bytes' is its size, 1 to {MAX_UPLOAD} (got {str(size)[:20]})")
        if self.uploads >= UPLOADS_AT_ONCE:
            raise ClientError(TRY_LATER, f"this server is reading {UPLOADS_AT_ONCE} files; try again in a moment")
        self.uploads += 1
        try:
            data = bytearray()
            while len(data) < size:
                try:
                    piece = await asyncio.wait_for(ws.next_message(), UPLOAD_WAIT_S)
                except TimeoutError:
                    raise ClientError(POLICY, f"{name[:80]!r}: no data for {UPLOAD_WAIT_S:g} s") from None
                if isinstance(piece, str):
                    raise ClientError(POLICY, f"{name[:80]!r}: a file's bytes come as binary messages")
                data += piece
                if len(data) > size:
                    raise ClientError(POLICY, f"{name[:80]!r}: more than the {size} bytes announced")
            result = await self._read_upload(purpose, name, suffix, bytes(data))
            glb = result.pop("glb", None)  # an FBX avatar made a GLB: its bytes follow the answer
            await ws.send(
                json.dumps({"type": purpose, "name": name, **result, "glb": None if glb is None else len(glb)})
            )
            if glb is not None:
                await ws.send(glb)
        finally:
            self.uploads -= 1

    async def _read_upload(self, purpose: str, name: str, suffix: str, data: bytes) -> dict:
        """``serve.uploads``'s reading of an uploaded file, on a thread, in a folder of its own."""
        with tempfile.TemporaryDirectory(prefix="styleerd-upload-") as folder:
            path = Path(folder) / f"upload{suffix}"
            path.write_bytes(data)
            read = motion_bvh if purpose == "motion" else functools.partial(avatar_rig, model=self.model)
            try:
                return await asyncio.wait_for(asyncio.to_thread(read, path), CONVERT_S)
            except StyleERDError as e:  # the reader names the file by its path here: by its own name there
                message = str(e).replace(str(path), name[:80])
                message = message if message.startswith(name[:80]) else f"{name[:80]}: {message}"
                raise ClientError(INVALID_DATA, message[:500]) from None
            except TimeoutError:
                raise ClientError(TRY_LATER, f"{name[:80]!r}: not read within {CONVERT_S:g} s") from None

    # ---- HTTP: the viewer page, its files, demo clips, the list of streams ----

    async def http(self, connection: ServerConnection, request: Request) -> Response | None:
        hosts, origins = request.headers.get_all("Host"), request.headers.get_all("Origin")
        if len(hosts) > 1 or len(origins) > 1:
            return _response(HTTPStatus.BAD_REQUEST, b"one Host and at most one Origin header, please", "text/plain")
        host = hosts[0] if hosts else ""
        try:
            name = urlsplit(f"//{host}").hostname or ""
        except ValueError:  # not a host at all
            name = ""
        if self.host_names is not None and name.lower() not in self.host_names:
            return _response(
                HTTPStatus.FORBIDDEN,
                f"this server does not answer to host {host!r} (serve --allow-host)".encode(),
                "text/plain",
            )
        if "upgrade" in request.headers.get("Connection", "").lower():
            if not _origin_allowed(origins[0] if origins else None, host, self.config.origins):
                return _response(
                    HTTPStatus.FORBIDDEN,
                    b"a page of another origin may not open a stream here (serve --allow-origin)",
                    "text/plain",
                )
            return None  # a WebSocket handshake
        if len(request.path) > 2048:
            return _response(HTTPStatus.REQUEST_URI_TOO_LONG, b"the path is too long", "text/plain")
        if request.method not in ("GET", "HEAD"):
            return _response(HTTPStatus.METHOD_NOT_ALLOWED, b"GET or HEAD only", "text/plain")
        path, _, query = request.path.partition("?")
        try:
            # the server's own figures on the event loop, which alone changes them; files in a
            # worker thread: reading a 14 MB file or making the browser step's graph and
            # reference clip (up to a second) must not stall the streams' stepping loop
            response = self._status_page(path) or await asyncio.to_thread(self._page, path, parse_qs(query))
        except (OSError, StyleERDError, ValueError) as e:  # a name the file system refuses, a clip that cannot be read
            response = _response(HTTPStatus.NOT_FOUND, f"not found: {e}".encode(errors="replace"), "text/plain")
        if request.method == "HEAD":  # the GET's headers, Content-Length included, and no body
            return Response(response.status_code, response.reason_phrase, response.headers, b"")
        return response

    def _status_page(self, path: str) -> Response | None:
        """``/healthz``, ``/metrics`` and ``/streams``: read from the streams on the event loop
        (a worker thread could see them change as it reads), else None."""
        if path == "/healthz":  # a balancer's check: 503 when full, so new streams go to another process
            streams = self._open_rows()
            full = streams >= self.config.max_streams
            body = {"status": "full" if full else "ok", "server": self.config.server_id, "streams": streams}
            return _response(
                HTTPStatus.SERVICE_UNAVAILABLE if full else HTTPStatus.OK, json.dumps(body).encode(), "application/json"
            )
        if path == "/metrics":
            return _response(HTTPStatus.OK, self.metrics().encode(), "text/plain; version=0.0.4; charset=utf-8")
        if path == "/streams":
            body = [{"stream": s.name, "frames": s.frames} for s in self.streams.values() if not s.private]
            return _response(HTTPStatus.OK, json.dumps(body).encode(), "application/json")
        return None

    def _engine_file(self, name: str, query: dict[str, list[str]]) -> bytes | None:
        """The files the in-browser step (static/engine.html) reads: the step graph and its
        JSON (exported from this server's model once, then kept), and a reference clip on the
        model's skeleton with this server's stylisation of it."""
        if name in ("stylizer.onnx", "stylizer.json"):
            if self._engine is None:
                proto = step_graph(self.model, "lstm")
                self._engine = {
                    "stylizer.onnx": proto.SerializeToString(),
                    "stylizer.json": json.dumps(sidecar(self.model, proto, "stylizer.onnx")).encode(),
                }
            return self._engine[name]
        if name == "reference.json":
            key = (query.get("style") or ["elderly"])[0], (query.get("clip") or ["walk"])[0]
            if key not in self._references:  # only the model's styles and the clips get here: others are refused
                self._references[key] = reference_clip(self.model, *key)
            return self._references[key]
        return None

    def _page(self, path: str, query: dict[str, list[str]] | None = None) -> Response:
        query = query or {}
        if path == "/favicon.ico":
            return _response(HTTPStatus.NO_CONTENT, b"", "image/x-icon")
        if path == "/":
            path = "/static/index.html"
        if path.startswith("/static/"):
            file = (STATIC / path[len("/static/") :]).resolve()
            if STATIC.resolve() in file.parents and file.is_file():
                kind = mimetypes.guess_type(file.name)[0] or "application/octet-stream"
                return _response(HTTPStatus.OK, file.read_bytes(), kind)
            if path.endswith("three.module.js"):
                return _response(
                    HTTPStatus.NOT_FOUND, b"three.js is not installed: run 'make install' (npm ci)", "text/plain"
                )
        elif path == "/clips":
            return _response(HTTPStatus.OK, json.dumps(self.clips.names()).encode(), "application/json")
        elif path.startswith("/clips/"):
            text = self.clips.bvh_text(path[len("/clips/") :])
            if text is not None:
                return _response(HTTPStatus.OK, text.encode(), "text/plain; charset=utf-8")
        elif path.startswith("/onnx/"):
            body = self._engine_file(path[len("/onnx/") :], query)
            if body is not None:
                return _response(
                    HTTPStatus.OK, body, "application/octet-stream" if path.endswith(".onnx") else "application/json"
                )
        elif path == "/styles":
            c = self.model.config
            body = {
                "styles": list(c.styles),
                "input_styles": list(c.input_styles),
                "contents": list(c.contents),
                "neutral": c.neutral_style,
            }
            return _response(HTTPStatus.OK, json.dumps(body).encode(), "application/json")
        return _response(HTTPStatus.NOT_FOUND, f"not found: {path}".encode(), "text/plain")


def _response(status: HTTPStatus, body: bytes, kind: str) -> Response:
    headers = Headers([("Content-Type", kind), ("Content-Length", str(len(body))), ("Cache-Control", "no-store")])
    return Response(status.value, status.phrase, headers, body)


def _frame_values(msg: dict, n: int, count: int) -> np.ndarray:
    """A JSON frame's ``values`` as ``[count, n]``: a list of ``n`` numbers, or, for a connection
    of ``count`` > 1 streams, a list of ``count`` such lists."""
    values = msg.get("values")
    rows = values if count > 1 and isinstance(values, list) else [values]
    if len(rows) != count or not all(
        isinstance(r, list) and len(r) == n and all(isinstance(v, (int, float)) for v in r) for r in rows
    ):
        what = f"a list of {count} lists of {n} numbers (one per stream)" if count > 1 else f"a list of {n} numbers"
        raise ClientError(POLICY, f"a frame's 'values' must be {what}")
    return np.asarray(rows, np.float64)


def _sequence_number(value) -> int:
    """A JSON frame's ``seq``: an integer that fits the binary replies' uint32."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not float(value).is_integer()
        or not 0 <= value <= 0xFFFFFFFF
    ):
        raise ClientError(INVALID_DATA, f"a frame's 'seq' must be an integer in 0..{0xFFFFFFFF}, got {value!r}")
    return int(value)


def _reads_style(stylizer, rows: np.ndarray) -> bool:
    """Whether the labeller reads some of these streams' input style with a measure of how far it
    went unread (``StreamStylizer.unread``)."""
    labeller = stylizer.labeller
    return labeller is not None and labeller.familiar is not None and not stylizer.known_style[rows].all()


def _joint_positions(
    skeleton: Skeleton, values: np.ndarray, fps: float, rest_fronts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Global joint positions ``[N, J, 3]`` and bone fronts ``[N, J, 3]`` (float32: the unit
    front of the bone from each joint's parent, turned with the parent, so a viewer can show
    its roll) of channel values ``[N, channels]``."""
    m = bvh.motion_from_channels(skeleton, values, fps)
    g_rot, g_pos = forward_kinematics(m.rotations, m.positions, skeleton.parents)
    fronts = quat.mul_vec(g_rot[:, np.maximum(skeleton.parents, 0)], rest_fronts)
    return g_pos.astype(np.float32), fronts.astype(np.float32)


def _json(message: bytes | str) -> dict:
    if isinstance(message, bytes):
        raise ClientError(POLICY, "expected a JSON text message here, got binary")
    try:
        msg = json.loads(message)
    except json.JSONDecodeError as e:
        raise ClientError(POLICY, f"bad JSON: {e}") from None
    if not isinstance(msg, dict):
        raise ClientError(POLICY, "a JSON message must be an object with a 'type'")
    return msg


def _offer(queue: asyncio.Queue, message, drop_oldest: bool = False) -> bool:
    """Queue a message without waiting; when full, drop the oldest (viewers) or say so."""
    if queue.full():
        if not drop_oldest:
            return False
        queue.get_nowait()
    queue.put_nowait(message)
    return True


async def _send_loop(ws: ServerConnection, outbox: asyncio.Queue) -> None:
    try:
        while True:
            await ws.send(await outbox.get())
    except ConnectionClosed:
        pass


async def _refuse(ws: ServerConnection, code: int, message: str) -> None:
    """Tell the client what is wrong, then close with ``code``; a client that does not read
    cannot be told, and its connection is dropped."""
    try:
        await asyncio.wait_for(ws.send(json.dumps({"type": "error", "code": code, "message": message})), 2.0)
        await asyncio.wait_for(ws.close(code, message[:120]), 4.0)  # a close reason is at most 123 bytes
    except (ConnectionClosed, TimeoutError):
        ws.transport.abort()


async def run_server(
    config: ServeConfig,
    reuse_port: bool = False,
    ready: multiprocessing.synchronize.Event | None = None,
    announce=print,
) -> None:
    """Serve until SIGINT/SIGTERM; then every client gets a clean close (1001, going away)."""
    server = StyleServer(config)
    announce(f"styleerd serve: warming the {config.backend} engine (the first start after an install compiles it)")
    server.warm_up()
    stepper = asyncio.create_task(server.step_forever())
    stop = asyncio.get_running_loop().create_future()
    for sig in (signal.SIGINT, signal.SIGTERM):
        asyncio.get_running_loop().add_signal_handler(sig, lambda: stop.done() or stop.set_result(None))
    async with serve(
        server.handle,
        config.host,
        config.port,
        process_request=server.http,
        max_size=config.max_message,
        max_queue=config.queue,
        create_connection=MessageConnection,
        reuse_port=reuse_port,
        ping_interval=20,
        close_timeout=2,
        compression=None,
    ) as ws_server:  # float frames barely compress; deflate cost a fifth of the CPU
        announce(
            f"styleerd serve: ws://{config.host}:{config.port}/  viewer: http://{config.host}:{config.port}/  "
            f"({config.backend} backend)"
        )
        if ready is not None:
            ready.set()
        await stop
        ws_server.close(code=GOING_AWAY, reason="server shutting down")
        await ws_server.wait_closed()
    stepper.cancel()


def _setup_logging() -> None:
    """One line per stream opened, closed or refused; websockets' own chatter only when wrong."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(process)d %(message)s")
    logging.getLogger("websockets").setLevel(logging.WARNING)


def _run(loop: str, main) -> None:
    """``main`` on uvloop's event loop (libuv: fewer CPU cycles a message) where it is installed
    and not refused (``loop``: auto, uvloop or asyncio), else on asyncio's own."""
    factory = None
    if loop != "asyncio":
        try:
            import uvloop

            factory = uvloop.new_event_loop
        except ImportError:
            if loop == "uvloop":
                raise StyleERDError("--loop uvloop: uvloop is not installed (pip install uvloop)") from None
    with asyncio.Runner(loop_factory=factory) as runner:
        runner.run(main)


def _worker(config: ServeConfig, ready) -> None:
    _setup_logging()
    _run(config.loop, run_server(config, reuse_port=True, ready=ready, announce=lambda _: None))


def serve_forever(config: ServeConfig, workers: int = 1) -> None:
    """``workers`` processes on one port (SO_REUSEPORT: the kernel spreads connections)."""
    _setup_logging()
    if workers <= 1:
        try:
            _run(config.loop, run_server(config))
        except OSError as e:  # the address is taken or cannot be bound
            raise StyleERDError(f"cannot serve on {config.host}:{config.port}: {e.strerror or e}") from None
        return

    def interrupt(*_):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)  # the workers then get SIGTERM: a clean close each
    ctx = multiprocessing.get_context("spawn")
    events = [ctx.Event() for _ in range(workers)]
    procs = [ctx.Process(target=_worker, args=(config, e), daemon=True) for e in events]
    try:
        for p in procs:
            p.start()
        for p, e in zip(procs, events):
            while not e.wait(0.2):
                if not p.is_alive():  # it could not bind (the port is taken): say so once, stop the rest
                    raise StyleERDError(
                        f"cannot serve on {config.host}:{config.port}: a worker could not start (is the port in use?)"
                    )
        print(
            f"styleerd serve: {workers} workers on ws://{config.host}:{config.port}/  viewer: http://{config.host}:{config.port}/",
            flush=True,
        )
        for p in procs:
            p.join()
    except KeyboardInterrupt:
        pass
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join()
