"""Parse + features for every Bandai-Namco-2 clip, from a cold cache and from a warm one.

    python benchmarks/bench_data.py [--data DIR] [--workers N]

Cold: an empty cache folder, so the archive is unpacked, every BVH parsed, features computed
and the .npz cache written. Warm: the same call again, which loads the cache. Targets on the
2-core reference machine: cold <= 60 s, warm <= 3 s.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from styleerd.data.cache import prepare
from styleerd.data.datasets import data_root, unpack


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data")
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    args = ap.parse_args()
    root = data_root(args.data)
    with tempfile.TemporaryDirectory(prefix="styleerd-bench-") as tmp:
        cache = Path(tmp)
        t0 = time.perf_counter()
        unpack(root / "bandai-namco-2.tar.xz", cache)
        t1 = time.perf_counter()
        fs = prepare("bandai-namco-2", root, cache=cache, workers=args.workers, progress=False)
        t2 = time.perf_counter()
        warm = prepare("bandai-namco-2", root, cache=cache, workers=args.workers, progress=False)
        t3 = time.perf_counter()
        assert len(warm.names) == len(fs.names) == 2762
        frames = len(fs.features)
        size = fs.path.stat().st_size / 2**20
    print(f"bandai-namco-2: {len(fs.names)} clips, {frames:,} frames, {args.workers} workers, cache {size:.0f} MiB")
    print(f"cold  unpack archive          {t1 - t0:6.2f} s")
    print(f"cold  parse + features + save {t2 - t1:6.2f} s  ({frames / (t2 - t1):,.0f} frames/s)")
    print(f"cold  total                   {t2 - t0:6.2f} s  (target <= 60 s)")
    print(f"warm  load cache              {t3 - t2:6.2f} s  (target <= 3 s)")


if __name__ == "__main__":
    main()
