"""What the compiled field queries buy: training steps per second in each stage and an evaluation
render, three ways side by side on one scene --

* ``autograd``: the SDF's normal from autograd (a loss on it: double backward), eager -- as before;
* ``written-out``: the normal by forward-mode written out (:meth:`srvol.fields.GridSDF.value_and_gradient`), eager;
* ``compiled``: the same through ``torch.compile`` (:mod:`srvol.compiled`), after its first calls.

and what compiling costs: the seconds before the first steps run, with an empty compiler cache
(a machine's first run) and with the cache the first filled (every later run).

    python -m bench.bench_compile [--scene SCENE] [--steps 40]     (srvol bench compile)

Each arm runs in its own process (one thread; the compiler cache is per process and per folder).
Writes bench/results/compile_table.{md,json}.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.paths import write_result
from srvol.cli_parser import OneLineParser

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "results"
ARMS = ("autograd", "written-out", "compiled")


def measure_arm(scene_dir: Path, arm: str, steps: int) -> dict:
    """ms per step of each stage (after warm-up steps), seconds of the warm-up (what compiling
    costs) and ms per 10k-ray evaluation chunk, for one arm, in this process."""
    import torch

    from srvol.checkpoint import freeze_geometry
    from srvol.data import load_scene
    from srvol.evaluate import render_view
    from srvol.fields import GridSDF, SceneFields
    from srvol.losses import compute_loss
    from srvol.pixels import PixelBank
    from srvol.presets import auto_config
    from srvol.psf import PsfSampler, SRMode
    from srvol.train import make_optimizers, take_step
    from srvol.types import PointLight

    torch.set_num_threads(1)
    GridSDF.explicit_gradient = {"autograd": False, "written-out": True}.get(arm)  # compiled: the default
    scene = load_scene(scene_dir)
    cfg = auto_config(scene, "gaussian", 600)
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    fields = SceneFields(cfg.fields, learn_intensity=False)
    if arm == "compiled":
        fields.compile_queries()
    intensity = torch.tensor(scene.info.light_intensity, dtype=torch.float32)
    bank = PixelBank(scene, torch.device("cpu"))
    psf = PsfSampler(SRMode(cfg.sr), scene.info.psf)
    out = {"arm": arm, "fields": cfg.fields.parameter_summary()}
    for stage in (1, 2):
        if stage == 2:
            freeze_geometry(fields, None)
        opts = make_optimizers(fields, cfg, stage)

        def step():
            take_step(opts, compute_loss(fields, bank, cfg, psf, stage, gen, intensity, 0.5).total)

        t0 = time.perf_counter()
        for _ in range(3):
            step()
        out[f"stage{stage}_warmup_s"] = round(time.perf_counter() - t0, 2)
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        out[f"stage{stage}_ms"] = round((time.perf_counter() - t0) / steps * 1000, 1)
    cam = scene.test_views()[0].camera  # the LR camera: the ratio is the point, not an HR view's minutes
    light = PointLight.at_camera(cam, intensity)
    t0 = time.perf_counter()
    render_view(fields, cam, light, cfg.sampler)
    out["eval_first_s"] = round(time.perf_counter() - t0, 2)
    t0 = time.perf_counter()
    render_view(fields, cam, light, cfg.sampler)
    out["eval_view_s"] = round(time.perf_counter() - t0, 2)
    out["eval_pixels"] = cam.width * cam.height
    return out


def run_arm(scene: Path, arm: str, steps: int, cache: Path) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", TORCHINDUCTOR_CACHE_DIR=str(cache))
    cmd = [sys.executable, "-m", "bench.bench_compile", "--scene", str(scene), "--steps", str(steps), "--arm", arm]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, env=env, cwd=ROOT.parent, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench_compile: the {arm} arm failed: {res.stderr.strip().splitlines()[-1:]}")
    out = json.loads(res.stdout.strip().splitlines()[-1])
    out["process_s"] = round(time.perf_counter() - t0, 1)
    return out


def table(rows: list[dict], scene: Path, steps: int) -> str:
    base = next(r for r in rows if r["arm"] == "autograd")
    lines = [f"# Compiled field queries: steps per second on `{scene.name}` (auto's model: {base['fields']})", "",
             f"One thread, one process per arm, {steps} steps per stage after 3 warm-up steps; evaluation: one "
             f"{base['eval_pixels']}-pixel test view, rendered twice (the second timed). Ratios against `autograd` "
             "(the eager path before) come from one run of this bench; absolute times on a shared machine are noisy.",
             "",
             "| arm | stage 1 ms/step | stage 2 ms/step | eval s/view | stage 1 x | stage 2 x | eval x | warm-up s (stage 1 / 2 / eval) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['label']} | {r['stage1_ms']} | {r['stage2_ms']} | {r['eval_view_s']} | "
                     f"{base['stage1_ms'] / r['stage1_ms']:.2f} | {base['stage2_ms'] / r['stage2_ms']:.2f} | "
                     f"{base['eval_view_s'] / r['eval_view_s']:.2f} | "
                     f"{r['stage1_warmup_s']} / {r['stage2_warmup_s']} / {r['eval_first_s'] - r['eval_view_s']:.1f} |")
    lines += ["", "Warm-up: the first 3 steps of each stage (and the first view's extra time), where compiling happens. "
              "`cold cache`: an empty compiler cache, a machine's first compiled run; `warm cache`: the cache that run "
              "left (`TORCHINDUCTOR_CACHE_DIR`, by default under the temporary folder), every later run.",
              "", f"Reproduce: `python -m bench.bench_compile --scene {scene} --steps {steps}`", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = OneLineParser(description=__doc__.split("\n\n")[0], prog="python -m bench.bench_compile")
    p.add_argument("--scene", type=Path, help="scene folder (default: the default scene, bench/work/scene_bumpy, "
                                              "made as bench_train makes it)")
    p.add_argument("--steps", type=int, default=40, help="timed steps per stage (default 40)")
    p.add_argument("--arm", choices=ARMS, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.arm:
        print(json.dumps(measure_arm(args.scene, args.arm, args.steps)))
        return 0
    if args.scene is None:
        from bench.bench_train import ensure_scene

        args.scene = ensure_scene("bumpy")
    elif not (args.scene / "cameras.json").is_file():
        print(f"bench_compile: {args.scene} is not a scene (make one with `srvol synth`)", file=sys.stderr)
        return 2
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_compile.") as tmp:
        cache = Path(tmp) / "inductor"
        for arm, label in (("autograd", "autograd (before)"), ("written-out", "written-out"),
                           ("compiled", "compiled, cold cache"), ("compiled", "compiled, warm cache")):
            r = run_arm(args.scene, arm, args.steps, cache)
            r["label"] = label
            print(json.dumps(r), flush=True)
            rows.append(r)
    text = table(rows, args.scene.resolve(), args.steps)
    print(text)
    write_result(RESULTS / "compile_table.md", text)
    write_result(RESULTS / "compile_table.json", json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
