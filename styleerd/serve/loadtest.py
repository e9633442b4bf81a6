"""``styleerd load-test``: start a server in its own process(es) on a free loopback port, run
N real-time clients against it (and, for a soak test, faulty clients beside them), print the
figures (and stop the server cleanly)."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from styleerd.atomic import atomic_write_text
from styleerd.errors import StyleERDError
from styleerd.motion import bvh
from styleerd.motion.motion import Motion
from styleerd.motion.procedural import walk
from styleerd.serve.client import load_test


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(port: int, *args: str) -> subprocess.Popen:
    """``styleerd serve`` on ``port`` in a new process; returns once it accepts connections."""
    # a file, not a pipe: a chatty server never blocks on it; closed with the process
    log = tempfile.TemporaryFile("w+")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "styleerd.cli", "serve", "--port", str(port), *args],
        stdout=log,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
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


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def expected_output(motion: Motion, frames: int, fps: float = 30.0, style: str = "elderly") -> np.ndarray:
    """What a well-behaved client of the load test should get back: its looped clip stylised
    locally, one stream, from float32 values as they go over the wire."""
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime.channels import ChannelStylizer

    values = bvh.channel_values(motion).astype("<f4").astype(np.float64)
    local = ChannelStylizer(load_generator_weights(), motion.skeleton, {style: 1.0}, fps=fps)
    return np.stack(
        [
            local.step(values[i % len(values)])[0]
            for i in tqdm(range(frames), desc="local reference", unit="frame", leave=False)
        ]
    )


def run_load_test(clients: int, seconds: float, workers: int = 1, output: str | None = None, faulty: int = 0) -> str:
    """The load test (and, with ``faulty``, the soak test): every well-behaved client's replies
    are compared with a local run of the same clip."""
    motion = walk(10.0, fps=30.0)
    reference = expected_output(motion, int(round(seconds * 30.0)))
    port = free_port()
    server = start_server(port, "--workers", str(workers), "--max-streams", str(max(256, clients + faulty + 8)))
    rss: list[float] = []  # the server's memory every 5 s (one worker)
    stop = threading.Event()

    def sample() -> None:
        while workers == 1 and not stop.wait(0 if not rss else 5.0):
            rss.append(round(_rss_mb(server.pid), 1))

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        figures = asyncio.run(
            load_test(f"ws://127.0.0.1:{port}/", motion, clients, seconds, faulty=faulty, reference=reference)
        )
        stop.set()
        sampler.join()
        figures["server_rss_mb"] = rss or [float("nan")]
        figures["server_tracebacks"] = server_log(server).count("Traceback")
    finally:
        code = stop_server(server)
    figures["server_exit_code"] = code
    if output:
        atomic_write_text(Path(output), json.dumps(figures, indent=1))
    lines = [
        f"{clients} clients x {seconds:g} s at {figures['fps']:g} fps on loopback ({workers} server worker(s))",
        (
            f"frames sent {figures['frames_sent']}, received {figures['frames_received']}, dropped "
            f"{figures['dropped']}, reordered {figures['reordered']}, "
            f"largest difference from a local run {figures['max_error_deg']:.2g} deg"
        ),
        (
            f"latency p50 {figures['latency_ms_p50']:.2f} ms, p99 {figures['latency_ms_p99']:.2f} ms, max "
            f"{figures['latency_ms_max']:.2f} ms"
        ),
        (
            f"server CPU {figures['server_cpu_cores']:.2f} cores, mean batch {figures['mean_batch']:.1f} streams per "
            "step, "
            f"memory {figures['server_rss_mb'][0]:.0f} -> {figures['server_rss_mb'][-1]:.0f} MB (peak "
            f"{max(figures['server_rss_mb']):.0f}), tracebacks {figures['server_tracebacks']}, "
            f"client late sends {figures['late_client_sends']}, errors {len(figures['errors'])}"
        ),
    ]
    if faulty:
        lines.append(
            f"{faulty} faulty clients, {figures['faulty_episodes']} episodes: "
            f"{json.dumps(figures['faulty_outcomes'])}; streams left open {figures['streams_left']}"
        )
    return "\n".join(lines)
