"""``styleerd load-test``: start a server in its own process(es) on a free loopback port, run
N real-time clients against it (and, for a soak test, faulty clients beside them), print the
figures (and stop the server cleanly)."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
from tqdm import tqdm

from styleerd.atomic import atomic_write_text
from styleerd.errors import StyleERDError
from styleerd.motion import bvh
from styleerd.motion.motion import Motion
from styleerd.motion.procedural import walk
from styleerd.serve.client import LABELS, PHASE, load_test


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(port: int, *args: str, code: str | None = None) -> subprocess.Popen:
    """``styleerd serve`` on ``port`` in a new process; returns once it accepts connections.
    ``code``: a checkout whose ``styleerd`` runs instead of the installed one (another commit's)."""
    # a file, not a pipe: a chatty server never blocks on it; closed with the process
    log = tempfile.TemporaryFile("w+")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "styleerd.cli", "serve", "--port", str(port), *args],
        stdout=log,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1", **({"PYTHONPATH": code} if code else {})},
        cwd=code,
    )
    proc.log = log
    deadline = time.time() + 300  # a first start after an install compiles the engine: a minute on 2 cores
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


def start_behind_haproxy(
    config: Path, *server_args: str, names: tuple[str, ...] = ("s0", "s1", "s2")
) -> tuple[int, dict[str, tuple[int, subprocess.Popen]], subprocess.Popen]:
    """``styleerd serve --id NAME`` for each name, behind HAProxy with ``config`` (deploy/haproxy.cfg:
    addresses from ``STYLEERD_*``), all on loopback; returns (the balancer's port, {name: (port,
    process)}, HAProxy's process) once HAProxy has seen every process healthy."""
    haproxy = shutil.which("haproxy") or "/usr/sbin/haproxy"
    servers = {}
    for name in names:
        port = free_port()
        servers[name] = (port, start_server(port, "--id", name, *server_args))
    front = free_port()
    env = {**os.environ, "STYLEERD_BIND": f"127.0.0.1:{front}"}
    env.update({f"STYLEERD_{name.upper()}": f"127.0.0.1:{port}" for name, (port, _) in servers.items()})
    check = subprocess.run([haproxy, "-c", "-f", str(config)], env=env, capture_output=True, text=True, check=False)
    if check.returncode != 0:
        raise StyleERDError(f"{config}: HAProxy refuses it: {check.stdout}{check.stderr}")
    proxy = subprocess.Popen([haproxy, "-db", "-f", str(config)], env=env, stderr=subprocess.DEVNULL)
    deadline = time.time() + 20
    while time.time() < deadline:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{front}/healthz", timeout=2):
                break
        except OSError:  # not listening yet, or 503: no process up yet
            time.sleep(0.2)
    time.sleep(2.5)  # two checks of every process (inter 1s, rise 2)
    return front, servers, proxy


def stop_behind_haproxy(servers: dict[str, tuple[int, subprocess.Popen]], proxy: subprocess.Popen) -> list[int]:
    """Stop HAProxy and every server still running; -> the servers' exit codes."""
    proxy.terminate()
    proxy.wait(10)
    return [stop_server(proc) for _, proc in servers.values() if proc.poll() is None]


def server_log(proc: subprocess.Popen) -> str:
    proc.log.seek(0)
    return proc.log.read()


def tree_cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` and every process under it (a server's workers)."""
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        try:
            stat = Path(f"/proc/{p}/stat").read_text()
            ticks = stat[stat.rindex(")") + 2 :].split()[11:15]  # utime, stime, and of children waited for
            total += sum(map(int, ticks)) / os.sysconf("SC_CLK_TCK")
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, ValueError):  # gone in between
            continue
    return total


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def expected_output(
    motion: Motion,
    frames: int,
    fps: float = 30.0,
    style: str = "elderly",
    streams: int = 1,
    labels: bool = False,
    pose: str = "input",
) -> np.ndarray:
    """What a well-behaved client of the load test should get back: its looped clip stylised
    locally, from float32 values as they go over the wire: ``[frames, C]``, or for a connection
    of ``streams`` > 1 (stream k from frame ``PHASE * k``) ``[frames, streams, C]``."""
    from styleerd.model.stored import load_generator_weights
    from styleerd.runtime.channels import ChannelStylizer

    values = bvh.channel_values(motion).astype("<f4").astype(np.float64)
    model = load_generator_weights()
    known = LABELS if labels else (None, None)
    local = ChannelStylizer(model, motion.skeleton, {style: 1.0}, *known, fps=fps, n_streams=streams, pose=pose)
    phases = PHASE * np.arange(streams)
    out = np.stack(
        [
            local.step(values[(i + phases) % len(values)])
            for i in tqdm(range(frames), desc="local reference", unit="frame", leave=False)
        ]
    )
    return out if streams > 1 else out[:, 0]


def run_load_test(
    clients: int,
    seconds: float,
    output: str | None = None,
    faulty: int = 0,
    streams_per_client: int = 1,
    labels: bool = False,
    server_args: tuple[str, ...] = (),
    server_code: str | None = None,
    pose: str = "input",
) -> tuple[str, dict]:
    """The load test (and, with ``faulty``, the soak test): every well-behaved client's replies
    are compared with a local run of the same clip. ``labels``: the hellos give the clip's
    input style and content (a neutral walk), so the server runs no labeller; ``pose``: the pose path they
    ask for (``"network"``: one pass, no blend towards the input). ``server_args``:
    ``styleerd serve``'s options (``--workers 2``, ``--backend numba``...); ``server_code``: a checkout
    of another commit to serve with (``start_server``). -> (a summary, the figures)."""
    motion = walk(10.0, fps=30.0)
    reference = expected_output(
        motion, int(round(seconds * 30.0)), streams=streams_per_client, labels=labels, pose=pose
    )
    port = free_port()
    room = clients * streams_per_client + faulty + 8
    server = start_server(port, "--max-streams", str(max(256, room)), *server_args, code=server_code)
    workers = int(server_args[server_args.index("--workers") + 1]) if "--workers" in server_args else 1
    rss: list[float] = []  # the server's memory every 5 s (one worker)
    stop = threading.Event()

    def sample() -> None:
        while workers == 1 and not stop.wait(0 if not rss else 5.0):
            rss.append(round(_rss_mb(server.pid), 1))

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    cpu_before = tree_cpu_seconds(server.pid)
    try:
        figures = asyncio.run(
            load_test(
                f"ws://127.0.0.1:{port}/",
                motion,
                clients,
                seconds,
                faulty=faulty,
                reference=reference,
                streams_per_client=streams_per_client,
                labels=labels,
                pose=pose,
            )
        )
        cpu_after = tree_cpu_seconds(server.pid)
        stop.set()
        sampler.join()
        figures["server_rss_mb"] = rss or [float("nan")]
        figures["server_tracebacks"] = server_log(server).count("Traceback")
    finally:
        code = stop_server(server)
    figures["server_exit_code"] = code
    if workers > 1:  # the stats answer for one worker: the CPU of them all from the system, the frames from the clients
        figures["server_cpu_cores"] = (cpu_after - cpu_before) / figures["wall_s"]
        figures["server_frames"] = figures["frames_received"]
        figures["server_step_cpu_s"] = None
    frames = max(1, figures["server_frames"])
    per_frame_us = figures["server_cpu_cores"] * figures["wall_s"] / frames * 1e6
    engine_us = None if figures["server_step_cpu_s"] is None else figures["server_step_cpu_s"] / frames * 1e6
    figures["server_cpu_us_per_frame"], figures["engine_cpu_us_per_frame"] = per_frame_us, engine_us
    if output:
        atomic_write_text(Path(output), json.dumps(figures, indent=1))
    each = f" x {streams_per_client} streams" if streams_per_client > 1 else ""
    lines = [
        (
            f"{clients} clients{each} x {seconds:g} s at {figures['fps']:g} fps on loopback ({workers} server "
            f"worker(s){', ' + ' '.join(server_args) if server_args else ''}{', labels given' if labels else ''}, "
            f"pose {pose})"
        ),
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
            f"server CPU {figures['server_cpu_cores']:.2f} cores ({per_frame_us:.1f} us a frame"
            + (
                f": engine {engine_us:.1f}, protocol {per_frame_us - engine_us:.1f}), "
                if engine_us is not None
                else f", all {workers} workers), "
            )
            + f"mean batch {figures['mean_batch']:.1f} streams per "
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
    return "\n".join(lines), figures
