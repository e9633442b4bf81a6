"""The style server over real sockets: protocol, batching equal to local streaming, control
messages, live viewers, faults (each closes only its own connection), restart, workers, load."""

import base64
import json
import math
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from styleerd.model.checkpoint import load_generator
from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.runtime.channels import ChannelStylizer
from styleerd.runtime.cleanup import FootLock
from styleerd.serve.client import SEQ, hello
from styleerd.serve.loadtest import free_port, run_load_test, start_server, stop_server

MAX_STREAMS, QUEUE = 6, 8


@pytest.fixture(scope="module")
def server():
    port = free_port()
    proc = start_server(port, "--max-streams", str(MAX_STREAMS), "--queue", str(QUEUE), "--max-message", "65536")
    yield f"ws://127.0.0.1:{port}/", port
    assert stop_server(proc) == 0


@pytest.fixture(scope="module")
def clip():
    m = walk(3.0, fps=30.0)
    return m, bvh.channel_values(m).astype("<f4")


def open_stream(url: str, m, **extra):
    ws = connect(url, open_timeout=20, legacy=True)
    ws.send(json.dumps({**hello(m, 30.0, "elderly", 1.0, None, None), **extra}))
    ready = json.loads(ws.recv(timeout=20))
    assert ready["type"] == "ready", ready
    return ws, ready


def send_all(ws, messages: list) -> None:
    """Send until the server closes the connection (it may, before the last)."""
    for message in messages:
        try:
            ws.send(message)
        except ConnectionClosed:
            return


def frame(i: int, values: np.ndarray) -> bytes:
    return SEQ.pack(i) + values.astype("<f4").tobytes()


def replies(ws, n: int, timeout: float = 20.0) -> tuple[list[int], list[np.ndarray], list[dict]]:
    """The next n binary replies (sequence numbers, float32 payloads) and any JSON in between."""
    seqs, payloads, texts = [], [], []
    while len(seqs) < n:
        message = ws.recv(timeout=timeout)
        if isinstance(message, str):
            texts.append(json.loads(message))
            continue
        seqs.append(SEQ.unpack_from(message)[0])
        payloads.append(np.frombuffer(message, "<f4", offset=SEQ.size))
    return seqs, payloads, texts


def side_by_side(streams: list, values: np.ndarray, n: int) -> list[np.ndarray]:
    """The first n frames sent to every stream in turn, one reply awaited per frame; then the
    streams are closed. -> each stream's replies ``[n, channels]``."""
    got = [[] for _ in streams]
    for i in range(n):
        for ws, out in zip(streams, got):
            ws.send(frame(i, values[i]))
            out += replies(ws, 1)[1]
    for ws in streams:
        ws.close()
    return [np.stack(out) for out in got]


def closed_with(ws, timeout: float = 20.0) -> tuple[int | None, list[dict]]:
    """Read until the server closes; -> (close code, the JSON messages it sent)."""
    texts = []
    try:
        while True:
            message = ws.recv(timeout=timeout)
            if isinstance(message, str):
                texts.append(json.loads(message))
    except ConnectionClosed as e:
        return (e.rcvd.code if e.rcvd else None), texts


def test_stream_answers_every_frame_in_order_equal_to_local_streaming(server, clip):
    url, _ = server
    m, values = clip
    ws, ready = open_stream(url, m, input_style="normal", content="walk")
    assert (
        ready["channels"] == values.shape[1]
        and ready["joints"] == list(m.skeleton.names)
        and "Hips" in ready["mapping"]
    )
    seqs, payloads = [], []
    for i in range(len(values)):
        ws.send(frame(i, values[i]))
        if i % 4 == 3 or i == len(values) - 1:  # a few frames in flight, never more than the queue
            got, data, _ = replies(ws, i + 1 - len(seqs))
            seqs += got
            payloads += data
    ws.close()
    assert seqs == list(range(len(values)))
    local = ChannelStylizer(load_generator()[0], m.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0)
    expected = np.stack([local.step(values[i].astype(np.float64))[0] for i in range(len(values))])
    assert np.abs(np.stack(payloads) - expected).max() < 1e-2  # degrees: float32 on the wire


def test_body_parts_in_the_hello_beside_a_stream_without(server, clip):
    """A stream with body parts of their own targets gets what a local ChannelStylizer with
    those parts gives, while a stream of the same skeleton without parts goes on beside it."""
    url, _ = server
    m, values = clip
    parts = {"legs": "exhausted", "arms": "input"}
    ws, ready = open_stream(url, m, input_style="normal", content="walk", parts=parts)
    plain, _ = open_stream(url, m, input_style="normal", content="walk")
    assert ready["parts"] == {"legs": {"exhausted": 1.0}, "arms": None}
    got, plain_got = side_by_side([ws, plain], values, 30)
    model = load_generator()[0]
    local = ChannelStylizer(model, m.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0, parts=parts)
    whole = ChannelStylizer(model, m.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0)
    expected = np.stack([local.step(values[i].astype(np.float64))[0] for i in range(30)])
    assert np.abs(got - expected).max() < 1e-2
    assert np.abs(plain_got - np.stack([whole.step(values[i].astype(np.float64))[0] for i in range(30)])).max() < 1e-2
    assert np.abs(expected - plain_got).max() > 1.0  # the parts change the output: the test can fail


def test_root_speed_in_the_hello_moves_the_root_at_the_styles_pace(server, clip):
    """A stream with ``root_speed`` gets a local ChannelStylizer(root_speed=True)'s frames: the
    rotations of a stream without it, and a root path on the input's heading at another pace."""
    url, _ = server
    m, values = clip
    # without foot cleanup, whose pinning of the feet would make the poses differ too
    ws, ready = open_stream(url, m, input_style="normal", content="walk", root_speed=True, cleanup=False)
    plain, plain_ready = open_stream(url, m, input_style="normal", content="walk", cleanup=False)
    assert ready["root_speed"] is True and plain_ready["root_speed"] is False
    got, plain_got = side_by_side([ws, plain], values, 60)
    local = ChannelStylizer(
        load_generator()[0], m.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0, cleanup=False, root_speed=True
    )
    expected = np.stack([local.step(values[i].astype(np.float64))[0] for i in range(60)])
    assert np.abs(got - expected).max() < 1e-2
    names = [c for chans in m.skeleton.channels for c in chans]
    root = [names.index(f"{axis}position") for axis in "XYZ"]  # the root's translation channels (its joint comes first)
    assert np.abs(np.delete(got, root, 1) - np.delete(plain_got, root, 1)).max() < 1e-2  # the same poses
    step, plain_step = np.diff(got[:, root], axis=0), np.diff(plain_got[:, root], axis=0)
    assert np.abs(step[:, 1] - plain_step[:, 1]).max() < 1e-3  # the input's height
    ratio = np.linalg.norm(step[:, [0, 2]], axis=-1).sum() / np.linalg.norm(plain_step[:, [0, 2]], axis=-1).sum()
    assert not 0.97 < ratio < 1.03, ratio  # an elderly pace is not the input's


def test_pose_in_the_hello_is_the_local_stylizers(server, clip):
    """``pose`` in the hello: each stream gets a local ChannelStylizer's frames with that pose; the
    input's pose (default) and the network's differ; anything else is refused in one line."""
    url, _ = server
    m, values = clip
    streams = {
        pose: open_stream(
            url, m, input_style="normal", content="walk", cleanup=False, **({"pose": pose} if pose else {})
        )
        for pose in (None, "network")
    }
    assert streams[None][1]["pose"] == "input" and streams["network"][1]["pose"] == "network"
    got = dict(zip(streams, side_by_side([ws for ws, _ in streams.values()], values, 30)))
    for pose in streams:
        local = ChannelStylizer(
            load_generator()[0],
            m.skeleton,
            {"elderly": 1.0},
            "normal",
            "walk",
            fps=30.0,
            cleanup=False,
            pose=pose or "input",
        )
        assert (
            np.abs(got[pose] - np.stack([local.step(values[i].astype(np.float64))[0] for i in range(30)])).max() < 1e-2
        ), pose
    assert np.abs(got[None] - got["network"]).max() > 1.0  # degrees: the two poses are not the same
    ws = connect(url, open_timeout=20, legacy=True)
    ws.send(json.dumps({**hello(m, 30.0, "elderly", 1.0, None, None), "pose": "paper"}))
    code, texts = closed_with(ws)
    assert code == 1008 and "'pose' must be one of input, network" in texts[0]["message"]


def test_json_frames_positions_and_style_change_midway(server, clip):
    url, _ = server
    m, values = clip
    ws, ready = open_stream(url, m, format="json", positions=True)
    J = len(ready["joints"])
    out = []
    targets = []
    for i in range(40):
        if i == 20:
            ws.send(json.dumps({"type": "set", "mix": {"feminine": 1, "exhausted": 1}, "intensity": 0.8}))
        ws.send(json.dumps({"type": "frame", "seq": i, "values": values[i].tolist()}))
        while True:
            msg = json.loads(ws.recv(timeout=20))
            if msg["type"] != "target":
                break
            targets.append(msg["weights"])
        assert msg["type"] == "frame" and msg["seq"] == i
        assert (
            len(msg["values"]) == values.shape[1] and len(msg["input_positions"]) == len(msg["output_positions"]) == J
        )
        assert 0.0 <= msg["unfamiliar"] <= 1.0 and 0.0 <= msg["unread"] <= 1.0  # the input's style is inferred
        out.append(msg)
    assert targets == [{"exhausted": 0.4, "feminine": 0.4, "normal": 0.2}]
    ws.send(json.dumps({"type": "stats"}))
    stats = json.loads(ws.recv(timeout=20))
    assert stats["type"] == "stats" and stats["frames"] >= 40
    ws.close()
    ws, _ = open_stream(url, m, format="json", input_style="normal")  # the input's style given: nothing unread
    ws.send(json.dumps({"type": "frame", "seq": 0, "values": values[0].tolist()}))
    msg = json.loads(ws.recv(timeout=20))
    assert msg["type"] == "frame" and "unread" not in msg and "unfamiliar" in msg
    ws.close()


def test_binary_replies_carry_unfamiliar_and_unread_when_asked(server, clip):
    """A hello's ``confidence``: a binary reply ends in ``float32 [K][2]``, each stream's unfamiliar and
    unread, the numbers a JSON reply to the same frames carries; with positions before them; the
    input's style given, unread is 0."""
    url, _ = server
    m, values = clip
    J = len(m.skeleton.names)
    json_ws, _ = open_stream(url, m, format="json")
    binary_ws, _ = open_stream(url, m, confidence=True, positions=True)
    plain_ws, _ = open_stream(url, m)
    for i in range(12):
        json_ws.send(json.dumps({"type": "frame", "seq": i, "values": values[i].tolist()}))
        want = json.loads(json_ws.recv(timeout=20))
        for ws in (binary_ws, plain_ws):
            ws.send(frame(i, values[i]))
        got, plain = replies(binary_ws, 1)[1][0], replies(plain_ws, 1)[1][0]
        assert len(got) == len(plain) + 6 * J + 2  # values, two [J][3] position blocks, then the two figures
        assert np.allclose(got[: len(plain)], plain, atol=1e-4)
        assert np.allclose(got[-2:], [want["unfamiliar"], want["unread"]], atol=2e-3), (got[-2:], want)
    for ws in (json_ws, binary_ws, plain_ws):
        ws.close()
    ws, _ = open_stream(url, m, confidence=True, input_style="normal", streams=2)  # two streams, style given
    ws.send(SEQ.pack(0) + np.stack([values[0], values[5]]).astype("<f4").tobytes())
    got = replies(ws, 1)[1][0]
    assert len(got) == 2 * values.shape[1] + 4 and (got[-4:][1::2] == 0.0).all()
    assert ((got[-4:][::2] >= 0.0) & (got[-4:][::2] <= 1.0)).all()
    ws.close()


def test_a_live_viewer_watches_and_steers_a_stream(server, clip):
    url, _ = server
    m, values = clip
    viewer = connect(url, open_timeout=20, legacy=True)
    viewer.send(json.dumps({"type": "watch", "stream": "performer"}))
    assert json.loads(viewer.recv(timeout=20))["type"] == "waiting"
    ws, ready = open_stream(url, m, name="performer")
    watching = json.loads(viewer.recv(timeout=20))
    assert watching["type"] == "watching" and watching["parents"] == ready["parents"]
    for i in range(10):
        ws.send(frame(i, values[i]))
        replies(ws, 1)
    shown = [viewer.recv(timeout=20) for _ in range(10)]
    J = len(ready["joints"])
    assert all(isinstance(s, bytes) and len(s) == 4 + 4 * 6 * J for s in shown)
    viewer.send(json.dumps({"type": "set", "style": "youthful"}))
    assert json.loads(viewer.recv(timeout=20)) == {"type": "target", "weights": {"youthful": 1.0}}
    ws.send(frame(10, values[10]))
    _, _, texts = replies(ws, 1)
    assert {"type": "target", "weights": {"youthful": 1.0}} in texts  # the performer is told too
    ws.close()
    while isinstance(message := viewer.recv(timeout=20), bytes):  # the last frames shown
        pass
    assert json.loads(message) == {"type": "ended", "stream": "performer"}
    viewer.close()


FAULTS = {
    "bad JSON": (lambda ws, v: ws.send("{not json"), 1008, "bad JSON"),
    "unknown message": (lambda ws, v: ws.send(json.dumps({"type": "dance"})), 1008, "unknown message type"),
    "wrong frame length": (lambda ws, v: ws.send(frame(0, v[0][:-1])), 1008, "a binary frame is"),
    "NaN": (
        lambda ws, v: ws.send(frame(0, np.where(np.arange(len(v[0])) == 5, np.nan, v[0]))),
        1007,
        "is not a finite number",
    ),
    "oversized payload": (lambda ws, v: ws.send(b"\0" * 70000), 1009, None),
    "absurd values": (lambda ws, v: ws.send(frame(1, np.full_like(v[0], 3e38))), 1007, "is out of range"),
    "frames faster than real time": (
        lambda ws, v: send_all(ws, [frame(i, v[0]) for i in range(400)]),
        1008,
        f"more than {QUEUE} frames waiting",
    ),
    "unknown style": (
        lambda ws, v: ws.send(json.dumps({"type": "set", "style": "zombie"})),
        1008,
        "valid: active, elderly",
    ),
    # a JSON frame on a binary stream whose seq cannot be packed as uint32 once stopped every stream
    "seq past uint32": (
        lambda ws, v: ws.send(json.dumps({"type": "frame", "seq": 2**40, "values": v[0].tolist()})),
        1007,
        "'seq' must be an integer",
    ),
    "negative seq": (
        lambda ws, v: ws.send(json.dumps({"type": "frame", "seq": -1, "values": v[0].tolist()})),
        1007,
        "'seq' must be an integer",
    ),
    "seq not a number": (
        lambda ws, v: ws.send(json.dumps({"type": "frame", "seq": "7", "values": v[0].tolist()})),
        1007,
        "'seq' must be an integer",
    ),
}


@pytest.mark.parametrize("fault", FAULTS)
def test_a_faulty_client_is_closed_with_a_clear_code_and_others_go_on(server, clip, fault):
    url, _ = server
    m, values = clip
    act, code, text = FAULTS[fault]
    good, _ = open_stream(url, m)
    bad, _ = open_stream(url, m)
    good.send(frame(0, values[0]))
    act(bad, values)
    got, texts = closed_with(bad)
    assert got == code, (got, texts)
    if text:
        assert any(t["type"] == "error" and text in t["message"] for t in texts), texts
    seqs, payloads, _ = replies(good, 1)
    for i in range(1, 6):
        good.send(frame(i, values[i]))
        s, p, _ = replies(good, 1)
        seqs += s
        payloads += p
    assert seqs == list(range(6)) and all(np.isfinite(p).all() for p in payloads)
    good.close()


def test_hello_problems_and_a_full_server(server, clip):
    url, _port = server
    m, _ = clip
    for msg, code, text in [
        ({"type": "hello", "fps": 30}, 1008, "needs 'skeleton'"),
        ({**hello(m, 30.0, "zombie", 1.0, None, None)}, 1008, "unknown style 'zombie'"),
        ({**hello(m, 5.0, "elderly", 1.0, None, None)}, 1008, "'fps' must be a number in [10, 480]"),
        (
            {"type": "hello", "skeleton": "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0\n}\n", "fps": 30, "style": "elderly"},
            1008,
            "handshake skeleton:5: joint 'Hips' OFFSET",
        ),
        (
            {"type": "hello", "preset": "model", "fps": 30, "style": "elderly", "input_style": "sleepy"},
            1008,
            "unknown input_style",
        ),
        (
            {"type": "hello", "preset": "model", "fps": 30, "style": "elderly", "parts": {"wings": "elderly"}},
            1008,
            "unknown body part 'wings'",
        ),
        (
            {"type": "hello", "preset": "model", "fps": 30, "style": "elderly", "parts": {"legs": {"elderly": "lots"}}},
            1008,
            "mixture weights must be",
        ),
        ({"type": "hello", "preset": "model", "fps": 30, "style": "elderly", "parts": [1, 2]}, 1008, "parts: give"),
        (
            {"type": "hello", "preset": "model", "fps": 30, "style": "elderly", "root_speed": "yes"},
            1008,
            "'root_speed' must be true or false",
        ),
    ]:
        ws = connect(url, open_timeout=20, legacy=True)
        ws.send(json.dumps(msg))
        got, texts = closed_with(ws)
        assert got == code and text in texts[0]["message"], (msg, texts)
    held = [open_stream(url, m)[0] for _ in range(MAX_STREAMS)]
    extra = connect(url, open_timeout=20, legacy=True)
    extra.send(json.dumps(hello(m, 30.0, "elderly", 1.0, None, None)))
    got, texts = closed_with(extra)
    assert got == 1013 and "full" in texts[0]["message"]
    for ws in held:
        ws.close()
    time.sleep(0.5)
    ws, _ = open_stream(url, m)  # slots come back when streams end
    ws.close()


class RawClient:
    """A WebSocket client on a bare socket (RFC 6455 by hand) that can stop reading, which
    library clients do not allow: it never reads after the handshake."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        response = b""
        while b"\r\n\r\n" not in response:
            response += self.sock.recv(1)
        assert response.startswith(b"HTTP/1.1 101")

    def send(self, opcode: int, payload: bytes) -> None:
        self.sock.sendall(wire_frame(opcode, payload))


def wire_frame(opcode: int, payload: bytes, fin: bool = True) -> bytes:
    """One masked client frame (RFC 6455), FIN as given."""
    mask, n = os.urandom(4), len(payload)
    head = bytes([(0x80 if fin else 0) | opcode]) + (
        bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n)
    )
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def test_messages_behind_the_hello_in_fragments_and_between_frames_are_taken_in_order(server, clip):
    """A stream's messages are handed over as websockets parses them (serve.connection), not through
    a queue: frames sent right behind the hello, before the ready came back, a frame and a stats
    request each in fragments, and a set between frames are all taken, in the order sent; a text
    message that is not UTF-8 closes the connection with 1007."""
    url, _ = server
    m, values = clip
    ws = connect(url, open_timeout=20, legacy=True)
    ws.send(json.dumps(hello(m, 30.0, "elderly", 1.0, None, None)))
    ws.send(frame(0, values[0]))
    ws.send(frame(1, values[1]))
    assert json.loads(ws.recv(timeout=20))["type"] == "ready"
    data = frame(2, values[2])
    ws.send([data[:3], data[3:100], data[100:]])
    ws.send(['{"type": ', '"stats"}'])
    ws.send(json.dumps({"type": "set", "style": "exhausted"}))
    ws.send(frame(3, values[3]))
    seqs, _, texts = replies(ws, 4)
    assert seqs == [0, 1, 2, 3] and [t["type"] for t in texts] == ["stats", "target"], (seqs, texts)
    ws.send(b"\xff\xfe", text=True)
    code, _ = closed_with(ws)
    assert code == 1007


def test_clients_vanishing_mid_stream_and_a_client_that_stops_reading(server, clip):
    url, port = server
    m, values = clip
    for _ in range(MAX_STREAMS + 2):  # more than the server holds: vanished streams must free their slots
        ws, _ = open_stream(url, m)
        ws.send(frame(0, values[0]))
        ws.socket.shutdown(socket.SHUT_RDWR)  # gone without a close handshake
        ws.socket.close()
    slow = RawClient(port)  # sends frames at 100 fps and never reads a reply
    slow.send(0x1, json.dumps({**hello(m, 30.0, "elderly", 1.0, None, "slow"), "positions": True}).encode())

    def listed() -> bool:
        return "slow" in urllib.request.urlopen(f"http://127.0.0.1:{port}/streams", timeout=10).read().decode()

    while not listed():
        time.sleep(0.05)
    t0 = time.time()
    closed = False
    for i in range(3000):  # the server must give up on it within seconds
        try:
            slow.send(0x2, frame(i, values[i % len(values)]))
        except OSError:  # reset by the server
            closed = True
            break
        if i % 10 == 0 and not listed():
            closed = True
            break
        time.sleep(0.01)
    assert closed and i > QUEUE and time.time() - t0 < 25
    good, _ = open_stream(url, m)
    for i in range(5):
        good.send(frame(i, values[i]))
        assert replies(good, 1)[0] == [i]
    good.close()


def test_http_pages_and_clips(server):
    _, port = server
    page = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10).read().decode()
    assert "/static/viewer.js" in page and "cdn" not in page.lower()
    names = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/clips", timeout=10).read())
    text = (
        urllib.request.urlopen(f"http://127.0.0.1:{port}/clips/{urllib.request.quote(names[0])}", timeout=10)
        .read()
        .decode()
    )
    assert bvh.parse(text).n_frames > 100
    with pytest.raises(urllib.error.HTTPError, match="404"):
        urllib.request.urlopen(f"http://127.0.0.1:{port}/static/../server.py", timeout=10)


def test_server_restart_closes_clients_cleanly_and_workers_share_a_port(clip):
    m, values = clip
    port = free_port()
    proc = start_server(port, "--workers", "2")
    url = f"ws://127.0.0.1:{port}/"
    streams = [open_stream(url, m)[0] for _ in range(4)]
    for ws in streams:
        ws.send(frame(0, values[0]))
        assert replies(ws, 1)[0] == [0]
    proc.send_signal(signal.SIGTERM)
    for ws in streams:
        code, _ = closed_with(ws)
        assert code == 1001  # going away: a clean close
    assert proc.wait(20) == 0


def test_soak_reduced_size(tmp_path):
    """CI size of the soak test (full size: 200 clients x 10 min with 20 faulty ones,
    docs/soak.json): well-behaved clients lose nothing and get what a local run gives, while
    faulty ones (malformed frames, slow readers, vanishing, bad hellos) are each closed with
    the right code and leave no stream behind."""
    report, _ = run_load_test(clients=20, seconds=12.0, output=str(tmp_path / "soak.json"), faulty=6)
    f = json.loads((tmp_path / "soak.json").read_text())
    assert f["dropped"] == 0 and f["reordered"] == 0 and not f["errors"] and f["frames_received"] == 20 * 360, report
    assert f["max_error_deg"] < 1e-2, report  # float32 on the wire
    assert f["server_tracebacks"] == 0 and f["streams_left"] == 0 and f["server_exit_code"] == 0, report
    outcomes = f["faulty_outcomes"]
    assert set(outcomes) == {"malformed frame", "slow reader", "vanishes", "bad hello"}, outcomes
    assert set(outcomes["malformed frame"]) <= {"1007", "1008"} and set(outcomes["bad hello"]) == {"1008"}, outcomes
    assert set(outcomes["slow reader"]) <= {"1008", "dropped"} and set(outcomes["vanishes"]) == {"vanished"}, outcomes
    assert math.isfinite(f["latency_ms_p99"]), report


def test_stream_bvh_writes_the_stylised_stream(server, tmp_path):
    """``styleerd stream-bvh FILE -o OUT.bvh``: the mocap source keeps what came back, a BVH
    on the input's skeleton with every frame."""
    import subprocess
    import sys

    url, _ = server
    source = walk(2.0, fps=30.0)
    bvh.write(tmp_path / "in.bvh", source)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "stream-bvh",
            str(tmp_path / "in.bvh"),
            "--to",
            url,
            "--style",
            "elderly",
            "--input-style",
            "normal",
            "--content",
            "walk",
            "-o",
            str(tmp_path / "out.bvh"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 0 and f"received {source.n_frames}, reordered 0" in r.stdout, r.stdout + r.stderr
    # the server's per-frame measures, summed over the stream: the input's style was given, nothing unread
    seen = re.search(r"unfamiliar mean (\d\.\d\d) \((\d+) % of frames above 0\.5[^)]*\), unread mean 0\.00", r.stdout)
    assert seen and 0.0 <= float(seen[1]) <= 1.0 and 0 <= int(seen[2]) <= 100, r.stdout
    out = bvh.read(tmp_path / "out.bvh")
    assert out.n_frames == source.n_frames and out.skeleton.names == source.skeleton.names
    assert np.allclose(out.positions[:, 0, [0, 2]], source.positions[:, 0, [0, 2]], atol=1e-3)  # the root's path kept
    height = np.abs(out.positions[:, 0, 1] - source.positions[:, 0, 1]).max()
    assert height <= FootLock(source.skeleton).max_drop + 1e-3  # and its height, but for the foot cleanup's pelvis
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "stream-bvh",
            str(tmp_path / "in.bvh"),
            "--to",
            url,
            "--style",
            "elderly",
            "--input-style",
            "normal",
            "--content",
            "walk",
            "--root-speed",
            "-o",
            str(tmp_path / "paced.bvh"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    paced = bvh.read(tmp_path / "paced.bvh").positions[:, 0]
    ground = (
        np.linalg.norm(np.diff(paced[:, [0, 2]], axis=0), axis=-1).sum()
        / np.linalg.norm(np.diff(source.positions[:, 0, [0, 2]], axis=0), axis=-1).sum()
    )
    lift = np.abs(paced[:, 1] - source.positions[:, 0, 1]).max()
    assert ground < 0.97 and lift <= FootLock(source.skeleton).max_drop + 1e-3  # an elderly pace, the input's height
    # but for the foot cleanup's pelvis
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "styleerd.cli",
            "stream-bvh",
            str(tmp_path / "in.bvh"),
            "--to",
            "ws://127.0.0.1:9/",
            "--style",
            "elderly",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert r.returncode == 2 and "cannot connect" in r.stderr and "Traceback" not in r.stderr


def test_bone_fronts_follow_each_bones_roll(server, clip):
    """With ``"fronts": true`` each frame also carries every bone's front: a unit vector
    perpendicular to the bone, equal to its parent's global rotation (scipy, from the channel
    values sent back) applied to the bone's rest front; what the viewer turns bones with."""
    from scipy.spatial.transform import Rotation

    from styleerd.motion.kinematics import bone_fronts

    url, _ = server
    m, values = clip
    J = m.skeleton.n_joints
    ws, _ready = open_stream(url, m, positions=True, fronts=True)
    for i in range(5):
        ws.send(frame(i, values[i]))
    _, payloads, _ = replies(ws, 5)
    ws.close()
    C = values.shape[1]
    out = payloads[-1]
    assert len(out) == C + 12 * J
    positions, fronts = out[C + 3 * J : C + 6 * J].reshape(J, 3), out[C + 9 * J :].reshape(J, 3)
    motion = bvh.motion_from_channels(m.skeleton, out[None, :C].astype(np.float64), 30.0)
    world = []
    for j, p in enumerate(m.skeleton.parents):
        r = Rotation.from_quat(motion.rotations[0, j], scalar_first=True)
        world.append(r if p < 0 else world[p] * r)
    rest = bone_fronts(m.skeleton)
    for j in range(1, J):
        expected = world[m.skeleton.parents[j]].apply(rest[j])
        assert np.allclose(fronts[j], expected, atol=1e-4), m.skeleton.names[j]
        bone = positions[j] - positions[m.skeleton.parents[j]]
        if np.linalg.norm(bone) > 1e-3:
            assert abs(np.dot(fronts[j], bone / np.linalg.norm(bone))) < 1e-3 and np.isclose(
                np.linalg.norm(fronts[j]), 1, atol=1e-4
            )


def test_the_load_tests_server_cpu_counts_every_worker():
    """``load-test --workers N`` reads the CPU of the server's whole process tree (the stats answer
    for one worker): a parent that sleeps while its child burns a second of CPU counts that second."""
    from styleerd.serve.loadtest import tree_cpu_seconds

    burn = (
        "import time\nt = time.process_time()\nwhile time.process_time() - t < 1.0: pass\n"
        "print('done', flush=True)\ntime.sleep(30)"
    )
    parent = subprocess.Popen(
        [sys.executable, "-c", f"import subprocess, sys; subprocess.run([sys.executable, '-c', {burn!r}])"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert parent.stdout.readline().strip() == "done"
        own = sum(map(int, Path(f"/proc/{parent.pid}/stat").read_text().rsplit(")", 1)[1].split()[11:13]))
        assert own / os.sysconf("SC_CLK_TCK") < 0.5
        assert 0.95 <= tree_cpu_seconds(parent.pid) < 3.0
    finally:
        parent.kill()
        parent.wait()


def test_the_load_test_asks_for_the_pose_path_it_compares_with(tmp_path):
    """``run_load_test(pose="network")``: the clients' hellos ask for the network's own pose and every reply
    matches a local run on that path, which differs from the default path's by far more than the wire's
    rounding (so a server that ignored the hello's pose would be caught)."""
    from styleerd.serve.loadtest import expected_output

    motion = walk(10.0, fps=30.0)
    network, own = (expected_output(motion, 60, labels=True, pose=p) for p in ("network", "input"))
    assert np.abs(network - own).max() > 1.0
    report, _ = run_load_test(
        clients=3, seconds=4.0, output=str(tmp_path / "f.json"), streams_per_client=2, labels=True, pose="network"
    )
    f = json.loads((tmp_path / "f.json").read_text())
    assert "pose network" in report and f["dropped"] == 0 and not f["errors"], report
    assert f["frames_received"] == 3 * 2 * 120 and f["max_error_deg"] < 1e-2, report
