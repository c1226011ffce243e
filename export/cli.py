"""``srvol export RUN --format ... --out DIR``: a trained run (or a built-in analytic field) to an asset."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

from srvol.errors import SrvolError

if TYPE_CHECKING:
    from srvol.export.pipeline import TextureEdit

BUILTIN_FIELDS = ("bumpy", "glossy")


def _auto_int(text: str) -> int | None:
    if text == "auto":
        return None
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a positive integer, got {text!r}") from None
    if n <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {n}")
    return n


def add_parser(sub) -> None:
    from srvol.export.pipeline import FORMATS

    p = sub.add_parser(
        "export", help="export a trained run as a USD / glTF / OBJ / .blend asset",
        description="Narrow-band marching cubes -> decimation -> xatlas UVs -> baked textures (albedo, F0, "
                    "alpha and roughness = sqrt(alpha), optional normal map) -> the formats asked, plus the "
                    "lossless EXRs and asset.json that `srvol relight` reads.")
    p.add_argument("run", nargs="?", type=Path, metavar="SOURCE",
                   help="training run folder (config.json, model.pt), or an asset folder (asset.json): its mesh "
                        "and lossless maps are written again, in the formats asked, with --material applied")
    p.add_argument("--builtin", choices=BUILTIN_FIELDS,
                   help="validation aid: export the exact analytic ground-truth fields of a built-in scene "
                        "instead of a trained run")
    p.add_argument("--format", default="usd", help=f"one of {', '.join(FORMATS)}, all, or a comma list "
                                                   "(default usd)")
    p.add_argument("--out", type=Path, required=True, help="asset folder to write")
    p.add_argument("--resolution", type=_auto_int, default=None, metavar="auto|N",
                   help="marching-cubes cells per axis over [-1, 1] (auto: one cell per HR pixel "
                        "footprint, but no finer than a quarter of a grid model's finest SDF cell)")
    p.add_argument("--faces", type=_auto_int, default=None, metavar="auto|N",
                   help="face budget (auto: smallest within the HR-pixel error tolerance)")
    p.add_argument("--texture-size", type=_auto_int, default=None, metavar="auto|N",
                   help="texture side in texels (auto: about one texel per HR pixel footprint)")
    p.add_argument("--hr-pixel-size", type=float, default=None,
                   help="override the HR pixel footprint in scene units (default: from the run)")
    p.add_argument("--allow-dark", action="store_true",
                   help="export even when the baked material is black everywhere (refused by default: "
                        "the sign of a collapsed run)")
    p.add_argument("--normal-map", action="store_true", help="also bake a tangent-space normal map")
    p.add_argument("--material", action="append", default=[], metavar="SPEC",
                   help="edit the baked maps, as `relight --material` renders them (e.g. roughness-scale=0.5, "
                        "gold, albedo-tint=1,0.8,0.8); repeatable")
    p.add_argument("--frame", choices=("scene", "capture"), default="scene",
                   help="frame of the USD / glTF / OBJ / .blend mesh: scene (the unit sphere, default) or capture "
                        "(an imported capture's own frame and units, by the normalisation its scene.json "
                        "records; the raw mesh for `relight` stays in the scene frame)")
    p.add_argument("--force", action="store_true", help="replace an existing --out folder")
    p.set_defaults(func=run_export)


def _formats(text: str) -> tuple[str, ...]:
    from srvol.export.pipeline import ALL_FORMATS

    names = [t.strip() for t in text.split(",") if t.strip()]
    out: list[str] = []
    for n in names:
        out.extend(ALL_FORMATS if n == "all" else [n])
    return tuple(out)


def _builtin_fields(name: str):
    from srvol.field_adapters import material_in_float64
    from srvol.synth import scenes

    sdf64, mat64 = {"bumpy": (scenes.bumpy_sdf, scenes.bumpy_material),
                    "glossy": (scenes.glossy_sdf, scenes.glossy_material)}[name]
    # The SDF's closed form runs in the caller's dtype: float32 errs by ~2e-7, far below a 1/256 cell.
    return sdf64, material_in_float64(mat64)


BUILTIN_HR_PIXEL_SIZE = 0.005
"""HR pixel footprint assumed for --builtin (the default synthetic scene's HR pixels at the object)."""


def _capture_frame(scene_dir):
    """scene -> capture similarity of the imported scene a run was trained on (one-line errors)."""
    from srvol.capture.frame import read_normalization

    if scene_dir is None:
        raise SrvolError("--frame capture needs a run trained on an imported scene (srvol import)")
    norm = read_normalization(Path(scene_dir))
    if norm is None:
        raise SrvolError(f"{scene_dir}: not an imported capture (scene.json has no normalization): "
                         f"--frame capture needs one")
    return norm.inverse()


TextureEditFor = Callable[[Sequence[str]], "TextureEdit"]
"""``--material`` specs -> a texture edit; the composition root (srvol.cli) hands it in, since the
specs' meaning belongs to the relighter, which this package does not import."""


def run_export(args, texture_edit_for: TextureEditFor | None = None) -> int:
    from srvol.export.asset import is_asset_dir
    from srvol.export.pipeline import ExportOptions, export_fields, reexport_asset

    if (args.run is None) == (args.builtin is None):
        raise SrvolError("export needs a training run folder or --builtin NAME (not both)")
    texture_edit = None
    if args.material:
        if texture_edit_for is None:
            raise SrvolError("--material needs srvol.relight (run `srvol export`, not this module)")
        texture_edit = texture_edit_for(args.material)
    if args.run is not None and is_asset_dir(args.run):
        report = reexport_asset(args.run, args.out, _formats(args.format), texture_edit, args.force)
        print(f"wrote {args.out} ({', '.join(report.files.values())}) from the asset {args.run}")
        return 0
    if args.builtin is not None:
        sdf_fn, material_fn = _builtin_fields(args.builtin)
        hr, sdf_cell = BUILTIN_HR_PIXEL_SIZE, None
    else:
        try:
            from srvol.checkpoint import load_model
        except ImportError:
            raise SrvolError("this srvol build cannot load trained runs (srvol.checkpoint.load_model missing)") from None
        if not args.run.is_dir():
            raise SrvolError(f"{args.run}: not a run folder")
        try:
            model, info = load_model(args.run, device="cpu")
        except SrvolError:
            raise
        except Exception as e:  # a corrupt checkpoint surfaces as torch/pickle/KeyError errors
            raise SrvolError(f"{args.run}: unreadable checkpoint ({type(e).__name__}: {e})") from None
        sdf_fn, material_fn, hr = model.sdf, model.material, info.hr_pixel_size
        sdf_cell = model.finest_sdf_cell()
    if args.hr_pixel_size is not None:
        hr = args.hr_pixel_size
    to_frame = None
    if args.frame == "capture":
        to_frame = _capture_frame(info.scene_dir if args.run is not None else None)
    opts = ExportOptions(to_frame=to_frame, frame_name=args.frame, formats=_formats(args.format), resolution=args.resolution, faces=args.faces,
                         texture_size=args.texture_size, normal_map=args.normal_map, hr_pixel_size=hr,
                         sdf_cell=sdf_cell, allow_dark=args.allow_dark, force=args.force)
    report = export_fields(sdf_fn, material_fn, args.out, opts, texture_edit)
    print(report.table())
    print(f"wrote {args.out}")
    return 0
