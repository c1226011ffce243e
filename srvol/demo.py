"""``make demo``: the whole pipeline on the bundled default scene, each step a printed command.

synthesise the default scene -> ``auto`` training -> eval on held-out views -> export USD + GLB ->
relight under three moved lights -> one HTML report -> the ``srvol view`` command to look at the
asset live. Everything lands in ``--out``.
"""
from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from srvol.cli import main as srvol
from srvol.cli_parser import OneLineParser

PREVIEW_LIGHTS = (("key", 35.0, 25.0), ("fill", -40.0, 10.0), ("top", -10.0, 55.0))
"""The preview's lights, placed relative to the preview camera: (name, degrees to the camera's right
(negative: left), degrees above it). All sit on the camera's side of the object, so each lights the
side the camera sees; a light from behind would show a black silhouette."""
LIGHT_DISTANCE = 2.2


def lights_facing(camera_center, distance: float = LIGHT_DISTANCE,
                  lights=PREVIEW_LIGHTS) -> list[tuple[str, tuple[float, float, float]]]:
    """Light positions round the origin, turned from the camera's direction by each light's angles
    (right about the world's +z, then up towards +z), at ``distance`` from the origin."""
    d = np.asarray(camera_center, np.float64)
    d = d / np.linalg.norm(d)
    right = np.cross([0.0, 0.0, 1.0], d)  # the image's right, seen from the camera looking at the origin
    right = right / max(np.linalg.norm(right), 1e-9)
    up = np.cross(d, right)
    out = []
    for name, side_deg, up_deg in lights:
        a, b = math.radians(side_deg), math.radians(up_deg)
        horizontal = math.cos(a) * d + math.sin(a) * right
        direction = math.cos(b) * horizontal + math.sin(b) * up
        out.append((name, tuple(float(c) for c in distance * direction / np.linalg.norm(direction))))
    return out


def run_demo(out: Path, budget: float, eval_views: int) -> int:
    out.mkdir(parents=True, exist_ok=True)
    scene, run, asset, relit = out / "scene", out / "run", out / "asset", out / "relit"
    relit.mkdir(exist_ok=True)
    commands: list[str] = []

    def step(*args: str) -> None:
        cmd = "srvol " + " ".join(shlex.quote(a) for a in args)
        commands.append(cmd)
        print(f"\n$ {cmd}", flush=True)
        t = time.time()
        rc = srvol(list(args))
        if rc != 0:
            raise SystemExit(f"demo: step failed ({rc}): {cmd}")
        print(f"  ({time.time() - t:.0f} s)", flush=True)

    if not (scene / "cameras.json").is_file():
        step("synth", "--out", str(scene), "--sheet", "--force")
    step("train", str(scene), "--out", str(run), "--time-budget", str(budget), "--force", "--snapshots", "0")
    from srvol.data import load_scene

    loaded = load_scene(scene, load_images=False)
    views = loaded.test
    step("eval", str(run), "--views", ",".join(views[:eval_views]))
    step("export", str(run), "--format", "usd,glb", "--out", str(asset), "--force")
    center = loaded.hr_camera(views[0]).center.double().numpy()
    for k, (name, pos) in enumerate(lights_facing(center)):
        step("relight", str(asset), "--light-pos", ",".join(f"{c:.3f}" for c in pos), "--view", views[0],
             "--scene", str(scene), "--out", str(relit / f"light{k}_{name}.png"), "--force")
    (out / "commands.txt").write_text("\n".join(commands) + "\n")
    step("report", str(run), "--out", str(out / "report.html"), "--asset", str(asset), "--previews", str(relit),
         "--include", str(scene), "--commands", str(out / "commands.txt"))
    print(f"\ndemo done: open {out / 'report.html'}")
    print("look at the asset live in the browser (drag the light, edit the material):")
    print(f"  {view_command(asset, scene)}")
    return 0


def run_capture_demo(out: Path, budget: float, photos: int) -> int:
    """``make demo-capture``: what a phone gives (JPEGs, EXIF focal, no poses or masks) -> ``srvol
    import`` -> train -> export -> eval against the capture's ground truth -> report."""
    out.mkdir(parents=True, exist_ok=True)
    capture, scene, run, asset = out / "capture", out / "scene", out / "run", out / "asset"
    commands: list[str] = []

    def step(*args: str) -> None:
        cmd = "srvol " + " ".join(shlex.quote(a) for a in args)
        commands.append(cmd)
        print(f"\n$ {cmd}", flush=True)
        t = time.time()
        rc = srvol(list(args))
        if rc != 0:
            raise SystemExit(f"demo: step failed ({rc}): {cmd}")
        print(f"  ({time.time() - t:.0f} s)", flush=True)

    if not (capture / "photos").is_dir():
        step("synth", "bunny", "--capture", "--photos", str(photos), "--out", str(capture), "--force")
    step("import", str(capture / "photos"), "--out", str(scene), "--force")
    step("train", str(scene), "--out", str(run), "--time-budget", str(budget), "--force")
    step("export", str(run), "--format", "usd,glb", "--out", str(asset), "--force")
    step("export", str(run), "--format", "usd", "--frame", "capture", "--out", str(out / "asset_capture_frame"),
         "--force")
    step("eval", str(run), "--gt", str(capture / "gt"))
    (out / "commands.txt").write_text("\n".join(commands) + "\n")
    step("report", str(run), "--out", str(out / "report.html"), "--asset", str(asset), "--commands",
         str(out / "commands.txt"))
    print(f"\ncapture demo done: open {out / 'report.html'}")
    print(f"  {view_command(asset, scene)}")
    return 0


def view_command(asset: Path, scene: Path) -> str:
    return shlex.join(["srvol", "view", str(asset), "--scene", str(scene)])


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("demo_out"))
    ap.add_argument("--budget", type=float, default=360.0, help="training seconds (both stages; default 360)")
    ap.add_argument("--eval-views", type=int, default=2)
    ap.add_argument("--capture", action="store_true",
                    help="the path from photos instead: a synthetic phone capture (JPEGs, no poses or masks), "
                         "srvol import, train, export, eval against its ground truth, report")
    ap.add_argument("--photos", type=int, default=64, help="with --capture: photos in the capture (default 64)")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.capture:
        return run_capture_demo(args.out, args.budget, args.photos)
    return run_demo(args.out, args.budget, args.eval_views)


if __name__ == "__main__":
    sys.exit(main())
