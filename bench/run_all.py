"""``make bench``: every benchmark in turn; each writes its table/chart under bench/results/."""
from __future__ import annotations

import importlib
import sys
import time

BENCHES = ("bench.bench_synth", "bench.bench_train", "bench.bench_stage2", "bench.bench_export", "bench.bench_relight",
           "bench.bench_study", "bench.bench_view", "bench.bench_batch", "bench.bench_compile",
           "bench.bench_anchors")


def main() -> int:
    for name in BENCHES:
        t = time.time()
        print(f"== {name}", flush=True)
        rc = importlib.import_module(name).main([]) or 0
        print(f"== {name}: exit {rc} in {time.time() - t:.0f} s", flush=True)
        if rc:
            return rc
    return 0


if __name__ == "__main__":
    sys.exit(main())
