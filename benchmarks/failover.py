"""Failover: three ``styleerd serve`` processes behind HAProxy (deploy/haproxy.cfg), real-time
clients that reconnect (the client library's ``play(reconnect=True)``, as ``stream-bvh
--reconnect``), and one process killed with SIGKILL under load.

    python benchmarks/failover.py [--clients 30] [--seconds 12] [-o docs/failover.json]

Prints, for the clients of the killed process: frames sent again (sent, never answered, and
sent again on the new connection), the time from noticing the loss to the first stylised frame
from another process, and that every client got every frame in order. Then what the avatar
shows after reconnecting: a new stream starts mid-motion from the model's learned initial
states, so the style recognition (SRA) of its first 10 frames is set against later windows, on
the Bandai-Namco-2 test clips streamed from frame 30 (``eval.metrics.responsiveness``; needs
styleerd[train] and the data).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import time
from pathlib import Path

import numpy as np

from styleerd.atomic import atomic_write_text
from styleerd.motion.procedural import walk
from styleerd.serve.client import hello, play
from styleerd.serve.loadtest import start_behind_haproxy, stop_behind_haproxy

ROOT = Path(__file__).resolve().parents[1]


async def clients_through(url: str, n: int, seconds: float) -> list:
    m = walk(10.0, fps=30.0)
    runs = [play(url, m, hello(m, 30.0, "elderly", 1.0, None, f"c{i}"), seconds, reconnect=True) for i in range(n)]
    return await asyncio.gather(*runs)


def live_failover(clients: int, seconds: float) -> dict:
    front, servers, proxy = start_behind_haproxy(ROOT / "deploy/haproxy.cfg")
    try:

        async def run() -> list:
            task = asyncio.create_task(clients_through(f"ws://127.0.0.1:{front}/", clients, seconds))
            await asyncio.sleep(seconds / 3)
            servers["s0"][1].kill()  # SIGKILL: no close frames, the kernel resets the connections
            return await task

        t0 = time.perf_counter()
        results = asyncio.run(run())
        wall = time.perf_counter() - t0
    finally:
        stop_behind_haproxy(servers, proxy)
    moved = [r for r in results if r.reconnects]
    total = int(round(seconds * 30))
    back = np.array([r.reconnected_ms for r in moved if r.reconnected_ms is not None])
    return {
        "clients": clients,
        "seconds": seconds,
        "wall_s": round(wall, 1),
        "clients_moved": len(moved),
        "every_frame_answered_in_order": all(r.received == total and r.reordered == 0 for r in results),
        "frames_sent_again": sum(r.resent for r in moved),
        "ms_to_first_frame_after_loss_p50": float(np.median(back)) if len(back) else None,
        "ms_to_first_frame_after_loss_max": float(back.max()) if len(back) else None,
        "errors": [r.error for r in results if r.error],
    }


def style_after_reconnecting(start: int) -> dict:
    from styleerd.eval.metrics import responsiveness
    from styleerd.model import checkpoint as ckpt
    from styleerd.train.config import TrainConfig
    from styleerd.train.trainer import setup

    model, _ = ckpt.load_generator()
    style_rec, _, _ = ckpt.load_recognisers()
    fmd, _ = ckpt.load_fmd()
    s = setup(TrainConfig(), None, progress=False)
    return {"from_frame": start, **responsiveness(model, s, style_rec, fmd, start=start)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=30)
    ap.add_argument("--seconds", type=float, default=12.0)
    ap.add_argument("-o", "--output", default="docs/failover.json")
    args = ap.parse_args()
    live = live_failover(args.clients, args.seconds)
    print(json.dumps(live, indent=1), flush=True)
    style = {"from_the_first_frame": style_after_reconnecting(0), "mid_motion": style_after_reconnecting(30)}
    print(json.dumps(style, indent=1))
    atomic_write_text(args.output, json.dumps({"live": live, "style_after_reconnecting": style}, indent=1))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
