"""Other clients against one honest stream (issue 36): a probe stream's reply latency (30 fps, real
time, 300 frames) with nobody else, under 1,000 watcher connections, under six clients looping
on ``/clips/generated...`` over HTTP; and the lockout: after a watcher with the token "é", how many
of 300 private hellos are answered ``ready``.

    python benchmarks/bench_abuse.py [--code DIR] [--json docs/abuse-bench.json]

``--code DIR``: the server runs the styleerd in DIR (a checkout of another commit: its "before").
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import time
from pathlib import Path
from urllib.parse import quote

import numpy as np
from websockets.asyncio.client import connect

from styleerd.atomic import atomic_write_text
from styleerd.motion import bvh
from styleerd.motion.procedural import walk
from styleerd.serve.client import SEQ, hello
from styleerd.serve.loadtest import free_port, start_server, stop_server

WALK = walk(12.0, fps=30.0)
VALUES = bvh.channel_values(WALK).astype("<f4")


async def probe(url: str, frames: int = 300) -> dict:
    """Reply latency of a real-time stream (ms): p50, p99, max."""
    async with connect(url, open_timeout=60, max_size=None) as ws:
        await ws.send(json.dumps(hello(WALK, 30.0, "elderly", 1.0, None, "probe", "normal", "walk")))
        assert json.loads(await ws.recv())["type"] == "ready"
        latency, start = [], time.perf_counter()
        for i in range(frames):
            await asyncio.sleep(max(0.0, start + i / 30.0 - time.perf_counter()))
            sent = time.perf_counter()
            await ws.send(SEQ.pack(i) + VALUES[i % len(VALUES)].tobytes())
            while True:
                reply = await ws.recv()
                if isinstance(reply, bytes) and SEQ.unpack_from(reply)[0] == i:
                    break
            latency.append(1000 * (time.perf_counter() - sent))
    return {
        "p50_ms": round(float(np.median(latency)), 2),
        "p99_ms": round(float(np.percentile(latency, 99)), 2),
        "max_ms": round(max(latency), 2),
    }


async def watchers(url: str, n: int, hold: asyncio.Event) -> dict:
    """``n`` watchers of any stream (the probe's), held open until ``hold`` is set and reading
    nothing; -> how many were let in."""
    admitted = refused = 0

    async def one() -> None:
        nonlocal admitted, refused
        try:
            async with connect(url, open_timeout=60) as ws:
                await ws.send(json.dumps({"type": "watch"}))  # any stream: the probe's
                first = json.loads(await ws.recv())
                if first.get("type") != "waiting":
                    refused += 1
                    return
                admitted += 1
                await hold.wait()
        except Exception:  # noqa: BLE001  closed by the server (1013) or any other way: refused
            refused += 1

    tasks = [asyncio.create_task(one()) for _ in range(n)]
    while admitted + refused < n:
        await asyncio.sleep(0.2)
    return {"tried": n, "admitted": admitted, "refused": refused, "tasks": tasks}


async def http_load(port: int, clients: int, stop: asyncio.Event) -> int:
    """``clients`` loops of GET /clips/generated walk ...; -> requests answered."""
    path = "/clips/" + quote("generated walk (T-pose skeleton, 30 fps)")
    done = 0

    async def loop() -> None:
        nonlocal done
        while not stop.is_set():
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n".encode())
            await writer.drain()
            await reader.read()
            writer.close()
            done += 1

    tasks = [asyncio.create_task(loop()) for _ in range(clients)]
    await stop.wait()
    await asyncio.gather(*tasks, return_exceptions=True)
    return done


async def lockout(url: str, hellos: int = 300) -> dict:
    """A watcher with a non-ASCII token, then ``hellos`` private hellos one after another."""
    ready = 0
    w = await connect(url, open_timeout=60)  # held open while the hellos come
    await w.send(json.dumps({"type": "watch", "token": "é"}))
    for k in range(hellos):
        try:
            async with connect(url, open_timeout=60) as ws:
                await ws.send(json.dumps({**hello(WALK, 30.0, "elderly", 1.0, None, f"private-{k}"), "private": True}))
                ready += json.loads(await asyncio.wait_for(ws.recv(), 20)).get("type") == "ready"
        except Exception:  # noqa: BLE001, S110  a hello not answered counts as not ready
            pass
    await w.close()
    after = 0
    try:
        async with connect(url, open_timeout=60) as ws:  # an honest client afterwards
            await ws.send(json.dumps(hello(WALK, 30.0, "elderly", 1.0, None, "honest")))
            after = json.loads(await asyncio.wait_for(ws.recv(), 20)).get("type") == "ready"
    except Exception:  # noqa: BLE001, S110  refused in any way: not ready
        pass
    return {"private_hellos": hellos, "ready": ready, "an_honest_client_after": bool(after)}


async def measure(port: int) -> dict:
    url = f"ws://127.0.0.1:{port}/"
    out = {"idle": await probe(url)}
    hold = asyncio.Event()
    crowd = await watchers(url, 1000, hold)
    out["1000 watchers"] = {**await probe(url), **{k: v for k, v in crowd.items() if k != "tasks"}}
    hold.set()
    await asyncio.gather(*crowd["tasks"], return_exceptions=True)
    stop = asyncio.Event()
    load = asyncio.create_task(http_load(port, 6, stop))
    await asyncio.sleep(1.0)
    out["6 HTTP clients on /clips/generated"] = await probe(url)
    stop.set()
    out["6 HTTP clients on /clips/generated"]["requests"] = await load
    out["lockout"] = await lockout(url)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--code", type=Path, help="run the server from this styleerd checkout")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    args.json = args.json.resolve() if args.json else None
    if args.code:  # ``python -m`` puts the working folder first on the path
        os.environ["PYTHONPATH"] = str(args.code.resolve())
        os.chdir(args.code)
    port = free_port()
    proc = start_server(port)
    try:
        result = asyncio.run(measure(port))
    finally:
        stop_server(proc)
    print(json.dumps(result, indent=1))
    if args.json:
        kept = json.loads(args.json.read_text()) if args.json.is_file() else {}
        kept["before" if args.code else "after"] = result
        atomic_write_text(args.json, json.dumps(kept, indent=1) + "\n")


if __name__ == "__main__":
    main()
