"""Heavy hellos beside a live stream: does one client's large skeleton stall the others?

    python benchmarks/bench_heavy_hellos.py [--seconds 10] [--joints 8000 480]

Starts ``styleerd serve`` (default settings), plays a 30 fps real-time stream twice: alone,
then while ten clients at once send hellos with skeletons of each size in ``--joints`` (a
humanoid plus chains of extra joints: 8,000 is refused by --max-joints, 480 is accepted and
set up). Prints the stream's latency p50/p99/max both times, side by side in one run.
"""

from __future__ import annotations

import argparse
import asyncio
import json

import numpy as np
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from styleerd.motion import bvh
from styleerd.motion.procedural import walk, with_extra_joints
from styleerd.serve.client import hello, play
from styleerd.serve.loadtest import free_port, start_server, stop_server


async def heavy_hello(url: str, text: str) -> str:
    """-> "ready", "error: ..." (the server's message), or "closed CODE" with no message."""
    async with connect(url, max_size=1 << 22, open_timeout=30) as ws:
        await ws.send(json.dumps({"type": "hello", "skeleton": text, "fps": 30, "style": "elderly"}))
        try:
            reply = json.loads(await ws.recv())
        except ConnectionClosed as e:
            return f"closed {e.rcvd.code if e.rcvd else None} without a message"
        return reply["type"] if reply["type"] == "ready" else f"{reply['type']}: {reply.get('message', '')[:60]}"


async def stream_with(url: str, seconds: float, texts: list[str]) -> tuple[dict, list[str]]:
    motion = walk(seconds, fps=30.0)
    player = asyncio.create_task(play(url, motion, hello(motion, 30.0, "elderly", 1.0, None, "probe")))
    await asyncio.sleep(seconds / 3)
    answers = await asyncio.gather(*(heavy_hello(url, t) for t in texts))
    result = await player
    lat = np.array(result.latencies_ms)
    return {
        "p50": np.percentile(lat, 50),
        "p99": np.percentile(lat, 99),
        "max": lat.max(),
        "received": result.received,
        "sent": result.sent,
    }, answers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--joints", type=int, nargs="+", default=[8000, 480])
    args = ap.parse_args()
    port = free_port()
    server = start_server(port)
    url = f"ws://127.0.0.1:{port}/"
    try:
        rows = [("alone", *asyncio.run(stream_with(url, args.seconds, [])))]
        for joints in args.joints:
            text = bvh.format_header(with_extra_joints(walk(0.2, fps=30.0).skeleton, joints), 0, 30.0).replace(
                "\t", ""
            )  # fits in 1 MB
            rows.append((f"10 hellos of +{joints} joints", *asyncio.run(stream_with(url, args.seconds, [text] * 10))))
    finally:
        stop_server(server)
    print("| the 30 fps stream | latency p50 ms | p99 ms | max ms | frames received/sent | the heavy hellos got |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, r, answers in rows:
        got = ", ".join(f"{answers.count(a)} {a}" for a in sorted(set(answers))) or "-"
        print(f"| {name} | {r['p50']:.1f} | {r['p99']:.1f} | {r['max']:.1f} | {r['received']}/{r['sent']} | {got} |")


if __name__ == "__main__":
    main()
