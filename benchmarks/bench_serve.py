"""The style server under load: N real-time clients (30 fps) on loopback for T seconds.

    python benchmarks/bench_serve.py [--clients 200] [--seconds 60] [--workers 1] [-o docs/load-test.json]
    python benchmarks/bench_serve.py --clients 200 --seconds 600 --faulty 20 -o docs/soak.json   # the soak test

Starts ``styleerd serve`` in its own process, runs the clients in this one (the same
``play`` loop as ``styleerd stream-bvh``), prints frame latency p50/p99, dropped and reordered
frames, every reply's difference from a local run, the server's CPU use and memory. With
``--faulty``, that many more clients misbehave in turn meanwhile (malformed frames, slow
readers, vanishing mid-stream, bad hellos). CI runs it at a reduced size (tests/test_server.py).
"""

from __future__ import annotations

import argparse

from styleerd.serve.loadtest import run_load_test


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--faulty", type=int, default=0)
    ap.add_argument("-o", "--output", default="docs/load-test.json")
    args = ap.parse_args()
    print(run_load_test(args.clients, args.seconds, args.workers, args.output, args.faulty))


if __name__ == "__main__":
    main()
