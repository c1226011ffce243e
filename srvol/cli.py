"""``srvol`` command line: the composition root (the only module importing core, export and relight).

User mistakes end with one line ``srvol: error: ...`` and exit status 2;
nothing half-written is left behind.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from srvol.cli_parser import EXIT_USER_ERROR, OneLineParser, image_size
from srvol.errors import SrvolError


# ----------------------------------------------------------------------------- synth / inspect

def _add_synth(sub) -> None:
    from srvol.synth.scenes import DEFAULT_SCENE, SCENES

    d = SCENES[DEFAULT_SCENE].synth
    p = sub.add_parser("synth", help="write a built-in synthetic scene with ground truth",
                       description="Render a built-in scene by the paper's protocol: HR render with a "
                                   "co-located point light, Gaussian PSF blur, decimation to LR; plus GT "
                                   "(HR test views, normals, albedo, moved-light renders, mesh). Each scene has "
                                   "its own LR size, PSF, views and framing (--list); a flag overrides one of them.")
    p.add_argument("name", nargs="?", default=DEFAULT_SCENE, help=f"scene name ({', '.join(SCENES)}; "
                                                                  f"default {DEFAULT_SCENE})")
    p.add_argument("--out", type=Path, help="scene folder to write (required unless --list)")
    p.add_argument("--list", action="store_true",
                   help="list the built-in scenes, their tuning/report set and capture defaults, and exit")
    p.add_argument("--lr", type=image_size, help=f"LR image size WxH (default: the scene's; {DEFAULT_SCENE} "
                                            f"{d.lr[0]}x{d.lr[1]})")
    p.add_argument("--sr", type=int, help=f"super-resolution factor HR/LR (default {d.sr})")
    p.add_argument("--views", type=int, help=f"training views (default: the scene's; {DEFAULT_SCENE} {d.views})")
    p.add_argument("--test-views", type=int, help=f"held-out views (default: the scene's; {DEFAULT_SCENE} "
                                                  f"{d.test_views})")
    p.add_argument("--psf-sigma", type=float,
                   help=f"Gaussian PSF sigma in LR pixels (default: the scene's; {DEFAULT_SCENE} {d.psf_sigma})")
    p.add_argument("--seed", type=int, help="random seed (default 0)")
    p.add_argument("--sheet", action="store_true", help="also write sheet.png (LR | HR GT | normals | albedo | relit)")
    p.add_argument("--capture", action="store_true",
                   help="write what a phone gives instead: OUT/photos/*.jpg (EXIF focal, no poses or masks; "
                        "hand-held path, off-lens flash, auto-exposure, vignetting, noise, ambient light, dim "
                        "backdrop) and the ground truth apart in OUT/gt/ (for `srvol import` and `srvol eval --gt`)")
    p.add_argument("--photos", type=int, help="with --capture: number of photos (default 64)")
    p.add_argument("--photo-size", type=image_size, help="with --capture: photo size WxH (default 320x240)")
    p.add_argument("--force", action="store_true", help="replace an existing --out folder")
    p.set_defaults(func=_run_synth)


def _run_synth(args) -> int:
    from dataclasses import replace

    from srvol.synth.generate import synthesize
    from srvol.synth.scenes import get_scene

    if args.list:
        print(_scene_list())
        return 0
    if args.out is None:
        raise SrvolError("synth needs --out DIR")
    if args.capture:
        return _run_synth_capture(args)
    if args.photos is not None or args.photo_size is not None:
        raise SrvolError("--photos and --photo-size go with --capture")
    given = {"lr": args.lr, "sr": args.sr, "views": args.views, "test_views": args.test_views,
             "psf_sigma": args.psf_sigma, "seed": args.seed}
    opts = replace(get_scene(args.name).synth, **{k: v for k, v in given.items() if v is not None})
    out = synthesize(args.name, args.out, opts, force=args.force)
    if args.sheet:
        from srvol.synth.sheet import scene_sheet

        scene_sheet(out, out / "sheet.png")
    print(f"wrote {out}")
    return 0


def _run_synth_capture(args) -> int:
    from dataclasses import replace

    from srvol.synth.capture import CaptureOptions, synthesize_capture

    given = {"photos": args.photos, "size": args.photo_size, "seed": args.seed}
    opts = replace(CaptureOptions(), **{k: v for k, v in given.items() if v is not None})
    out = synthesize_capture(args.name, args.out, opts, force=args.force)
    print(f"wrote {out / 'photos'} ({opts.photos} photos, {opts.size[0]}x{opts.size[1]}) and its ground truth "
          f"{out / 'gt'}")
    return 0


def _scene_list() -> str:
    """One line per built-in scene: name, set, LR size, PSF sigma, views + test views, framing, description."""
    from srvol.synth.scenes import DEFAULT_SCENE, SCENES, scene_set

    lines = [f"{'name':9s} {'set':7s} {'LR':8s} {'PSF':5s} {'views':6s} {'zoom':5s} {'aim':12s} description"]
    for name, spec in SCENES.items():
        o = spec.synth
        aim = f"{o.aim[0]:+.2f},{o.aim[1]:+.2f}"
        lines.append(f"{name:9s} {scene_set(name) or '-':7s} {o.lr[0]}x{o.lr[1]:<4d} {o.psf_sigma:<5.3g} "
                     f"{o.views}+{o.test_views:<3d} {o.zoom:<5.3g} {aim:12s} {spec.description}"
                     f"{'  [default]' if name == DEFAULT_SCENE else ''}")
    return "\n".join(lines)


def _add_inspect(sub) -> None:
    p = sub.add_parser("inspect", help="validate a scene folder and print a summary",
                       description="Read every camera, image and mask of a scene; report the first problem "
                                   "in one line (exit 2) or print a summary.")
    p.add_argument("scene", type=Path)
    p.set_defaults(func=_run_inspect)


def _run_inspect(args) -> int:
    from srvol.data import load_scene

    scene = load_scene(args.scene)
    v0 = next(iter(scene.views.values()))
    sizes = sorted({(v.camera.width, v.camera.height) for v in scene.views.values()})
    light = scene.info.light_intensity
    print(f"scene      {scene.root}")
    print(f"views      {len(scene.views)} ({len(scene.train)} train, {len(scene.test)} test)")
    print(f"LR size    {', '.join(f'{w}x{h}' for w, h in sizes)}; HR x{scene.info.sr_factor}")
    print(f"colour     {scene.info.color_space or 'by file type'}; masks: {'yes' if scene.has_masks else 'no'}")
    print(f"light      co-located, intensity {list(light) if light else 'unknown (learned)'}")
    print(f"PSF        gaussian, sigma {scene.info.psf_sigma_lr_px} LR px")
    print(f"GT         {', '.join(scene.gt.parts()) or 'none'}")
    print(f"pixel range {min(float(v.image.min()) for v in scene.views.values()):.3g} .. "
          f"{max(float(v.image.max()) for v in scene.views.values()):.3g} (linear); first view {v0.name}")
    print("ok")
    return 0


# ----------------------------------------------------------------------------- eval

def _add_eval(sub) -> None:
    p = sub.add_parser("eval", help="score a trained run on the scene's held-out test views",
                       description="Render the held-out test views at HR and compute psnr_hr, ssim_hr, psnr_lr, "
                                   "normal_mae_deg, albedo_psnr, relit_psnr/ssim (with shadows, via the "
                                   "relighter), chamfer; write eval_sheet.png (GT | ours | |error| | normals).")
    p.add_argument("run", type=Path, help="training run folder")
    p.add_argument("--scene", type=Path, help="scene folder (default: the one the run was trained on)")
    p.add_argument("--json", type=Path, help="write the metrics here (default RUN/metrics.json)")
    p.add_argument("--views", help="comma-separated test view names (default: all test views)")
    p.add_argument("--no-relit", action="store_true", help="skip the moved-light metrics")
    p.add_argument("--compile", choices=("auto", "on", "off"), default="auto",
                   help="render through torch.compile'd field queries (the same maths, ~1.7x as fast after ~20 s "
                        "of compiling on first use, ~2 s once cached); auto: on when the test views hold >= "
                        f"{EVAL_COMPILE_MIN_PIXELS:,} HR pixels (default auto)")
    p.add_argument("--gt", type=Path,
                   help="the GT folder of a synthetic capture (srvol synth --capture): align the imported scene "
                        "to it by the photos' camera centres, report rotation errors, score the GT's held-out "
                        "views, normals and moved lights in the GT frame after one per-channel gain, and the "
                        "Chamfer distance of the level set")
    p.set_defaults(func=_run_eval)


EVAL_COMPILE_MIN_PIXELS = 1_000_000
"""Below this an evaluation takes about as long as compiling its queries the first time."""


def _test_hr_pixels(scene) -> int:
    """HR pixels of the scene's test views (what an evaluation renders, moved lights aside)."""
    return sum(cam.width * cam.height for cam in (scene.hr_camera(s) for s in scene.test))


def _run_eval(args) -> int:
    import json

    from srvol.checkpoint import load_model
    from srvol.config import read_run_config
    from srvol.data import load_scene
    from srvol.evaluate import evaluate_run, write_metrics

    fields, info = load_model(args.run)
    scene_dir = args.scene or info.scene_dir
    if scene_dir is None:
        raise SrvolError("the run does not record its scene: pass --scene")
    scene = load_scene(scene_dir)
    cfg = read_run_config(args.run).train
    if args.compile == "on" or (args.compile == "auto" and _test_hr_pixels(scene) >= EVAL_COMPILE_MIN_PIXELS):
        fields.compile_queries()
    if args.gt is not None:
        return _run_eval_capture(args, fields, info, scene, cfg)
    relit_fn = None
    if not args.no_relit:
        relit_fn = _neural_relit_fn(fields)
    summary = evaluate_run(fields, scene, cfg.sampler, info.light_intensity, args.run,
                           views=args.views.split(",") if args.views else None, relit_fn=relit_fn)
    ts = args.run / "train_summary.json"
    if ts.is_file():
        t = json.loads(ts.read_text())
        summary["train_seconds"] = t["train_seconds"]
        summary["iterations"] = t["iterations"]
    out = args.json or args.run / "metrics.json"
    write_metrics(out, summary)
    for k in ("psnr_hr", "ssim_hr", "psnr_hr_masked", "psnr_lr", "normal_mae_deg", "albedo_psnr", "relit_psnr",
              "relit_ssim", "chamfer", "train_seconds", "iterations"):
        if k in summary:
            print(f"{k:16s} {summary[k]:.4f}")
    print(f"wrote {out} and {args.run / 'eval_sheet.png'}")
    dark = summary.get("dark_fraction", 0.0)
    if dark > 0.5:
        from srvol.metrics import DARK_RATIO

        print(f"srvol: warning: the renders are dark: {dark:.0%} of lit foreground pixels get < "
              f"{DARK_RATIO:.0%} of the ground truth (a collapsed run?)", file=sys.stderr)
    return 0


def _run_eval_capture(args, fields, info, scene, cfg) -> int:
    """``srvol eval RUN --gt GT``: srvol.capture.evaluate with the run's volume renderer."""
    from srvol.capture.evaluate import evaluate_capture
    from srvol.evaluate import occupancy_of, render_view, write_metrics

    occupancy = occupancy_of(fields, cfg.sampler)  # one grid for every view
    summary = evaluate_capture(scene, args.gt,
                               lambda cam, light: render_view(fields, cam, light, cfg.sampler, occupancy=occupancy),
                               info.light_intensity, relit=None if args.no_relit else _neural_relit_fn(fields),
                               fields=fields, out_dir=args.run)
    out = args.json or args.run / "metrics.json"
    write_metrics(out, summary)
    for k in ("registered", "rotation_median_deg", "rotation_max_deg", "psnr_hr", "ssim_hr", "psnr_hr_masked",
              "normal_mae_deg", "albedo_psnr", "relit_psnr", "relit_ssim", "chamfer"):
        if k in summary:
            print(f"{k:20s} {summary[k]:.4f}")
    print(f"wrote {out} and {args.run / 'eval_sheet.png'}")
    return 0


def _neural_relit_fn(fields):
    """Shadowed renders of the neural fields under a moved light, from srvol.relight (None if absent);
    2x2 rays per pixel, as the GT's supersampling."""
    try:
        from srvol.relight.render import render_fields
    except ImportError:
        return None
    import numpy as np

    def relit(camera, light):
        return np.asarray(render_fields(fields.sdf, fields.material, camera, light, None, shadows=True,
                                        ss=2).rgb,
                          dtype=np.float32)

    return relit


# ----------------------------------------------------------------------------- bench

BENCHES = {"all": "bench.run_all", "synth": "bench.bench_synth", "train": "bench.bench_train",
           "stage2": "bench.bench_stage2", "export": "bench.bench_export", "relight": "bench.bench_relight", "study": "bench.bench_study",
           "suite": "bench.bench_suite", "capacity": "bench.bench_capacity", "view": "bench.bench_view", "batch": "bench.bench_batch",
           "compile": "bench.bench_compile"}


def _add_bench(sub) -> None:
    p = sub.add_parser("bench", help="run the benchmarks (tables and charts into bench/results/)",
                       description="Run a benchmark of a source checkout; each writes markdown + JSON tables and "
                                   "PNG charts under bench/results/ and records the command of every row. "
                                   "'all' (= make bench) takes about two hours on 2 cores. Arguments after the "
                                   "name go to the benchmark, e.g. `srvol bench study --budget 120 --only sweep`.")
    p.add_argument("which", nargs="?", default="all", choices=tuple(BENCHES),
                   help="synth, train (SR vs noSR vs Vol-SR, paper), stage2 (stage-2 PSF samplers on the train runs), export, relight, "
                        "view (srvol view's render latency), batch (srvol batch against the same steps by hand), "
                        "compile (steps per second with and without the compiled field queries), "
                        "study (N_s sweep, "
                        "stability, capacity), suite (every built-in scene, tuning and report sets; hours, "
                        "resumable; not part of 'all'), capacity (--capacity factors on suite scenes; hours, "
                        "resumable; not part of 'all') or all (default)")
    p.add_argument("args", nargs=argparse.REMAINDER, help="passed on to the benchmark")
    p.set_defaults(func=_run_bench)


def _run_bench(args) -> int:
    import os
    import subprocess

    root = Path(__file__).resolve().parent.parent
    if not (root / "bench" / "run_all.py").is_file():
        raise SrvolError("srvol bench needs a source checkout (bench/ next to srvol/); clone the repository")
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "2"))
    return subprocess.run([sys.executable, "-m", BENCHES[args.which], *args.args], cwd=root, env=env).returncode


# ----------------------------------------------------------------------------- entry points

def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="srvol",
        description="SuperRVol: shape and reflectance sharper than the input images, from flash photos; "
                    "exported as relightable assets.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_synth(sub)
    _add_inspect(sub)
    _add_eval(sub)
    _add_bench(sub)
    for add in _optional_commands():
        add(sub)
    _compose_export_edits(sub)
    return parser


def _compose_export_edits(sub) -> None:
    """``srvol export --material``: the exporter gets the relighter's edit as a callable on its maps."""
    export = sub.choices.get("export")
    if export is None:
        return
    from functools import partial

    from srvol.export.cli import run_export

    def texture_edit_for(specs):
        from srvol.relight.edits import edit_textures, parse_material

        edit = parse_material(specs)
        return partial(edit_textures, edit=edit)

    export.set_defaults(func=partial(run_export, texture_edit_for=texture_edit_for))


def _optional_commands():
    """Commands contributed by the pipeline stages (each module exposes ``add_parser(sub)``)."""
    adders = []
    for mod_name in ("srvol.train_cli", "srvol.capture.cli", "srvol.export.cli", "srvol.relight.cli",
                     "srvol.relight.view", "srvol.report", "srvol.batch.cli"):
        try:
            mod = __import__(mod_name, fromlist=["add_parser"])
        except ModuleNotFoundError as e:
            if e.name != mod_name:
                raise
            continue
        adders.append(mod.add_parser)
    return adders


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except SrvolError as e:
        print(f"srvol: error: {e}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("srvol: interrupted", file=sys.stderr)
        return 130


def relight_main(argv: list[str] | None = None) -> int:
    """``relight ...`` is ``srvol relight ...``."""
    return main(["relight", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
