"""What each real-capture term buys: train on an imported synthetic capture with all terms, with
none, and with each one off in turn; score every run against the capture's ground truth.

Needs the imported scene and the capture's GT of ``bench.bench_import`` (bench/work/scene_NAME,
bench/work/capture_NAME/gt; that bench makes them). Each run: ``srvol train SCENE --capture-terms
...`` for ``--budget`` seconds, then ``srvol eval RUN --gt GT`` (HR test views, normals and relit
views in the GT frame after one per-channel gain; the exported mesh's Chamfer distance). Runs go
``--parallel`` at a time, each on OMP_NUM_THREADS=1 (all arms share the machine alike).

    OMP_NUM_THREADS=2 python -m bench.bench_capture_terms --scene bunny --budget 300

writes bench/results/capture_terms_table.md/.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

from bench.paths import REPO, write_result
from srvol.capture.terms import TERM_NAMES

RESULTS = REPO / "bench" / "results"
WORK = REPO / "bench" / "work"
KEYS = ("psnr_hr", "ssim_hr", "normal_mae_deg", "albedo_psnr", "relit_psnr", "chamfer")


@dataclass(frozen=True)
class Arm:
    name: str
    terms: str
    """--capture-terms of the run."""


def arms() -> list[Arm]:
    out = [Arm("all terms", "all"), Arm("none", "none")]
    out += [Arm(f"all but {t}", ",".join(n for n in TERM_NAMES if n != t)) for t in TERM_NAMES]
    return out


def run_arm(arm: Arm, scene: Path, gt: Path, budget: int) -> dict:
    run_dir = WORK / "runs" / f"terms_{scene.name}_{budget}_{arm.terms.replace(',', '-')}"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    train = [sys.executable, "-m", "srvol", "train", str(scene), "--out", str(run_dir), "--time-budget", str(budget),
             "--capture-terms", arm.terms, "--force", "--quiet"]
    ev = [sys.executable, "-m", "srvol", "eval", str(run_dir), "--gt", str(gt), "--json", str(run_dir / "metrics_gt.json")]
    for cmd in (train, ev):
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO)
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-3000:]}")
    m = json.loads((run_dir / "metrics_gt.json").read_text())
    summary = json.loads((run_dir / "train_summary.json").read_text())
    row = {"arm": arm.name, "capture_terms": arm.terms, **{k: round(m[k], 4) for k in KEYS if k in m},
           "iterations": summary.get("iterations"), "command": " ".join(["srvol", *train[3:-1]])}
    terms_file = run_dir / "capture_terms.json"
    if terms_file.is_file():
        t = json.loads(terms_file.read_text())
        row["flash_offset_learned"] = t["flash_offset_camera_frame"]
        row["ambient_learned"] = t["ambient_rgb"]
    print(row, flush=True)
    return row


def write_table(rows: list[dict], scene: str, budget: int, parallel: int) -> None:
    cols = ["arm", "capture_terms", *KEYS, "iterations"]
    lines = [f"# What each real-capture term buys: {scene} capture, {budget} s per run", "",
             "Each run trains on the imported capture (`srvol import`) with the terms named, then `srvol eval RUN "
             "--gt GT` scores it in the GT frame after one per-channel gain. Terms: exposure (a gain per photo), "
             "flash (the flash's offset from the lens, learned), vignetting (per camera), ambient, pose (per-photo "
             f"pose refinement). {parallel} runs at a time, 1 thread each.", "",
             "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in cols) + " |" for r in rows]
    base = next((r for r in rows if r["capture_terms"] == "all"), None)
    if base is not None:
        lines += ["", "Change when a term is off (all terms - run without it; positive = the term helps):", ""]
        lines += ["| term | HR PSNR dB | normal MAE deg (negative = helps) | relit PSNR dB |", "|---|---|---|---|"]
        for r in rows:
            if r["arm"].startswith("all but "):
                lines.append(f"| {r['arm'][8:]} | {base['psnr_hr'] - r['psnr_hr']:+.2f} | "
                             f"{base['normal_mae_deg'] - r['normal_mae_deg']:+.2f} | "
                             f"{base.get('relit_psnr', 0) - r.get('relit_psnr', 0):+.2f} |")
    lines += ["", "Commands (from the repository root):", ""] + [f"- `{r['command']}`" for r in rows]
    lines += ["", f"Reproduce: `python -m bench.bench_capture_terms --scene {scene} --budget {budget}` "
                  "(after `python -m bench.bench_import --scenes " + scene + "`)."]
    write_result(RESULTS / "capture_terms_table.md", "\n".join(lines) + "\n")
    write_result(RESULTS / "capture_terms_table.json", json.dumps(rows, indent=1) + "\n")


def merged(rows: list[dict]) -> list[dict]:
    """``rows`` with the committed rows of the arms not run this time (``--arms`` reruns its own), in arm order."""
    path = RESULTS / "capture_terms_table.json"
    old = json.loads(path.read_text()) if path.is_file() else []
    by_terms = {r["capture_terms"]: r for r in old}
    by_terms.update({r["capture_terms"]: r for r in rows})
    return [by_terms[a.terms] for a in arms() if a.terms in by_terms]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.bench_capture_terms")
    p.add_argument("--scene", default="bunny", help="the capture bench_import made (default bunny)")
    p.add_argument("--budget", type=int, default=300, help="training seconds per run (default 300)")
    p.add_argument("--parallel", type=int, default=2, help="runs at a time, 1 thread each (default 2)")
    p.add_argument("--arms", help="comma list of --capture-terms values to run (default: all, none, each off)")
    args = p.parse_args(argv)
    scene, gt = WORK / f"scene_{args.scene}", WORK / f"capture_{args.scene}" / "gt"
    if not (scene / "scene.json").is_file() or not gt.is_dir():
        raise SystemExit(f"{scene} or {gt} missing: run `python -m bench.bench_import --scenes {args.scene}` first")
    todo = arms() if not args.arms else [a for a in arms() if a.terms in args.arms.split(";")]
    with ThreadPoolExecutor(max_workers=max(1, args.parallel)) as pool:
        rows = list(pool.map(lambda a: run_arm(a, scene, gt, args.budget), todo))
    write_table(merged(rows), args.scene, args.budget, args.parallel)
    print(f"wrote {RESULTS / 'capture_terms_table.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
