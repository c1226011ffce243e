"""Benchmark of ``srvol view``'s render panel on the asset path: latency of a light move at 640x480.

Run as ``python -m bench.bench_view`` (``OMP_NUM_THREADS=2``). It exports the default scene's exact
fields the way a user would (``srvol export --builtin bumpy --format usd,glb``, auto sizing), starts
the viewer's server on a free local port (no browser: the panel renders the initial viewer camera),
and moves the light 20 times round the object (through viser's Python API, as a drag does). The viewer
camera is ``relight``'s default camera (the rig's view, the object filling the frame's height), not
the viewer's wider starting view, so that most pixels are object pixels. For each move it records

* move -> panel: seconds from setting the gizmo's position to the panel's new image (what a user
  waits; includes up to one 0.05 s tick of the render thread);
* render: seconds of the relighter call alone (``render_scene``: embree rays, the BRDF, shadow rays).

Median, 90th percentile and maximum; the issue's target is <= 1 s at 640x480. Writes
bench/results/view_table.md and view_table.json.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bench.paths import write_result

RESULTS = Path(__file__).resolve().parent / "results"
MOVES = 20
TARGET_SECONDS = 1.0
SIZE = (640, 480)


@dataclass(frozen=True)
class LatencyRow:
    what: str
    median: float
    p90: float
    max: float
    runs: int


def light_path(n: int) -> list[tuple[float, float, float]]:
    """``n`` light positions on a circle about +z, 2 units out and 1 up: every side of the object in turn."""
    return [(2.0 * math.cos(2 * math.pi * k / n), 2.0 * math.sin(2 * math.pi * k / n), 1.0) for k in range(n)]


def row(what: str, seconds: list[float]) -> LatencyRow:
    s = np.asarray(seconds)
    return LatencyRow(what, float(np.median(s)), float(np.percentile(s, 90)), float(s.max()), len(s))


def measure(asset: Path) -> tuple[list[LatencyRow], int]:
    from srvol.export.asset import load_asset
    from srvol.relight.view import ViewOptions, Viewer
    from srvol.relight.sources import default_camera
    from srvol.relight.view_state import camera_from_pose, pose_from_camera

    faces = len(load_asset(asset).mesh.faces)
    with tempfile.TemporaryDirectory(prefix="bench_view_out.") as out:
        import socket

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        viewer = Viewer(asset, ViewOptions(port=port, out=Path(out)))
        try:
            viewer.default_pose = pose_from_camera(default_camera(*SIZE))  # no browser: the panel's camera
            viewer.wait_for_render()
            coverage = float(viewer.render(viewer.state(), SIZE).mask.mean())
            moves, renders = [], []
            for pos in light_path(MOVES):
                n = viewer.renders
                t0 = time.perf_counter()
                viewer.light_handle.position = pos
                viewer.wait_for_render(n)
                moves.append(time.perf_counter() - t0)
                state = viewer.last_state
                assert camera_from_pose(state.pose, *SIZE).width == SIZE[0]
                t0 = time.perf_counter()
                viewer.render(state, SIZE)
                renders.append(time.perf_counter() - t0)
        finally:
            viewer.stop()
    what = f"asset path ({faces} faces, object on {coverage:.0%} of the pixels), 640x480 + shadows"
    return [row(f"light move -> panel updated, {what}", moves), row(f"render_scene alone, {what}", renders)], faces


def table(rows: list[LatencyRow], commands: list[str]) -> str:
    lines = ["# `srvol view` render panel latency", "",
             f"Asset path (embree + srvol's BRDF + shadow rays), {SIZE[0]}x{SIZE[1]}, {MOVES} light moves round the "
             f"default scene's exported asset; {os.environ.get('OMP_NUM_THREADS', '?')} CPU threads. "
             f"Target <= {TARGET_SECONDS:g} s.", "",
             "| what | median s | p90 s | max s | runs | within target (median) |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.what} | {r.median:.3f} | {r.p90:.3f} | {r.max:.3f} | {r.runs} | "
                     f"{'yes' if r.median <= TARGET_SECONDS else 'NO'} |")
    lines += ["", "Commands:", "", *[f"    {c}" for c in commands], ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from srvol.cli_parser import OneLineParser

    OneLineParser(description=__doc__.splitlines()[0]).parse_args(argv)  # --help; no options
    with tempfile.TemporaryDirectory(prefix="bench_view.") as work:
        asset = Path(work) / "asset"
        export = [sys.executable, "-m", "srvol", "export", "--builtin", "bumpy", "--format", "usd,glb",
                  "--out", str(asset)]
        subprocess.run(export, check=True, stdout=subprocess.DEVNULL)
        rows, _ = measure(asset)
        commands = ["srvol " + " ".join(export[3:]), "python -m bench.bench_view"]
        RESULTS.mkdir(parents=True, exist_ok=True)
        write_result(RESULTS / "view_table.md", table(rows, commands))
        write_result(RESULTS / "view_table.json", json.dumps({"rows": [asdict(r) for r in rows],
                                                              "commands": commands, "size": list(SIZE),
                                                              "target_seconds": TARGET_SECONDS}, indent=1))
    print(table(rows, commands))
    return 0


if __name__ == "__main__":
    sys.exit(main())
