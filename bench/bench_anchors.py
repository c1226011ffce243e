"""How accurate the stereo anchors are (``srvol train --anchors W``): points found, seconds, and their
distance to the true surface, scene by scene.

    python -m bench.bench_anchors [--scenes glossy,bumpy] [--work bench/work/suite]

For each built-in scene (synthesised as ``bench_suite`` does, and kept under --work) it runs
:func:`srvol.anchors.find_anchors` on the training views, one process, timed, then measures each
point's distance to the GT mesh (``gt/mesh.ply``; the nearest of 1 M points drawn uniformly over its
area, so a distance reads about half their spacing, ~0.001, too high). Printed and written to
``anchors_table.md`` / ``.json``: points, seconds, the distance's median and 90th percentile, the
share beyond the loss's tolerance (``ANCHOR_TOLERANCE``: the surface is pulled only from further)
and beyond the depth maps' agreement (``AGREE``), each next to an LR pixel's footprint on the object
-- what a point's depth can be trusted to.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.paths import write_result
from srvol.capture.compare import point_distances
from srvol.cli_parser import OneLineParser

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_SCENES = ("glossy", "bumpy", "stool", "airplane")
"""The tuning scenes auto's anchors choice was measured on (suite_tuning.md)."""
SURFACE_SAMPLES = 1_000_000
"""Points drawn on the GT mesh to read each anchor's distance from (``point_distances``)."""


def scene_row(name: str, work: Path) -> dict:
    """One scene's anchors: count, seconds and distances (module docstring)."""
    import trimesh

    from bench.bench_suite import ensure_scene
    from srvol.anchors import AGREE, ANCHOR_TOLERANCE, find_anchors
    from srvol.config import hr_pixel_size
    from srvol.data import load_scene

    scene_dir = ensure_scene(name, work, "")
    scene = load_scene(scene_dir)
    t0 = time.perf_counter()
    found = find_anchors(scene)
    seconds = time.perf_counter() - t0
    mesh = trimesh.load(scene_dir / "gt" / "mesh.ply", force="mesh", process=False)
    d = point_distances(found.points, mesh, SURFACE_SAMPLES)
    lr_px = hr_pixel_size(scene) * scene.info.sr_factor

    def share(x: float) -> float:
        return float((d > x).mean()) if len(d) else float("nan")

    return {"scene": name, "train_views": len(scene.train), "points": len(found), "seconds": round(seconds, 1),
            "median": float(np.median(d)) if len(d) else float("nan"),
            "p90": float(np.percentile(d, 90)) if len(d) else float("nan"),
            "beyond_tolerance": share(ANCHOR_TOLERANCE), "beyond_agree": share(AGREE),
            "tolerance": ANCHOR_TOLERANCE, "agree": AGREE, "lr_px": lr_px}


def table(rows: list[dict], command: str) -> str:
    tol, agree = rows[0]["tolerance"], rows[0]["agree"]
    lines = ["# Stereo anchors: points and their distance to the true surface", "",
             "Per scene: `find_anchors` on the training views (one process, timed; the time counts in a run's budget "
             "when `--anchors` is on), then each point's distance to the GT mesh (the nearest of 1 M points drawn "
             f"uniformly over its area: ~0.001 too high). The loss pulls the surface from beyond {tol} units (ANCHOR_TOLERANCE); depth maps "
             f"agree within {agree} (AGREE). Distances are in scene units, next to an LR pixel's footprint.", "",
             f"| scene | train views | points | seconds | median | p90 | share > {tol} | share > {agree} | LR pixel |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['train_views']} | {r['points']} | {r['seconds']:.1f} | {r['median']:.4f} | "
                     f"{r['p90']:.4f} | {r['beyond_tolerance']:.1%} | {r['beyond_agree']:.1%} | {r['lr_px']:.4f} |")
    lines += ["", f"Reproduce: `{' '.join(['python -m bench.bench_anchors', command]).strip()}`", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from bench.bench_suite import WORK

    p = OneLineParser(description=__doc__.split("\n\n")[0], prog="python -m bench.bench_anchors")
    p.add_argument("--scenes", default=",".join(DEFAULT_SCENES),
                   help=f"comma list of built-in scenes (default {','.join(DEFAULT_SCENES)})")
    p.add_argument("--work", type=Path, default=WORK / "suite", help="scene cache (default bench/work/suite, "
                                                                    "shared with bench_suite)")
    p.add_argument("--results", type=Path, default=RESULTS, help="where the table goes (default bench/results)")
    args = p.parse_args(argv)
    from srvol.synth.scenes import SCENES

    names = [s for s in args.scenes.split(",") if s]
    unknown = [s for s in names if s not in SCENES]
    if unknown or not names:
        p.error(f"unknown scene: {', '.join(unknown) or '(none given)'} (scenes: {', '.join(SCENES)})")
    rows = []
    for name in names:
        rows.append(scene_row(name, args.work))
        print(json.dumps(rows[-1]), flush=True)
    text = table(rows, " ".join(sys.argv[1:] if argv is None else argv))
    print(text)
    write_result(args.results / "anchors_table.md", text)
    write_result(args.results / "anchors_table.json", json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
