"""A mocap source for the style server: play a BVH in real time over the WebSocket protocol
(``styleerd stream-bvh``), and many of them at once (the load test, ``styleerd load-test``)."""

from __future__ import annotations

import asyncio
import functools
import json
import socket
import struct
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus, InvalidURI

from styleerd.errors import StyleERDError
from styleerd.motion import bvh
from styleerd.motion.motion import Motion

SEQ = struct.Struct("<I")
LABELS = ("normal", "walk")  # the load test's clip (a procedural neutral walk): its input style and content
PHASE = 7  # frames between the clip's start for consecutive streams of one connection (a crowd not in lockstep)
IN_FLIGHT = 16  # frames sent ahead of their replies when not in real time (the server queues 64 by default)


@dataclass
class StreamResult:
    """What one client's stream to the server gave: frames sent and received, order, latency, errors."""

    sent: int = 0
    received: int = 0
    reordered: int = 0  # replies whose sequence number is not the next one expected
    latencies_ms: list[float] = field(default_factory=list)
    late_sends: int = 0  # frames the client itself sent more than a frame late (an overloaded client)
    error: str | None = None  # the server's error message, if it closed the stream
    error_at: float | None = None  # seconds into the stream
    close_code: int | None = None
    output: np.ndarray | None = None  # the stylised channel values, when kept
    max_error: float = 0.0  # largest difference from ``reference`` (float32 on the wire), when given
    reconnects: int = 0  # connections opened again after one was lost (``play(reconnect=True)``)
    lost_at: float | None = None  # perf_counter when the first lost connection was noticed
    reconnected_ms: float | None = None  # from then to the first stylised frame on a new connection
    resent: int = 0  # frames sent, never answered on a lost connection, and sent again on the next
    # with the hello's "confidence": per frame and stream, summed: unfamiliar, unread, and frames unfamiliar > 0.5
    confidence: np.ndarray = field(default_factory=lambda: np.zeros(3))


def hello(
    motion: Motion,
    fps: float,
    style: str | None,
    intensity: float,
    mix: dict[str, float] | None,
    name: str | None,
    input_style: str | None = None,
    content: str | None = None,
) -> dict:
    """The JSON hello that opens a stream of ``motion``'s skeleton at ``fps`` (``docs/PROTOCOL.md``)."""
    msg = {
        "type": "hello",
        "skeleton": bvh.format_header(motion.skeleton, 0, fps),
        "fps": fps,
        "intensity": intensity,
        "format": "binary",
    }
    for key, value in (
        ("style", style),
        ("mix", mix),
        ("name", name),
        ("input_style", input_style),
        ("content", content),
    ):
        if value is not None:
            msg[key] = value
    return msg


RECONNECT_CODES = {1001, 1006, 1011, 1012, 1013}  # going away, lost, a server fault, restart, overloaded: try again
BACKOFF_S = (0.1, 0.2, 0.5, 1.0, 2.0, 4.0, 8.0)  # waits before each reconnection attempt; then give up


async def play(
    url: str,
    motion: Motion,
    hello_msg: dict,
    seconds: float | None = None,
    keep: bool = False,
    realtime: bool = True,
    reference: np.ndarray | None = None,
    reconnect: bool = False,
    say=None,
) -> StreamResult:
    """Send the motion's frames (looped until ``seconds`` when given) at its frame rate (or,
    not ``realtime``, as fast as replies come: at most ``IN_FLIGHT`` unanswered), one binary
    message each, and collect the replies; returns what was sent and received, and how far the
    replies are from ``reference`` (the expected output of every frame sent) when given. A hello
    of ``streams`` K > 1 opens K streams on the connection: stream k plays the clip from frame
    ``PHASE * k``, and every message carries one frame of each (``reference``: ``[T, K, C]``).

    ``reconnect``: a connection lost or closed by a server going away (``RECONNECT_CODES``)
    is opened again after ``BACKOFF_S`` waits (a balancer sends it to a live process), the hello
    sent again, and the frames from the first unanswered one sent again; ``say`` is told each time.
    It gives up after ``len(BACKOFF_S)`` attempts in a row that brought no reply."""
    clip = bvh.channel_values(motion).astype("<f4")
    fps, count = float(hello_msg["fps"]), int(hello_msg.get("streams", 1))
    total = len(clip) if seconds is None else int(round(seconds * fps))
    phases = PHASE * np.arange(count)
    result = StreamResult()
    sent_at = np.zeros(total)
    kept = np.zeros((total, count, clip.shape[1]), np.float32) if keep else None
    failures = 0  # connections in a row that gave no reply
    while True:
        before, refused = result.received, None
        try:
            await _play_once(url, hello_msg, clip, total, phases, realtime, result, sent_at, kept, reference)
        except ConnectionClosed as e:
            result.close_code = e.rcvd.code if e.rcvd else 1006
        except (OSError, InvalidURI, InvalidStatus, TimeoutError) as e:
            # a balancer with no live process behind it yet answers 502-504: worth another try
            unavailable = isinstance(e, InvalidStatus) and e.response.status_code in (502, 503, 504)
            if not reconnect or not (unavailable or isinstance(e, (OSError, TimeoutError))):
                raise StyleERDError(f"{url}: cannot connect ({e})") from None
            result.close_code, refused = 1006, e
        failures = 0 if result.received > before else failures + 1
        if failures == len(BACKOFF_S) and refused is not None:
            raise StyleERDError(f"{url}: cannot connect ({refused}); gave up after {failures} attempts")
        if (
            result.received >= total * count
            or not reconnect
            or result.close_code not in RECONNECT_CODES
            or failures == len(BACKOFF_S)
        ):
            break
        result.lost_at = result.lost_at or time.perf_counter()
        result.error = None  # the going-away message of a server that ended: this stream goes on
        if say is not None:
            say(
                f"{url}: the connection was lost (code {result.close_code}) after {result.received // count} frames; "
                f"reconnecting in {BACKOFF_S[failures]:g} s"
            )
        await asyncio.sleep(BACKOFF_S[failures])
        result.reconnects += 1
    if kept is not None:
        result.output = kept[: result.received // count].astype(np.float64)
        result.output = result.output if count > 1 else result.output[:, 0]
    return result


async def _play_once(
    url: str,
    hello_msg: dict,
    clip: np.ndarray,
    total: int,
    phases: np.ndarray,
    realtime: bool,
    result: StreamResult,
    sent_at: np.ndarray,
    kept: np.ndarray | None,
    reference: np.ndarray | None,
) -> None:
    """One connection of ``play``: from the first frame without a reply to the last."""
    fps, count = float(hello_msg["fps"]), len(phases)
    first = result.received // count
    result.resent += result.sent - result.received
    result.sent = result.received  # frames sent and never answered are sent again
    async with connect(url, max_size=1 << 22, open_timeout=20, close_timeout=5, compression=None) as ws:
        await ws.send(json.dumps(hello_msg))
        ready = json.loads(await ws.recv())
        if ready.get("type") != "ready":
            raise StyleERDError(f"{url}: the server refused the stream: {ready.get('message', ready)}")
        replied = asyncio.Event()

        async def receive() -> None:
            try:
                await receive_replies()
            finally:
                replied.set()  # a sender waiting for replies stops waiting

        async def receive_replies() -> None:
            expected = first
            async for message in ws:
                if isinstance(message, str):
                    reply = json.loads(message)
                    if reply.get("type") == "error":
                        result.error, result.error_at = reply["message"], time.perf_counter() - start
                    continue
                seq = SEQ.unpack_from(message)[0]
                now = time.perf_counter()
                result.latencies_ms.append((now - sent_at[seq]) * 1e3)
                if result.lost_at is not None and result.reconnected_ms is None:
                    result.reconnected_ms = (now - result.lost_at) * 1e3
                result.reordered += seq != expected
                expected = seq + 1
                if hello_msg.get("confidence"):  # the last block: unfamiliar and unread per stream
                    c = np.frombuffer(message, "<f4", count=2 * count, offset=len(message) - 8 * count).reshape(
                        count, 2
                    )
                    result.confidence += (c[:, 0].sum(), c[:, 1].sum(), (c[:, 0] > 0.5).sum())
                if kept is not None or reference is not None:
                    out = np.frombuffer(message, "<f4", count=clip.shape[1] * count, offset=SEQ.size)
                    out = out.reshape(count, -1)
                    if kept is not None:
                        kept[seq] = out
                    if reference is not None:
                        expect = reference[seq] if count > 1 else reference[seq][None]
                        result.max_error = max(result.max_error, float(np.abs(out - expect).max()))
                result.received += count
                replied.set()
                if result.received == total * count:
                    return

        receiver = asyncio.create_task(receive())
        receiver.add_done_callback(lambda t: t.cancelled() or t.exception())  # raised again below, or moot
        start = time.perf_counter() - first / fps
        for i in range(first, total):
            if realtime:
                due = start + i / fps
                wait = due - time.perf_counter()
                if wait > 0:
                    await asyncio.sleep(wait)
                elif wait < -1.0 / fps:
                    result.late_sends += 1
            else:
                while (
                    result.sent - result.received >= count * min(IN_FLIGHT, max(1, ready.get("queue", IN_FLIGHT) // 2))
                    and not receiver.done()
                ):
                    replied.clear()
                    await asyncio.wait_for(replied.wait(), 30.0)
            if receiver.done():
                break
            sent_at[i] = time.perf_counter()
            await ws.send(SEQ.pack(i) + clip[(i + phases) % len(clip)].tobytes())
            result.sent += count
        try:
            await asyncio.wait_for(asyncio.shield(receiver), 10.0)
        except TimeoutError:
            receiver.cancel()
        receiver.result()  # a lost connection raises here


def stream_bvh(
    path: str,
    url: str,
    style: str | None,
    intensity: float,
    mix: dict[str, float] | None,
    output: str | None = None,
    input_style: str | None = None,
    content: str | None = None,
    realtime: bool = True,
    root_speed: bool = False,
    reconnect: bool = False,
) -> str:
    """``styleerd stream-bvh``: play a BVH file to the server in real time; optionally write
    the stylised stream as a BVH; with ``reconnect``, a lost connection is opened again (said
    on stderr). Returns a summary."""
    motion = bvh.read(path)
    if motion.n_frames == 0:
        raise StyleERDError(f"{path}: the motion has no frames")
    msg = hello(motion, motion.fps, style, intensity, mix, Path(path).stem, input_style, content)
    msg["confidence"] = True
    if root_speed:
        msg["root_speed"] = True
    say = functools.partial(print, file=sys.stderr, flush=True)
    result = asyncio.run(
        play(url, motion, msg, keep=output is not None, realtime=realtime, reconnect=reconnect, say=say)
    )
    if result.error:
        raise StyleERDError(f"the server closed the stream: {result.error}")
    if output is not None and result.received == motion.n_frames:
        out = bvh.motion_from_channels(motion.skeleton, result.output, motion.fps)
        bvh.write(output, out)
    lat = np.array(result.latencies_ms) if result.latencies_ms else np.zeros(1)
    return (
        f"{path}: sent {result.sent} frames at {motion.fps:g} fps, received {result.received}, reordered "
        f"{result.reordered}; "
        f"latency p50 {np.percentile(lat, 50):.2f} ms, p99 {np.percentile(lat, 99):.2f} ms"
        + _confidence_summary(result)
        + (
            f"; reconnected {result.reconnects} time(s), the first stylised frame {result.reconnected_ms:.0f} ms "
            "after the connection was lost"
            if result.reconnects and result.reconnected_ms is not None
            else ""
        )
        + (f"; wrote {output}" if output else "")
    )


def _confidence_summary(result: StreamResult) -> str:
    """How unlike the model's training the stream was, as the server measured it frame by frame."""
    if not result.received:
        return ""
    unfamiliar, unread, far = result.confidence / result.received
    return (
        f"; unfamiliar mean {unfamiliar:.2f} ({100 * far:.0f} % of frames above 0.5: the input's own pose turned "
        f"by the style), unread mean {unread:.2f}"
    )


async def server_stats(url: str) -> dict:
    """The server's counters (streams, frames, steps, CPU seconds), through a short stream."""
    from styleerd.motion.procedural import walk

    async with connect(url, open_timeout=20, compression=None) as ws:
        await ws.send(json.dumps(hello(walk(0.1, fps=30.0), 30.0, "normal", 1.0, None, "stats")))
        await ws.recv()
        await ws.send(json.dumps({"type": "stats"}))
        while True:
            reply = json.loads(await ws.recv())
            if reply.get("type") == "stats":
                return reply


FAULTS = ("malformed frame", "slow reader", "vanishes", "bad hello")
_BAD_MESSAGES = (
    lambda n: SEQ.pack(0) + b"\0" * (4 * n - 2),
    lambda n: SEQ.pack(0) + np.full(n, np.nan, "<f4").tobytes(),
    lambda n: "{not json",
    lambda n: json.dumps({"type": "frame", "seq": 2**40, "values": [0.0] * n}),
    lambda n: json.dumps({"type": "set", "style": "zombie"}),
)


async def faulty_client(url: str, motion: Motion, kind: str, seed: int) -> dict:
    """One episode of a faulty client of ``kind`` (see ``FAULTS``) -> what happened: the close
    code the server sent, or how the connection ended."""
    rng = np.random.default_rng(seed)
    values = bvh.channel_values(motion).astype("<f4")
    msg = hello(motion, 30.0, "elderly", 1.0, None, f"faulty-{seed}")
    if kind == "bad hello":
        msg = [
            {**msg, "fps": float("nan")},
            {**msg, "mix": {"elderly": -1}},
            {**msg, "skeleton": "HIERARCHY\nROOT"},
            {"type": "hello"},
        ][int(rng.integers(4))]
    outcome = {"kind": kind, "code": None}
    sock = socket.socket()
    if kind == "slow reader":  # a small receive buffer: the server's replies back up in seconds, not minutes
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    try:
        where = urlsplit(url)
        sock.setblocking(False)
        await asyncio.wait_for(asyncio.get_running_loop().sock_connect(sock, (where.hostname, where.port or 80)), 20)
        async with connect(
            url, sock=sock, max_size=1 << 22, open_timeout=20, close_timeout=2, compression=None, max_queue=1
        ) as ws:
            await ws.send(json.dumps(msg, allow_nan=True))
            if json.loads(await ws.recv()).get("type") != "ready":
                await ws.recv()  # the close
            frames = int(rng.integers(5, 60)) if kind != "slow reader" else 30 * 30
            for i in range(frames):  # real time; the slow reader never reads a reply
                await ws.send(SEQ.pack(i) + values[i % len(values)].tobytes())
                await asyncio.sleep(1 / 30)
            if kind == "vanishes":
                ws.transport.abort()  # no close handshake
                outcome["code"] = "vanished"
                return outcome
            if kind == "malformed frame":
                await ws.send(_BAD_MESSAGES[int(rng.integers(len(_BAD_MESSAGES)))](values.shape[1]))
                while True:
                    await ws.recv()
            outcome["code"] = "never closed"  # a slow reader the server did not drop in 30 s
    except ConnectionClosed as e:
        outcome["code"] = e.rcvd.code if e.rcvd else "dropped"
    except (OSError, TimeoutError) as e:
        outcome["code"] = f"dropped ({type(e).__name__})"
    finally:
        sock.close()
    return outcome


async def _faulty_loop(url: str, motion: Motion, deadline: float, index: int) -> list[dict]:
    episodes = []
    while time.perf_counter() < deadline - 5:
        episodes.append(
            await faulty_client(
                url, motion, FAULTS[(index + len(episodes)) % len(FAULTS)], 1000 * index + len(episodes)
            )
        )
    return episodes


async def load_test(
    url: str,
    motion: Motion,
    clients: int,
    seconds: float,
    fps: float = 30.0,
    style: str = "elderly",
    faulty: int = 0,
    reference: np.ndarray | None = None,
    streams_per_client: int = 1,
    labels: bool = False,
    pose: str = "input",
) -> dict:
    """``clients`` concurrent real-time connections of ``seconds`` each (``streams_per_client``
    streams each, one message per frame of them all, on the pose path ``pose``), and ``faulty`` clients
    misbehaving in turn (``FAULTS``) meanwhile; latency percentiles, dropped and reordered
    frames, the largest difference from ``reference`` (the expected output of the looped
    clip), the server's CPU use over the run, and what happened to each faulty episode."""
    before = await server_stats(url)
    t0 = time.perf_counter()
    stalls: list[
        tuple[float, float]
    ] = []  # (seconds into the run, ms) where this process's own loop stalled past 100 ms

    async def watch_loop() -> None:
        while time.perf_counter() < t0 + seconds:
            t = time.perf_counter()
            await asyncio.sleep(0.05)
            late = (time.perf_counter() - t - 0.05) * 1e3
            if late > 100:
                stalls.append((round(t - t0, 1), round(late)))

    watcher = asyncio.create_task(watch_loop())
    runs = [
        play(
            url,
            motion,
            {
                **hello(motion, fps, style, 1.0, None, f"load-{i}", *(LABELS if labels else (None, None))),
                "streams": streams_per_client,
                "pose": pose,
            },
            seconds,
            reference=reference,
        )
        for i in range(clients)
    ]
    bad = [_faulty_loop(url, motion, t0 + seconds, i) for i in range(faulty)]
    done = await asyncio.gather(*runs, *bad)
    results, episodes = done[:clients], [e for loop in done[clients:] for e in loop]
    watcher.cancel()
    wall = time.perf_counter() - t0
    after = await server_stats(url)
    lat = np.concatenate([np.array(r.latencies_ms) for r in results if r.latencies_ms] or [np.zeros(1)])
    sent = sum(r.sent for r in results)
    outcomes: dict[str, dict[str, int]] = {}
    for e in episodes:
        kind = outcomes.setdefault(e["kind"], {})
        kind[str(e["code"])] = kind.get(str(e["code"]), 0) + 1
    return {
        "clients": clients,
        "streams_per_client": streams_per_client,
        "seconds": seconds,
        "fps": fps,
        "frames_sent": sent,
        "frames_received": sum(r.received for r in results),
        "dropped": sent - sum(r.received for r in results),
        "reordered": sum(r.reordered for r in results),
        "errors": [r.error for r in results if r.error],
        "errors_at_s": sorted(round(r.error_at, 1) for r in results if r.error),
        "client_loop_stalls": stalls,
        "max_error_deg": max((r.max_error for r in results), default=0.0) if reference is not None else None,
        "late_client_sends": sum(r.late_sends for r in results),
        "latency_ms_p50": float(np.percentile(lat, 50)),
        "latency_ms_p99": float(np.percentile(lat, 99)),
        "latency_ms_max": float(lat.max()),
        "server_cpu_cores": (after["cpu_seconds"] - before["cpu_seconds"]) / wall,
        "server_step_cpu_s": after["step_cpu_seconds"] - before["step_cpu_seconds"],
        "wall_s": wall,
        "server_frames": after["frames"] - before["frames"],
        "mean_batch": (after["frames"] - before["frames"]) / max(1, after["steps"] - before["steps"]),
        "faulty_clients": faulty,
        "faulty_episodes": len(episodes),
        "faulty_outcomes": outcomes,
        "streams_left": after["streams"] - 1,
    }
