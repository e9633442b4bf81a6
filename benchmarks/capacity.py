"""How many real-time streams one machine serves: for 1, 2 and 3 server processes (``serve
--workers``), the most streams at 30 fps whose frame latency stays within one frame time
(p99 <= 33 ms) with nothing dropped, found by a ladder of load tests.

    python benchmarks/capacity.py [--seconds 10] [--processes 1 2 3] [-o docs/capacity.json]

Two kinds of client: single-stream connections (a VTuber's mocap, ``stream-bvh``) and crowds
of 10 streams a connection (a game's NPCs, a hello's ``streams``); the labeller runs (no labels
given) as it does for users' streams. The load generator runs on the same machine and shares
its cores: on a machine of its own the server holds more. docs/DEPLOY.md has the table.
"""

from __future__ import annotations

import argparse
import json

from styleerd.atomic import atomic_write_text
from styleerd.runtime.system import system_report
from styleerd.serve.loadtest import run_load_test

FRAME_MS = 1000 / 30
LADDER = (10, 20, 30, 40, 60, 80, 100, 130, 160, 200, 260, 330, 400, 500, 650, 800, 1000)


def holds(streams: int, each: int, processes: int, seconds: float) -> tuple[bool, dict]:
    """One load test: ``streams`` in connections of ``each``; -> (within one frame time, figures)."""
    _, f = run_load_test(streams // each, seconds, streams_per_client=each, server_args=("--workers", str(processes)))
    ok = f["latency_ms_p99"] <= FRAME_MS and f["dropped"] == 0 and f["reordered"] == 0 and not f["errors"]
    print(
        f"  {processes} process(es), {streams} streams ({each} a connection): p99 {f['latency_ms_p99']:.1f} ms, "
        f"dropped {f['dropped']}: {'holds' if ok else 'does not hold'}",
        flush=True,
    )
    return ok, f


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--processes", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("-o", "--output", default="docs/capacity.json")
    args = ap.parse_args()
    rows = []
    for each in (1, 10):
        for processes in args.processes:
            best, figures = 0, None
            for streams in (n for n in LADDER if n % each == 0):
                ok, f = holds(streams, each, processes, args.seconds)
                if not ok:
                    break
                best, figures = streams, f
            rows.append(
                {
                    "streams_a_connection": each,
                    "processes": processes,
                    "streams": best,
                    "p99_ms": None if figures is None else round(figures["latency_ms_p99"], 1),
                }
            )
    system = system_report()
    cores = system["cores"]
    print("| processes | streams a connection | streams at 30 fps, p99 <= 33 ms | streams a core | p99 (ms) |")
    print("| --- | --- | --- | --- | --- |")
    for r in rows:
        print(
            f"| {r['processes']} | {r['streams_a_connection']} | {r['streams']} | {r['streams'] / cores:.0f} | "
            f"{r['p99_ms']} |"
        )
    atomic_write_text(args.output, json.dumps({"system": system, "seconds": args.seconds, "rows": rows}, indent=1))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
