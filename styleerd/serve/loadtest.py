"""``styleerd load-test``: start a server in its own process(es) on a free loopback port, run
N real-time clients against it, print the figures (and stop the server cleanly)."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from styleerd.atomic import atomic_write_text
from styleerd.errors import StyleERDError
from styleerd.motion.procedural import walk
from styleerd.serve.client import load_test


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(port: int, *args: str) -> subprocess.Popen:
    """``styleerd serve`` on ``port`` in a new process; returns once it accepts connections."""
    log = tempfile.TemporaryFile("w+")  # a file, not a pipe: a chatty server never blocks on it
    proc = subprocess.Popen([sys.executable, "-m", "styleerd.cli", "serve", "--port", str(port), *args],
                            stdout=log, stderr=subprocess.STDOUT, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})  # fmt: skip
    proc.log = log
    deadline = time.time() + 60
    while time.time() < deadline:
        if proc.poll() is not None:
            log.seek(0)
            raise StyleERDError(f"the server exited: {log.read()}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return proc
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise StyleERDError("the server did not start within 60 s")


def stop_server(proc: subprocess.Popen) -> int:
    proc.terminate()
    try:
        return proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()
    finally:
        proc.log.close()


def server_log(proc: subprocess.Popen) -> str:
    proc.log.seek(0)
    return proc.log.read()


def run_load_test(clients: int, seconds: float, workers: int = 1, output: str | None = None) -> str:
    port = free_port()
    server = start_server(port, "--workers", str(workers), "--max-streams", str(max(256, clients + 8)))
    try:
        figures = asyncio.run(load_test(f"ws://127.0.0.1:{port}/", walk(10.0, fps=30.0), clients, seconds))
    finally:
        code = stop_server(server)
    figures["server_exit_code"] = code
    if output:
        atomic_write_text(Path(output), json.dumps(figures, indent=1))
    lines = [f"{clients} clients x {seconds:g} s at {figures['fps']:g} fps on loopback ({workers} server worker(s))",
             f"frames sent {figures['frames_sent']}, received {figures['frames_received']}, dropped {figures['dropped']}, reordered {figures['reordered']}",
             f"latency p50 {figures['latency_ms_p50']:.2f} ms, p99 {figures['latency_ms_p99']:.2f} ms, max {figures['latency_ms_max']:.2f} ms",
             f"server CPU {figures['server_cpu_cores']:.2f} cores, mean batch {figures['mean_batch']:.1f} streams per step, "
             f"client late sends {figures['late_client_sends']}, errors {len(figures['errors'])}"]  # fmt: skip
    return "\n".join(lines)
