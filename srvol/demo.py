"""``make demo``: the whole pipeline on the bundled default scene, each step a printed command.

synthesise the default scene -> ``auto`` training -> eval on held-out views -> export USD + GLB ->
relight under three moved lights -> one HTML report. Everything lands in ``--out``.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

from srvol.cli import main as srvol
from srvol.cli_parser import OneLineParser

LIGHTS = ("1.6,-1.2,1.4", "-1.8,0.4,0.9", "0.3,1.9,-0.8")


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

    views = load_scene(scene).test
    step("eval", str(run), "--views", ",".join(views[:eval_views]))
    step("export", str(run), "--format", "usd,glb", "--out", str(asset), "--force")
    for k, pos in enumerate(LIGHTS):
        step("relight", str(run), "--light-pos", pos, "--view", views[0], "--out", str(relit / f"light{k}.png"),
             "--force")
    (out / "commands.txt").write_text("\n".join(commands) + "\n")
    step("report", str(run), "--out", str(out / "report.html"), "--include", str(relit),
         "--include", str(scene), "--commands", str(out / "commands.txt"))
    print(f"\ndemo done: open {out / 'report.html'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("demo_out"))
    ap.add_argument("--budget", type=float, default=360.0, help="training seconds (both stages; default 360)")
    ap.add_argument("--eval-views", type=int, default=2)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return run_demo(args.out, args.budget, args.eval_views)


if __name__ == "__main__":
    sys.exit(main())
