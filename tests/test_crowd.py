"""Many streams on one connection (a hello's ``streams``): one message a frame for them all,
each stream's output equal to a local stream of its own, steered one by one, watched one by
one, and every bad message refused with what is wrong."""

import json
import urllib.error
import urllib.request

import numpy as np
import pytest
from test_server import closed_with, open_stream
from websockets.sync.client import connect

from styleerd.model.checkpoint import load_generator
from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.runtime.channels import ChannelStylizer
from styleerd.serve.client import PHASE, SEQ, hello
from styleerd.serve.loadtest import free_port, start_server, stop_server

MAX_STREAMS, K = 8, 4


@pytest.fixture(scope="module")
def server():
    port = free_port()
    proc = start_server(port, "--max-streams", str(MAX_STREAMS), "--queue", "8")
    yield f"ws://127.0.0.1:{port}/"
    assert stop_server(proc) == 0


@pytest.fixture(scope="module")
def clip():
    m = walk(3.0, fps=30.0)
    return m, bvh.channel_values(m).astype("<f4")


def crowd_frame(i: int, values: np.ndarray, count: int = K) -> np.ndarray:
    """Frame i of each of ``count`` streams, stream k from frame ``PHASE * k``."""
    return values[(i + PHASE * np.arange(count)) % len(values)]


def test_a_crowd_on_one_connection_equals_local_streams_and_is_steered_one_by_one(server, clip):
    m, values = clip
    ws, ready = open_stream(server, m, input_style="normal", content="walk", streams=K, name="crowd")
    assert ready["streams"] == K and ready["channels"] == values.shape[1]
    viewer = connect(server, open_timeout=20, legacy=True)
    viewer.send(json.dumps({"type": "watch", "stream": "crowd", "index": 2}))
    assert json.loads(viewer.recv(timeout=20))["type"] == "waiting"
    watching = json.loads(viewer.recv(timeout=20))
    assert watching["type"] == "watching" and watching["index"] == 2
    got, texts = [], []
    for i in range(40):
        if i == 20:  # stream 1 only turns youthful
            ws.send(json.dumps({"type": "set", "style": "youthful", "streams": [1]}))
        ws.send(SEQ.pack(i) + crowd_frame(i, values).astype("<f4").tobytes())
        while isinstance(message := ws.recv(timeout=20), str):
            texts.append(json.loads(message))
        assert SEQ.unpack_from(message)[0] == i and len(message) == 4 + 4 * K * values.shape[1]
        got.append(np.frombuffer(message, "<f4", offset=4).reshape(K, -1))
    assert {"type": "target", "weights": {"youthful": 1.0}, "streams": [1]} in texts
    shown = [viewer.recv(timeout=20) for _ in range(5)]
    assert all(isinstance(s, bytes) and len(s) == 4 + 4 * 6 * len(ready["joints"]) for s in shown)
    ws.close()
    viewer.close()
    model = load_generator()[0]
    for k in range(K):
        local = ChannelStylizer(model, m.skeleton, {"elderly": 1.0}, "normal", "walk", fps=30.0)
        expected = []
        for i in range(40):
            if i == 20 and k == 1:
                local.stylizer.set_target({"youthful": 1.0})
            expected.append(local.step(crowd_frame(i, values)[k].astype(np.float64))[0])
        assert np.abs(np.stack(got)[:, k] - np.stack(expected)).max() < 1e-2, k


def test_json_frames_of_a_crowd(server, clip):
    m, values = clip
    ws, _ = open_stream(server, m, input_style="normal", content="walk", streams=2, format="json")
    ws.send(json.dumps({"type": "frame", "seq": 0, "values": crowd_frame(0, values, 2).tolist()}))
    reply = json.loads(ws.recv(timeout=20))
    assert reply["type"] == "frame" and reply["seq"] == 0
    assert np.asarray(reply["values"]).shape == (2, values.shape[1]) and len(reply["unfamiliar"]) == 2
    ws.close()


BAD = {
    "one stream's values for two": (
        lambda v: json.dumps({"type": "frame", "values": v[0].tolist()}),
        "a list of 2 lists of",
    ),
    "a binary frame of one stream": (lambda v: SEQ.pack(0) + v[0].astype("<f4").tobytes(), "4 + 2 x 4 x"),
    "NaN in the second stream": (
        lambda v: SEQ.pack(0) + np.stack([v[0], np.full_like(v[0], np.nan)]).astype("<f4").tobytes(),
        "frame 0 of stream 1: joint",
    ),
    "set of a stream it does not have": (
        lambda v: json.dumps({"type": "set", "style": "elderly", "streams": [2]}),
        "this connection's stream indices, 0 to 1",
    ),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_crowd_messages_are_refused_with_what_is_wrong(server, clip, case):
    m, values = clip
    make, words = BAD[case]
    ws, _ = open_stream(server, m, streams=2)
    ws.send(make(values))
    code, texts = closed_with(ws)
    assert code in (1007, 1008) and words in texts[-1]["message"], texts


@pytest.mark.parametrize("count", [0, True, 1.5, "4", MAX_STREAMS + 1])
def test_a_hello_with_a_bad_number_of_streams_is_refused(server, clip, count):
    m, _ = clip
    ws = connect(server, open_timeout=20, legacy=True)
    ws.send(json.dumps({**hello(m, 30.0, "elderly", 1.0, None, None), "streams": count}))
    code, texts = closed_with(ws)
    assert code == 1008 and "'streams' must be an integer in [1, 8]" in texts[-1]["message"]


def test_a_crowd_counts_every_stream_against_the_servers_room(server, clip):
    m, _ = clip
    first, _ = open_stream(server, m, streams=MAX_STREAMS - 1)
    ws = connect(server, open_timeout=20, legacy=True)
    ws.send(json.dumps({**hello(m, 30.0, "elderly", 1.0, None, None), "streams": 2}))
    code, texts = closed_with(ws)
    assert code == 1013 and "the server is full" in texts[-1]["message"]
    first.close()


@pytest.mark.parametrize("index", [-1, True, "2", 1.5, 10**9])
def test_a_watch_with_a_bad_index_is_refused(server, index):
    ws = connect(server, open_timeout=20, legacy=True)
    ws.send(json.dumps({"type": "watch", "stream": "crowd", "index": index}))
    code, texts = closed_with(ws)
    assert code == 1008 and "'index' is which of a connection's streams to watch" in texts[-1]["message"]


def test_healthz_and_metrics_count_a_crowds_streams(server, clip):
    from prometheus_client.parser import text_string_to_metric_families

    m, _ = clip
    port = server.rsplit(":", 1)[1].strip("/")
    ws, _ = open_stream(server, m, streams=3)
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=10) as r:
        assert r.status == 200 and json.loads(r.read()) == {"status": "ok", "server": "", "streams": 3}
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as r:
        assert r.headers["Content-Type"].startswith("text/plain; version=0.0.4")
        samples = {s.name: s.value for f in text_string_to_metric_families(r.read().decode()) for s in f.samples}
    assert samples["styleerd_streams"] == 3 and samples["styleerd_connections"] == 1, samples
    assert samples["styleerd_uptime_seconds"] > 0 and samples["styleerd_frames_total"] >= 0, samples
    full, _ = open_stream(server, m, streams=MAX_STREAMS - 3)
    try:
        urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=10)
        raise AssertionError("a full server answered 200")
    except urllib.error.HTTPError as e:
        assert e.code == 503 and json.loads(e.read())["status"] == "full"
    full.close()
    ws.close()
