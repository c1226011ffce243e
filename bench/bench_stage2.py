"""Stage-2 sampler study: continue a finished run's stage 2 (geometry frozen, BRDF refined) for a
few more seconds with each PSF sampler and each count of samples per ray, and score HR PSNR on
held-out views. It isolates what the samplers do for the BRDF from what they do for the geometry
(stage 1), and shows how much noSR gains from the same extra time.

    python -m bench.bench_stage2 [--seconds 90] [--runs bumpy_auto_gaussian_600s,bumpy_auto_none_600s]

Reads the runs that `bench.bench_train` leaves in bench/work/runs (it does not change them); writes
bench/results/stage2_table.{md,json}. The learning rate replays the run's stage-2 part of its schedule;
Adam starts afresh.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.paths import write_result
from srvol.cli_parser import OneLineParser

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "results"
WORK = ROOT / "work"


def ray_samples_label(s) -> str:
    return f"{s.n_coarse} + {s.gradient_samples}"


def continue_stage2(run: Path, sampler: str | None, ray_samples, seconds: float, views: int,
                    seed: int = 1) -> dict:
    """HR PSNR on the first ``views`` test views after ``seconds`` more of stage 2 with the PSF
    ``sampler`` and ``ray_samples`` (a SamplerConfig; None: stage 1's) -- sampler None: score the
    run as it is."""
    import torch

    from srvol import metrics
    from srvol.checkpoint import load_model
    from srvol.config import rays_per_step, read_run_config
    from srvol.data import load_scene
    from srvol.evaluate import occupancy_of, render_view
    from srvol.losses import compute_loss
    from srvol.pixels import PixelBank
    from srvol.psf import PsfSampler, SRMode
    from srvol.train import make_optimizers, set_learning_rate, take_step
    from srvol.types import PointLight

    config = read_run_config(run)
    cfg = config.train
    scene = load_scene(config.scene.path)
    fields, info = load_model(run)
    intensity = torch.tensor(info.light_intensity, dtype=torch.float32)
    steps = 0
    eval_sampler = cfg.sampler
    if sampler is not None:
        cfg = replace(cfg, stage2_psf_sampler=sampler, stage2_sampler=ray_samples or cfg.sampler)
        for p in fields.parameters():
            p.requires_grad_(True)
        for p in fields.geometry_parameters():
            p.requires_grad_(False)
        bank = PixelBank(scene, torch.device("cpu"))
        gen = torch.Generator().manual_seed(seed)
        opts = make_optimizers(fields, cfg, 2)
        psf = PsfSampler(SRMode(cfg.sr), scene.info.psf)
        t0 = time.time()
        while time.time() - t0 < seconds:
            set_learning_rate(opts, 1 - cfg.stage2_fraction * (1 - (time.time() - t0) / seconds), cfg, 1.0)
            take_step(opts, compute_loss(fields, bank, cfg, psf, 2, gen, intensity).total)
            steps += 1
    psnr = []
    occupancy = occupancy_of(fields, eval_sampler)  # the geometry is frozen: one grid for the views
    with torch.no_grad():
        for stem in scene.test[:views]:
            cam = scene.hr_camera(stem)
            vr = render_view(fields, cam, PointLight.at_camera(cam, intensity), eval_sampler, occupancy=occupancy)
            psnr.append(metrics.psnr(vr.rgb, scene.gt.image("hr", stem)))
    return {"run": run.name, "sr": cfg.sr, "sampler": sampler or "(as trained)",
            "ray_samples": ray_samples_label(cfg.stage2_sampler or cfg.sampler) if sampler else "",
            "seconds": seconds if sampler else 0.0, "steps": steps, "psnr_hr": float(np.mean(psnr)),
            "views": scene.test[:views], "rays_per_step": rays_per_step(cfg, 2), "psf_samples": cfg.psf_samples}


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", default="bumpy_auto_gaussian_600s,bumpy_auto_none_600s",
                    help="run folders under bench/work/runs (made by bench.bench_train)")
    ap.add_argument("--seconds", type=float, default=90.0, help="extra stage-2 seconds per row (default 90)")
    ap.add_argument("--views", type=int, default=2, help="held-out views scored")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    import torch

    from srvol.config import read_run_config
    from srvol.presets import STAGE2_SAMPLER
    from srvol.render import SamplerConfig

    torch.set_num_threads(2)
    rows = []
    for name in args.runs.split(","):
        run = WORK / "runs" / name
        if not (run / "model.pt").is_file():
            print(f"{run}: no finished run (python -m bench.bench_train makes it)", file=sys.stderr)
            return 2
        sr = read_run_config(run).train.sr
        # (PSF sampler, samples per ray; None = the run's stage-1 count): the PSF samplers, then the counts
        samplers = [(None, None)]
        if sr == "gaussian":
            samplers += [("mc", None), ("antithetic", None), ("lattice", None), ("lattice", STAGE2_SAMPLER),
                         ("lattice", SamplerConfig(n_coarse=12, n_importance=2, n_uniform=0))]
        else:
            samplers += [("mc", None), ("mc", STAGE2_SAMPLER)]
        base = None
        for s, ray_samples in samplers:
            row = continue_stage2(run, s, ray_samples, args.seconds, args.views)
            base = row["psnr_hr"] if base is None else base
            row["gain_db"] = row["psnr_hr"] - base
            rows.append(row)
            print(json.dumps(row), flush=True)
    RESULTS.mkdir(exist_ok=True)
    write_result(RESULTS / "stage2_table.json", json.dumps(rows, indent=1))
    lines = [f"# Stage 2 (geometry frozen): {args.seconds:.0f} more seconds per sampler", "",
             "| run | sr | stage-2 PSF sampler | samples per ray (locating + gradient) | extra s | steps | HR PSNR | "
             "gain (dB) |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['run']} | {r['sr']} | {r['sampler']} | {r['ray_samples']} | {r['seconds']:.0f} | {r['steps']} | "
              f"{r['psnr_hr']:.2f} | {r['gain_db']:+.2f} |" for r in rows]
    per_step = sorted({r["rays_per_step"] for r in rows})
    ns = sorted({r["psf_samples"] for r in rows if r["sr"] == "gaussian"})
    lines += ["", f"HR PSNR over held-out views {', '.join(rows[0]['views'])}; "
              f"{' / '.join(map(str, per_step))} rays per step (the runs' stage-2 batch); the learning rate "
              "replays the stage-2 part of the run's schedule, Adam starts afresh; scored with stage 1's samples "
              "per ray.",
              "", f"gaussian samplers: `mc` {' / '.join(map(str, ns))} i.i.d. rays per LR pixel, `antithetic` "
              "the same count in antithetic pairs {g, -g}, `lattice` "
              "shared lattices with Gaussian weights (auto's stage 2). The L1 of a noisy PSF estimate is at "
              "least the noise's mean magnitude, and the noise is the image's variation within the pixel: "
              "the noisier the estimate, the stronger the loss's pull towards an image flat within each pixel.",
              "", "Samples per ray: with the geometry frozen, fewer samples make a step cheaper (more steps in "
              f"the same seconds); {next(r['ray_samples'] for r in rows if r['sampler'] == 'mc')} is the runs' "
              f"stage-1 count, {ray_samples_label(STAGE2_SAMPLER)} auto's stage 2.",
              "", f"Command: `python -m bench.bench_stage2 --runs {args.runs} --seconds {args.seconds:g} "
              f"--views {args.views}`"]
    write_result(RESULTS / "stage2_table.md", "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
