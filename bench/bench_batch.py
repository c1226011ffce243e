"""What `srvol batch` costs over running the same steps by hand: four scenes, one after another.

By hand: for each scene, the very commands the batch runs (`srvol train / eval / export / report`,
from :func:`srvol.batch.steps.step_command`), one process after another, each with
OMP_NUM_THREADS=--threads. Then `srvol batch` over the same four scenes into a fresh folder, with
--threads equal to the machine's CPUs, so that it too runs one job at a time (Ray starts inside the
command). Both train a fixed number of iterations, so the work is the same; the overhead is the
difference of the wall times over the by-hand total (Ray's start, scheduling, polling).

    OMP_NUM_THREADS=2 python -m bench.bench_batch [--iters 400] [--threads 2]

writes bench/results/batch_table.md/.json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from bench.paths import REPO, write_result
from srvol.batch.steps import STEPS, JobSpec, Source, step_command

RESULTS = REPO / "bench" / "results"
WORK = REPO / "bench" / "work" / "batch"
SCENES = (("bumpy", 0), ("torus", 1), ("cup", 2), ("bunny", 3))
"""Four small scenes (name, seed): LR 48x36, 10 training + 1 test views."""


def ensure_scenes() -> list[Path]:
    out = []
    for name, seed in SCENES:
        scene = WORK / "scenes" / name
        if not (scene / "cameras.json").is_file():
            subprocess.run([sys.executable, "-m", "srvol", "synth", name, "--out", str(scene), "--lr", "48x36",
                            "--views", "10", "--test-views", "1", "--seed", str(seed), "--force"], check=True,
                           capture_output=True)
        out.append(scene)
    return out


def by_hand(scenes: list[Path], spec: JobSpec) -> tuple[float, dict[str, float]]:
    """Every step of every scene, one process after another; (total seconds, seconds per step)."""
    env = dict(os.environ, OMP_NUM_THREADS=str(spec.threads))
    per_step = dict.fromkeys(spec.steps, 0.0)
    t_all = time.time()
    for scene in scenes:
        src = Source(scene.name, scene, "scene", WORK / "by_hand" / scene.name)
        shutil.rmtree(src.out, ignore_errors=True)
        src.out.mkdir(parents=True)
        for step in spec.steps:
            t0 = time.time()
            subprocess.run([sys.executable, "-m", "srvol", *step_command(src, step, spec)], check=True, env=env,
                           capture_output=True)
            per_step[step] += time.time() - t0
    return time.time() - t_all, per_step


def with_batch(scenes: list[Path], spec: JobSpec) -> float:
    out = WORK / "batch_out"
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "srvol", "batch", *map(str, scenes), "--out", str(out), "--iters",
           str(spec.iters), "--threads", str(spec.threads), "--quiet"]
    t0 = time.time()
    subprocess.run(cmd, check=True, capture_output=True)
    return time.time() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iters", type=int, default=400, help="training iterations per scene (default 400)")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 2,
                    help="threads per job (default: the machine's CPUs: one job at a time)")
    args = ap.parse_args(argv)
    spec = JobSpec(steps=tuple(s for s in STEPS if s != "import"), threads=args.threads, iters=args.iters)
    scenes = ensure_scenes()
    hand, per_step = by_hand(scenes, spec)
    batch = with_batch(scenes, spec)
    overhead = (batch - hand) / hand
    row = {"scenes": [s.name for s in scenes], "iters": args.iters, "threads": args.threads,
           "by_hand_s": round(hand, 1), "batch_s": round(batch, 1), "overhead": round(overhead, 4),
           "by_hand_step_s": {k: round(v, 1) for k, v in per_step.items()}}
    steps = " + ".join(f"{k} {v:.0f} s" for k, v in per_step.items())
    text = "\n".join([
        "# srvol batch against the same steps by hand (one machine)", "",
        f"Four scenes ({', '.join(row['scenes'])}; LR 48x36, 10 + 1 views), {args.iters} training iterations each, "
        f"{args.threads} threads per job; by hand: the batch's own step commands one after another. "
        "Reproduce: `OMP_NUM_THREADS=2 python -m bench.bench_batch`.", "",
        "| | wall s | ratio |", "|---|---|---|",
        f"| by hand ({steps}) | {hand:.1f} | 1.000 |",
        f"| srvol batch (local Ray) | {batch:.1f} | {batch / hand:.3f} |", "",
        f"Overhead of srvol batch: {overhead:+.1%} of the total (target <= 5 %).", ""])
    write_result(RESULTS / "batch_table.md", text)
    write_result(RESULTS / "batch_table.json", json.dumps(row, indent=1) + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
