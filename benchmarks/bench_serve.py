"""The style server under load, its protocols side by side in one run: the same real-time
clients (30 fps, loopback) against a fresh server for each row.

    python benchmarks/bench_serve.py [--seconds 20] [--before COMMIT] [--rounds N] [--only NAME ...]
                                     [-o docs/protocol-bench.json]

Rows: 40 single-stream connections (a light live load) on the numpy step (the server's default
until now) and on the numba step (the default); 200 single-stream connections (numpy on asyncio's
event loop and on uvloop, then numba); the same 200 streams on 2 connections of 100 (a hello's
``streams``); 1,000 streams on 10 connections (labels given: no labeller); the last two again on
the network's own pose (the clients' ``"pose": "network"``: one pass, no blend towards the input),
beside 200 single-stream connections with labels given on the default pose. Each row prints the
server's CPU a frame, split into the engine (the stylizer's steps) and the protocol (everything
else), latency p50/p99/max, and frames dropped, reordered or changed (every reply against a local
run). The load generator shares the machine's cores with the server. ``--before COMMIT`` serves
each row also with that commit's server (a git worktree), the two in alternating order, the same
clients; ``--rounds N`` runs each row N times, the order alternating each time (a worktree's first
server compiles what numba has not cached for its paths, so compare rounds after the first).
``styleerd load-test`` runs one row (and the soak test, ``--faulty``); CI runs a reduced
size (tests/test_server.py, test_crowd.py).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

from styleerd.atomic import atomic_write_text
from styleerd.runtime.system import system_report
from styleerd.serve.loadtest import run_load_test

ROOT = Path(__file__).resolve().parents[1]

ROWS = [  # (name, connections, streams each, labels given, server options, the clients' pose path)
    ("40 x 1 stream, numpy (the default until now)", 40, 1, False, ("--backend", "numpy"), "input"),
    ("40 x 1 stream, numba (the default)", 40, 1, False, ("--backend", "numba"), "input"),
    ("200 x 1 stream, numpy, asyncio loop", 200, 1, False, ("--loop", "asyncio", "--backend", "numpy"), "input"),
    ("200 x 1 stream, numpy, uvloop", 200, 1, False, ("--loop", "uvloop", "--backend", "numpy"), "input"),
    ("200 x 1 stream, numba, uvloop", 200, 1, False, ("--loop", "uvloop", "--backend", "numba"), "input"),
    ("2 x 100 streams, numba, uvloop", 2, 100, False, ("--loop", "uvloop", "--backend", "numba"), "input"),
    ("10 x 100 streams, numba, labels given", 10, 100, True, ("--loop", "uvloop", "--backend", "numba"), "input"),
    ("200 x 1 stream, numba, labels given", 200, 1, True, ("--loop", "uvloop"), "input"),
    # the paper's pose path (one pass, no blend towards the input), beside the two rows above
    ("200 x 1 stream, numba, labels given, pose network", 200, 1, True, ("--loop", "uvloop"), "network"),
    ("10 x 100 streams, numba, labels given, pose network", 10, 100, True, ("--loop", "uvloop"), "network"),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--before", help="also serve each row with this commit's server, in alternating order")
    ap.add_argument("--rounds", type=int, default=1, help="each row this many times, the order alternating")
    ap.add_argument("--only", nargs="*", default=[], help="the rows whose name holds one of these")
    ap.add_argument("-o", "--output", default="docs/protocol-bench.json")
    args = ap.parse_args()
    chosen = [r for r in ROWS if not args.only or any(o in r[0] for o in args.only)]
    with tempfile.TemporaryDirectory() as tmp:
        servers: dict[str, str | None] = {"now": None}
        if args.before:
            tree = str(Path(tmp) / "before")
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", tree, args.before], check=True)
            servers = {f"before ({args.before})": tree, "now": None}
        try:
            rows = []
            runs = [(row, k) for row in chosen for k in range(args.rounds)]
            for i, ((name, clients, each, labels, server, pose), k) in enumerate(runs):
                for who in list(servers)[:: 1 if i % 2 == 0 else -1]:
                    summary, figures = run_load_test(
                        clients,
                        args.seconds,
                        streams_per_client=each,
                        labels=labels,
                        server_args=server,
                        server_code=servers[who],
                        pose=pose,
                    )
                    print(f"## {name}, {who}, round {k + 1}\n{summary}\n", flush=True)
                    rows.append(
                        {
                            "row": name,
                            "server": who,
                            "round": k + 1,
                            "server_args": list(server),
                            "pose": pose,
                            **figures,
                        }
                    )
        finally:
            if args.before:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", tree], check=False)
    print(
        "| load | server | round | server CPU a frame (us) | engine | protocol | latency p50 / p99 / max (ms) | "
        "dropped | reordered | largest difference from a local run (deg) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(
            f"| {r['row']} | {r['server']} | {r['round']} | {r['server_cpu_us_per_frame']:.1f} | "
            f"{r['engine_cpu_us_per_frame']:.1f} | {r['server_cpu_us_per_frame'] - r['engine_cpu_us_per_frame']:.1f} | "
            f"{r['latency_ms_p50']:.0f} / "
            f"{r['latency_ms_p99']:.0f} / {r['latency_ms_max']:.0f} | {r['dropped']} | {r['reordered']} | "
            f"{r['max_error_deg']:.2g} |"
        )
    atomic_write_text(
        args.output,
        json.dumps(
            {
                "system": system_report(),
                "seconds": args.seconds,
                "before": args.before,
                "rounds": args.rounds,
                "rows": rows,
            },
            indent=1,
        ),
    )
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
