"""Three ``styleerd serve`` processes behind a real HAProxy with the shipped configuration
(deploy/haproxy.cfg): new streams spread over them, each process's /healthz and /metrics
(read by Prometheus' own parser), private-stream tokens and the viewer page through the
balancer, and a process killed (-9) under a live stream: the client reconnects through the
balancer to another process and goes on."""

import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
import urllib.request
from collections import Counter
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families
from websockets.sync.client import connect

from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.serve.client import SEQ, hello
from styleerd.serve.loadtest import start_behind_haproxy, stop_behind_haproxy

ROOT = Path(__file__).resolve().parents[1]
HAPROXY = shutil.which("haproxy") or "/usr/sbin/haproxy"
pytestmark = pytest.mark.skipif(
    not Path(HAPROXY).exists(), reason="HAProxy not installed (.ci/run installs Debian's haproxy)"
)


def get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


@pytest.fixture(scope="module")
def balanced():
    """(front port, {server name: (port, process)}, haproxy process)."""
    front, servers, proxy = start_behind_haproxy(ROOT / "deploy/haproxy.cfg", "--max-streams", "16")
    yield front, servers, proxy
    assert all(code == 0 for code in stop_behind_haproxy(servers, proxy))


def open_stream(url: str, **extra):
    m = walk(3.0, fps=30.0)
    ws = connect(url, open_timeout=20, legacy=True)
    ws.send(json.dumps({**hello(m, 30.0, "elderly", 1.0, None, None), **extra}))
    ready = json.loads(ws.recv(timeout=20))
    assert ready["type"] == "ready", ready
    return ws, ready


def metrics(port: int) -> dict[str, float]:
    status, text = get(f"http://127.0.0.1:{port}/metrics")
    assert status == 200
    return {s.name: s.value for family in text_string_to_metric_families(text) for s in family.samples}


def test_streams_spread_over_the_processes_and_tokens_find_theirs(balanced):
    front, servers, _ = balanced
    url = f"ws://127.0.0.1:{front}/"
    opened = [open_stream(url, private=True, name=f"p{i}") for i in range(6)]
    where = Counter(ready["server"] for _, ready in opened)
    assert where == {"s0": 2, "s1": 2, "s2": 2}, where
    assert get(f"http://127.0.0.1:{front}/metrics")[0] == 404  # only each process's own Prometheus reads them
    for name, (port, _) in servers.items():
        figures = metrics(port)
        assert figures["styleerd_streams"] == 2 and figures["styleerd_connections"] == 2, (name, figures)
        status, body = get(f"http://127.0.0.1:{port}/healthz")
        assert status == 200 and json.loads(body) == {"status": "ok", "server": name, "streams": 2}
    for _, ready in opened:  # a watcher with the token in its address reaches the process holding the stream
        assert ready["token"].startswith(ready["server"] + ".")
        with connect(f"{url}?token={ready['token']}", open_timeout=20) as viewer:
            viewer.send(json.dumps({"type": "watch", "token": ready["token"]}))
            assert json.loads(viewer.recv(timeout=20))["type"] == "waiting"
            watching = json.loads(viewer.recv(timeout=20))
            assert watching["type"] == "watching" and watching["stream"] == ready["stream"]
    for ws, _ in opened:
        ws.close()


def send_frames(ws, stop: threading.Event) -> None:
    values = bvh.channel_values(walk(3.0, fps=30.0)).astype("<f4")
    i = 0
    while not stop.is_set():
        ws.send(SEQ.pack(i) + values[i % len(values)].tobytes())
        ws.recv(timeout=20)
        i += 1
        time.sleep(1 / 30)


def test_the_viewer_page_watches_a_private_stream_through_the_balancer(balanced, tmp_path):
    from test_viewer import CHROMIUM, chromium_page

    if not Path(CHROMIUM).exists():
        pytest.skip("Chromium not installed (.ci/run installs Debian's chromium)")
    front, _, _ = balanced
    ws, ready = open_stream(f"ws://127.0.0.1:{front}/", private=True, name="behind-the-balancer")
    stop = threading.Event()
    sender = threading.Thread(target=send_frames, args=(ws, stop), daemon=True)
    sender.start()
    try:
        with chromium_page(f"http://127.0.0.1:{front}/?token={ready['token']}") as (page, errors):
            page.wait_for_function("window.viewer.stream === 'behind-the-balancer'", timeout=30000)
            page.wait_for_function("window.viewer.drawn && window.viewer.drawn.size > 10", timeout=30000)
            shot = Path(os.environ.get("STYLEERD_SCREENSHOT_DIR") or tmp_path) / "viewer-balancer.png"
            page.screenshot(path=str(shot))
            assert "live: behind-the-balancer" in page.locator("#status").inner_text()
            assert not errors, errors
    finally:
        stop.set()
        sender.join(5)
        ws.close()


def test_a_killed_process_s_client_reconnects_to_another_and_goes_on(balanced):
    """kill -9 under a live stream: ``styleerd stream-bvh --reconnect`` through the balancer
    says so, reconnects to a live process and finishes its clip."""
    front, servers, _ = balanced
    m = walk(6.0, fps=30.0)
    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"failover-{os.getpid()}.bvh"
    bvh.write(path, m)
    try:
        client = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "styleerd.cli",
                "stream-bvh",
                str(path),
                "--to",
                f"ws://127.0.0.1:{front}/",
                "--style",
                "elderly",
                "--reconnect",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        victim = None
        deadline = time.time() + 30
        while victim is None and time.time() < deadline:  # the process the client landed on
            for name, (port, proc) in servers.items():
                if proc.poll() is None and metrics(port)["styleerd_streams"] >= 1:
                    victim = name
            time.sleep(0.2)
        assert victim is not None
        time.sleep(1.0)
        servers[victim][1].kill()
        out, _ = client.communicate(timeout=60)
        assert client.returncode == 0, out
        assert "the connection was lost (code 1006)" in out and "reconnecting in 0.1 s" in out, out
        summary = re.search(
            r"received (\d+), reordered (\d+).*reconnected (\d+) time\(s\), the first stylised frame (\d+) ms", out
        )
        assert summary is not None, out
        received, reordered, reconnects, after_ms = (int(g) for g in summary.groups())
        assert received == m.n_frames and reordered == 0 and reconnects == 1, out
        assert after_ms < 3000, out  # the balancer's checks (1 s apart) may first send it to the dead process once
    finally:
        path.unlink(missing_ok=True)
