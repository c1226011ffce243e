"""``srvol train``: argument parsing and the run folder; the loop is srvol.train."""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import torch

from srvol.compiled import COMPILE_MIN_ITERS, COMPILE_MIN_SECONDS, compile_training
from srvol.encodings import SDF_INTERPOLATIONS
from srvol.errors import SrvolError

PRESETS = ("auto", "fast", "paper")
SR_MODES = ("gaussian", "box", "none")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "train", help="learn SDF + BRDF from a scene (SuperRVol)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Learn a neural SDF and BRDF from LR flash photos by volume rendering with the "
                    "camera's Gaussian PSF (super-resolution), then freeze the geometry and refine the BRDF.\n\n"
                    "presets:\n"
                    "  auto   capacity derived from the scene (HR pixel footprint, PSF, --time-budget); "
                    "printed with reasons\n"
                    "  fast   CPU-first: dense SDF grids + hash-grid material, few gradient samples per ray\n"
                    "  paper  the paper's MLPs, 98 samples per ray, 25 PSF rays, its batches and learning "
                    "rates (a GPU recipe)")
    p.add_argument("scene", type=Path, help="scene folder (DESIGN.md section 4)")
    p.add_argument("--out", type=Path, required=True, help="run folder to write")
    p.add_argument("--preset", choices=PRESETS, default="auto", help="model/training recipe (default auto)")
    p.add_argument("--sr", choices=SR_MODES, default="gaussian",
                   help="PSF model: gaussian (SuperRVol), box (Vol-SR, d x d HR grid), none (one ray per pixel)")
    p.add_argument("--psf-samples", type=int,
                   help="--sr gaussian: Monte Carlo rays per LR pixel (the paper's N_s) or the per-pixel ray "
                        "budget of a lattice step (default: by preset; on auto it also turns stage 1's "
                        "pixel-centre rays into N_s PSF rays per pixel)")
    p.add_argument("--psf-sampler", choices=("mc", "antithetic", "lattice", "centre"),
                   help="--sr gaussian: 'mc' = N_s i.i.d. rays per LR pixel drawn from the PSF (paper, fast); "
                        "'antithetic' = the same Gaussian draws in rotated groups {g, -g, Jg, -Jg}, exact for "
                        "linear image variation; 'lattice' = one randomly shifted ray lattice shared by 4x4 LR "
                        "pixels with Gaussian weights; 'centre' = one ray at each LR pixel's centre and N_s times "
                        "the pixels (noSR's estimate, free of its noise; the PSF enters in stage 2) (default: "
                        "auto centre, or antithetic with --psf-samples; fast and paper mc; see README)")
    p.add_argument("--stage2-psf-sampler", choices=("mc", "antithetic", "lattice"),
                   help="--sr gaussian: the sampler of stage 2 (BRDF refined through the PSF); default: auto "
                        "lattice (low-noise Gaussian weights for the BRDF), otherwise the --psf-sampler of stage 1")
    p.add_argument("--batch-scale", type=float, metavar="K",
                   help="multiply the preset's pixels per step (both stages, the mask, eikonal and smoothness "
                        "batches) by K: a GPU has room for many more rays per step than auto's CPU-sized "
                        "batches (bench/results/cuda_table.md)")
    p.add_argument("--geometry-lr-tail", type=float, metavar="F",
                   help="stage 1: the SDF's learning rates fall by a further factor F, 0.001..1, over the second "
                        "half of stage 1, so the surface settles (auto 0.1; fast, paper 1 = off)")
    p.add_argument("--photometric-clip", type=float, metavar="W",
                   help="the photometric L1 takes photo pixels at or past white level W as saturated, as a sensor "
                        "and the HR metric clip them: an estimate there costs only what it falls short of W "
                        "(default 0 = linear values; tuning set: shiny +1.3 dB, glossy -0.7, "
                        "airplane -1.5, so auto leaves it off; bench/results/suite_tuning.md)")
    p.add_argument("--stage2-geometry-lr", type=float, metavar="F",
                   help="stage 2: the SDF goes on learning at F, 0..10, times the rate stage 1 ended with, so the "
                        "surface under each highlight moves with the BRDF (auto 3; fast, paper 0 = frozen)")
    p.add_argument("--stage2-importance", type=float, metavar="S",
                   help="stage 2: draw this share, 0..0.9, of the pixels in proportion to an error map of the "
                        "training views (the flash highlights left to fit), the rest uniformly, each weighted so "
                        "the loss means the same (auto 0.5; fast, paper 0 = uniform, the paper's draw; see README)")
    p.add_argument("--lattice-cell", type=float,
                   help="lattice sampler: spacing of the shared rays in LR pixels, 0.05..1 (default 0.5; "
                        "1 / sr factor puts one ray on each HR pixel)")
    p.add_argument("--lattice-patch", type=int, metavar="P",
                   help="lattice sampler: side in LR pixels, 1..8, of the patch one lattice serves (default 4; "
                        "smaller patches spread a step's rays over more places, at more rays per pixel)")
    p.add_argument("--stage2-fraction", type=float,
                   help="share of the run (time budget or --iters), 0..0.9, spent in stage 2 "
                        "(default: auto 0.3, fast 0.15, paper 0.1)")
    p.add_argument("--psf-warmup", type=float,
                   help="--sr gaussian (mc, antithetic): share of training, 0..0.85, that uses one PSF ray per LR "
                        "pixel and N_s times as many pixels per step before switching to N_s rays per pixel "
                        "(default 0 = off: at 600 s it measured no gain, bench/results/train_table.md)")
    p.add_argument("--beta-anneal", type=float,
                   help="share of the run, 0..0.9, over which an upper bound on VolSDF's beta falls from 0.1 to "
                        "--beta-cap-end (auto: 0.3; fast, paper: 0, beta free as in the paper)")
    p.add_argument("--beta-cap-end", type=float,
                   help="where the --beta-anneal bound ends, in scene units (auto: the HR pixel footprint; "
                        "others 0.002)")
    p.add_argument("--coarse-to-fine", type=float,
                   help="share of the run, 0..0.9, over which the grids' finer levels (material detail, the SDF's "
                        "finer grids) fade in one after another, so that shading explains the shape before texture "
                        "can paint it (default 0 = every level from the start; on the tuning set 0.3 gained on glossy, "
                        "+0.67 dB, and lost on stool, -0.59: suite_tuning.md)")
    p.add_argument("--silhouette-rays", type=float,
                   help="share, 0..1, of the out-of-mask rays drawn from each view's mask bounding box (+2 px): "
                        "where the mask carves gaps between thin parts (auto: 0.5 when the masks show thin parts, "
                        "else 0: anywhere outside the mask)")
    p.add_argument("--refine-samples", type=int,
                   help="no-grad samples added, in both stages and at evaluation, inside the first interval of "
                        "each ray where the surface may lie (d + d' < spacing): parts thinner than the locating "
                        "samples' spacing are found (auto: 8 when the masks show thin parts, else 0)")
    p.add_argument("--capture-terms", metavar="LIST",
                   help="real-capture terms to learn: 'all', 'none' or a comma list of exposure (a gain per "
                        "photo), flash (the flash's offset from the lens), vignetting (per camera), ambient, pose "
                        "(per-photo pose refinement) (default: auto exposure,flash,vignetting for a scene made by "
                        "'srvol import', none otherwise)")
    p.add_argument("--flash-offset", metavar="X,Y,Z",
                   help="the flash's offset from the lens in the camera frame (x right, y down, z forward), in "
                        "the units of the capture's poses (SfM, --colmap, --transforms); given, it is not learned")
    p.add_argument("--normal-smoothness", type=float, metavar="W",
                   help="stage 1: weight of a term that keeps the normal from turning within one SDF grid cell "
                        "(mean |n(x) - n(x + e)|^2 on the rendered surface; 0 = off)")
    p.add_argument("--anchors", type=float, metavar="W",
                   help="stage 1: weight of two terms over surface points found by stereo between neighbouring "
                        "training views: one holds the SDF to the points, one keeps their lines of sight free; "
                        "together they open concavities (a cup's inside, a bowl) that the photometric loss leaves "
                        "closed, fading out by half the run (default 0; 1 on the tuning scene glossy opens its bowl: "
                        "normals 1.5 vs 5.2 deg, but HR PSNR 0.5-3.5 dB lower, see bench/results/suite_tuning.md)")
    p.add_argument("--free-space", type=float, metavar="W",
                   help="stage 1: weight of the line-of-sight term alone: the SDF kept positive in front of each "
                        "stereo point, up to 0.05 before it, never pulling the surface to a point (default 0; 1 "
                        "lowers the lid over a bowl: tuning scene glossy +0.52 dB, normals -0.97 deg, see "
                        "bench/results/suite_tuning.md)")
    p.add_argument("--sdf-interpolation", choices=SDF_INTERPOLATIONS,
                   help="grid presets: how the SDF grids interpolate (default smoothstep). bspline (quadratic) "
                        "draws flat faces flat but costs 3x per SDF query: in 600 s the tuning scene stool (flat "
                        "faces) gained 0.59 dB and 1.5 deg of normals, shiny (smooth, glossy) lost 0.64 dB "
                        "(bench/results/suite_tuning.md)")
    p.add_argument("--capacity", type=float, default=1.0,
                   help="auto preset: scale the scene-derived model size (grids, hash table, head widths) by "
                        "this factor -- for capacity studies (default 1: what the scene needs)")
    p.add_argument("--time-budget", type=float, default=600.0,
                   help="wall-clock seconds for both stages (default 600; ignored with --iters)")
    p.add_argument("--iters", type=int, help="total iterations of both stages instead of a time budget")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="device (default cpu)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--compile", choices=("auto", "on", "off"), default="auto",
                   help="run the fields' queries through torch.compile: the same maths, ~1.4x the steps per second "
                        "on a CPU; compiling takes ~2 min on a machine's first run of a model and ~15 s once cached "
                        "(inside the budget, off the schedule's clock); auto: on for a run of at least "
                        f"{COMPILE_MIN_SECONDS:.0f} s or {COMPILE_MIN_ITERS} iterations (default auto)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--force", action="store_true", help="replace an existing run folder")
    p.add_argument("--checkpoint-every", type=int, help="iterations between checkpoints (default 200)")
    p.add_argument("--snapshots", type=int, default=0,
                   help="save the fields N times evenly over training (RUN/snapshots/, for quality-vs-time charts)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--distributed", action="store_true",
                   help="data-parallel over the processes torchrun starts (`torchrun --standalone --nproc_per_node N "
                        "-m srvol train ... --distributed`): each rank renders its share of every step's rays, gradients "
                        "are summed (gloo on the CPU, nccl on CUDA); rank 0 writes the run; --out must be a "
                        "folder every rank sees")
    p.set_defaults(func=run_train)


def _in_range(value: float, flag: str, most: float, least: float = 0.0, unit: str = "") -> float:
    """A flag's value checked finite and in [least, most] (a share: 0..most); one error line otherwise."""
    if not (math.isfinite(value) and least <= value <= most):
        raise SrvolError(f"{flag} {value}: must be between {least:g} and {most:g}{unit}")
    return value


def _capture_terms(scene, args, default):
    """The capture terms the flags ask for (``default``: the preset's)."""
    from srvol.capture.frame import read_normalization
    from srvol.capture.terms import TERM_NAMES, terms_config

    offset = None
    if args.flash_offset is not None:
        try:
            offset = tuple(float(v) for v in args.flash_offset.split(","))
        except ValueError:
            offset = ()
        if len(offset) != 3 or not all(math.isfinite(v) for v in offset):
            raise SrvolError(f"--flash-offset {args.flash_offset!r}: give three numbers X,Y,Z")
        norm = read_normalization(scene.root)
        offset = tuple(v * (norm.scale if norm is not None else 1.0) for v in offset)  # capture -> scene units
    if args.capture_terms is None:
        if offset is None:
            return default
        return terms_config((default.names() if default is not None else set()) | {"flash"}, offset)
    words = {w.strip() for w in args.capture_terms.split(",") if w.strip()}
    if words == {"none"}:
        if offset is not None:
            raise SrvolError("--flash-offset needs the flash term (--capture-terms none turns it off)")
        return None
    names = set(TERM_NAMES) if words == {"all"} else words
    unknown = sorted(names - set(TERM_NAMES))
    if unknown or not names:
        raise SrvolError(f"--capture-terms {args.capture_terms!r}: 'all', 'none' or a comma list of "
                         f"{', '.join(TERM_NAMES)}")
    if offset is not None and "flash" not in names:
        raise SrvolError("--flash-offset needs the flash term in --capture-terms")
    return terms_config(names, offset)


def build_config(scene, args):
    from srvol.presets import auto_batches, auto_config, fast_config, paper_config, stage1_rays_reason

    _in_range(args.capacity, "--capacity", 8, least=0.1)
    if args.capacity != 1.0 and args.preset != "auto":
        raise SrvolError("--capacity applies to --preset auto only")
    if args.preset == "paper":
        cfg = paper_config(sr=args.sr)
    elif args.preset == "fast":
        cfg = fast_config(sr=args.sr)
    else:
        cfg = auto_config(scene, args.sr, args.time_budget, capacity=args.capacity)
    changes = {"device": args.device, "seed": args.seed, "time_budget": args.time_budget,
               "snapshots": max(0, args.snapshots)}
    if args.iters is not None:
        if args.iters < 1:
            raise SrvolError(f"--iters {args.iters}: must be >= 1")
        changes["iters"] = args.iters
    elif args.preset == "paper":
        changes["iters"] = 0  # the paper's iteration count is a GPU schedule; a budget bounds it here
    if args.psf_samples is not None:
        if args.psf_samples < 1:
            raise SrvolError(f"--psf-samples {args.psf_samples}: must be >= 1")
        changes["psf_samples"] = args.psf_samples
        if args.preset == "auto" and args.sr == "gaussian" and cfg.psf_sampler == "centre":
            changes["psf_sampler"] = "antithetic"  # N PSF rays per pixel asked for stage 1 too
    if args.psf_sampler is not None:
        changes["psf_sampler"] = args.psf_sampler
        # the asked sampler serves both stages unless stage 2's is asked too; "centre" serves stage 1 only
        # (the PSF enters in stage 2: the preset's stage-2 sampler, else mc)
        changes["stage2_psf_sampler"] = (cfg.stage2_psf_sampler or "mc") if args.psf_sampler == "centre" else ""
    if args.stage2_psf_sampler is not None:
        changes["stage2_psf_sampler"] = args.stage2_psf_sampler
    if args.sr == "gaussian" and (args.psf_samples is not None or args.psf_sampler is not None):
        ns = changes.get("psf_samples", cfg.psf_samples)
        centre = changes.get("psf_sampler", cfg.psf_sampler) == "centre"  # one centre ray per pixel, ns x the pixels
        if args.preset == "auto":  # auto keeps its rays per step: its batches follow the final stage-1 sampler
            changes.update(auto_batches(ns, centre_rays=centre)._asdict())
        asked = " ".join(f"--psf-{k} {v}" for k, v in (("samples", args.psf_samples), ("sampler", args.psf_sampler))
                         if v is not None)
        changes["reasons"] = cfg.reasons + (stage1_rays_reason(asked, ns, centre, changes.get("batch_in", cfg.batch_in),
                                                               changes.get("batch_out", cfg.batch_out)),)
    if args.batch_scale is not None:
        _in_range(args.batch_scale, "--batch-scale", 64, least=0.25)
        for key in ("batch_in", "batch_out", "batch_eikonal", "batch_stage2", "batch_smooth",
                    "batch_anchor"):
            changes[key] = max(16, round(changes.get(key, getattr(cfg, key)) * args.batch_scale))
        changes["reasons"] = changes.get("reasons", cfg.reasons) + (
            f"--batch-scale {args.batch_scale:g} (asked): {args.batch_scale:g}x the pixels of every batch per step",)
    if args.geometry_lr_tail is not None:
        changes["geometry_lr_tail"] = _in_range(args.geometry_lr_tail, "--geometry-lr-tail", 1.0, least=0.001)
    if args.stage2_geometry_lr is not None:
        changes["stage2_geometry_lr"] = _in_range(args.stage2_geometry_lr, "--stage2-geometry-lr", 10.0)
    if args.stage2_importance is not None:
        changes["stage2_importance"] = _in_range(args.stage2_importance, "--stage2-importance", 0.9)
    if args.lattice_cell is not None:
        changes["lattice_cell"] = _in_range(args.lattice_cell, "--lattice-cell", 1.0, least=0.05, unit=" LR pixel")
    if args.lattice_patch is not None:
        changes["patch"] = int(_in_range(args.lattice_patch, "--lattice-patch", 8, least=1, unit=" LR pixels"))
    if args.stage2_fraction is not None:
        changes["stage2_fraction"] = _in_range(args.stage2_fraction, "--stage2-fraction", 0.9)
    if args.psf_warmup is not None:
        changes["psf_warmup"] = _in_range(args.psf_warmup, "--psf-warmup", 0.85)
    if args.sr == "none":
        changes["psf_samples"] = 1
    if args.checkpoint_every is not None:
        changes["checkpoint_every"] = max(1, args.checkpoint_every)
    if args.beta_anneal is not None:
        changes["beta_anneal"] = _in_range(args.beta_anneal, "--beta-anneal", 0.9)
    if args.beta_cap_end is not None:
        changes["beta_cap_end"] = _in_range(args.beta_cap_end, "--beta-cap-end", 0.1, least=1e-5)
    if args.photometric_clip is not None:
        changes["photometric_clip"] = _in_range(args.photometric_clip, "--photometric-clip", 1e3)
    if args.coarse_to_fine is not None:
        changes["coarse_to_fine"] = _in_range(args.coarse_to_fine, "--coarse-to-fine", 0.9)
    if args.silhouette_rays is not None:
        changes["silhouette_rays"] = _in_range(args.silhouette_rays, "--silhouette-rays", 1.0)
    if args.refine_samples is not None:
        if not 0 <= args.refine_samples <= 64:
            raise SrvolError(f"--refine-samples {args.refine_samples}: must be 0..64")
        changes["sampler"] = replace(cfg.sampler, n_refine=args.refine_samples)
        if cfg.stage2_sampler is not None:
            changes["stage2_sampler"] = replace(cfg.stage2_sampler, n_refine=args.refine_samples)
    if args.normal_smoothness is not None:
        changes["lambda_smooth"] = _in_range(args.normal_smoothness, "--normal-smoothness", 10)
    if args.anchors is not None:
        changes["lambda_anchor"] = changes["lambda_free_space"] = _in_range(args.anchors, "--anchors", 100)
    if args.free_space is not None:
        changes["lambda_free_space"] = _in_range(args.free_space, "--free-space", 100)
    if args.sdf_interpolation is not None:
        if cfg.fields.kind != "grid":
            raise SrvolError(f"--sdf-interpolation applies to the grid presets (fast, auto), not {cfg.preset}")
        changes["fields"] = replace(cfg.fields, sdf_interpolation=args.sdf_interpolation)
    changes["compile"] = compile_training(args.compile, changes.get("iters", cfg.iters), args.time_budget)
    capture = _capture_terms(scene, args, cfg.capture)
    if capture != cfg.capture:
        changes["capture"] = capture
        changes["reasons"] = changes.get("reasons", cfg.reasons) + (
            f"real-capture terms (asked): {capture.describe() if capture else 'none'}",)
    if args.time_budget <= 0 and args.iters is None:
        raise SrvolError("--time-budget must be > 0 (or give --iters)")
    return replace(cfg, **changes)


def run_train(args) -> int:
    if not args.distributed:
        return _run_train(args)
    from srvol import distributed

    shard = distributed.start(args.device)
    try:
        return _run_train(args, shard)
    finally:
        distributed.stop()


def _prepare_run(args, scene):
    """The run's config: read back (--resume) or built and written into a fresh --out."""
    from srvol.config import RunConfig, SceneRecord, read_run_config, write_run_config

    run = args.out
    if args.resume:
        return read_run_config(run).train
    if run.exists() and any(run.iterdir()) and not args.force:
        raise SrvolError(f"{run}: already exists (use --resume to continue or --force to replace it)")
    if run.exists() and args.force:
        import shutil

        shutil.rmtree(run)
    cfg = build_config(scene, args)
    run.mkdir(parents=True, exist_ok=True)
    write_run_config(run, RunConfig(train=cfg, scene=SceneRecord.of_scene(scene, args.scene)))
    return cfg


def _run_train(args, shard=None) -> int:
    from srvol.config import describe_psf_rays, describe_ray_samples, read_run_config
    from srvol.data import load_scene
    from srvol.distributed import SINGLE
    from srvol.train import train

    shard = shard or SINGLE
    t0 = time.time()
    if args.device == "cuda" and not torch.cuda.is_available():
        raise SrvolError("--device cuda: no CUDA device available")
    if args.distributed and args.normal_smoothness:
        raise SrvolError("--normal-smoothness does not run with --distributed (its points differ per rank)")
    scene = load_scene(args.scene)
    run = args.out
    if shard.is_main:
        try:
            cfg = _prepare_run(args, scene)
        except SrvolError:
            shard.all_true(False)  # the other ranks stop too
            raise
        shard.all_true(True)
    else:
        if not shard.all_true(True):
            return 2  # rank 0 said why
        cfg = read_run_config(run).train
    from srvol.fields import SceneFields

    n_params = sum(p.numel() for p in SceneFields(cfg.fields, learn_intensity=False).parameters())
    say = print if shard.is_main else (lambda *_: None)
    say(f"preset {cfg.preset}, sr {cfg.sr}, {describe_psf_rays(cfg, scene.info.psf)}, "
        f"{describe_ray_samples(cfg)}, "
        f"{n_params / 1e6:.2f} M parameters" + (", compiled queries" if cfg.compile else "")
        + (f", {shard.world} data-parallel ranks" if shard.world > 1 else ""))
    say(f"  {cfg.fields.parameter_summary()}")
    for r in cfg.reasons:
        say(f"  - {r}")
    if cfg.iters == 0:
        # The budget bounds the whole command: setup so far and the final save come out of it.
        cfg = replace(cfg, time_budget=max(1.0, cfg.time_budget - (time.time() - t0) - 3.0))
    summary = train(scene, cfg, run, resume=args.resume, progress=not args.quiet, shard=shard)
    if not shard.is_main:
        return 0
    from srvol.atomic import atomic_write_text

    atomic_write_text(run / "train_summary.json", json.dumps(
        {"iterations": summary.iterations, "train_seconds": round(summary.train_seconds, 2),
         "command_seconds": round(time.time() - t0, 2), "final_train_psnr": summary.final_psnr,
         "rollbacks": summary.rollbacks, "parameters": n_params, "peak_rss_gib": _peak_rss_gib(),
         **({"stage2_samples": summary.stage2_samples} if summary.stage2_samples else {}),
         **({"peak_gpu_gib": round(torch.cuda.max_memory_allocated() / 2 ** 30, 3)} if args.device == "cuda" else {}),
         **({"ranks": shard.world} if shard.world > 1 else {})}, indent=1))
    print(f"trained {summary.iterations} iterations in {summary.train_seconds:.0f} s "
          f"(train PSNR {summary.final_psnr:.2f} dB) -> {run}")
    return 0


def _peak_rss_gib() -> float | None:
    """Peak resident memory of this process so far (GiB); None where the OS does not say."""
    try:
        import resource
    except ImportError:  # not on Windows
        return None
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20, 3)
