"""``srvol relight`` (also ``relight``): render a run, an asset or a built-in scene under a moved point light."""
from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

from srvol.cli_parser import image_size
from srvol.errors import SrvolError
from srvol.relight.edits import SPEC_HELP, parse_material
from srvol.relight.render import RelitImage, render_scene
from srvol.relight.sources import BUILTIN_FIELDS, Source, default_camera, load_source, resize_camera
from srvol.types import Camera, PointLight

IMAGE_SUFFIXES = (".exr", ".png")
DEFAULT_RESOLUTION = (640, 480)


@dataclass(frozen=True)
class NamedCamera:
    name: str
    camera: Camera


@dataclass(frozen=True)
class RelightJob:
    """One image to render: output name, camera and light."""

    name: str
    camera: Camera
    light: PointLight


def add_parser(sub) -> None:
    p = sub.add_parser(
        "relight", help="render a run or an exported asset under a moved point light, with shadows",
        description="Render the neural model (a training RUN), an exported asset folder, or an exact built-in "
                    "scene under a point light that need not sit at the camera, with shadows and optional "
                    "material edits, through the BRDF used in training. Positions are in the scene frame: "
                    "the object normalised into the unit sphere, +z up.")
    p.add_argument("source", nargs="?", type=Path, metavar="SOURCE",
                   help="a training run folder (config.json) or an exported asset folder (asset.json)")
    p.add_argument("--builtin", choices=BUILTIN_FIELDS,
                   help="render a built-in scene's exact analytic fields instead of SOURCE (validation aid)")
    p.add_argument("--light-pos", required=True, metavar="X,Y,Z",
                   help="light position in the scene frame (object in the unit sphere, +z up), e.g. -1.5,0,2")
    p.add_argument("--intensity", metavar="I|R,G,B",
                   help="radiant intensity (W/sr) of the light, one number or r,g,b, in the scene's units "
                        "(default: the run's learned/given intensity; 10 for assets and built-ins)")
    cams = p.add_mutually_exclusive_group()
    cams.add_argument("--view", metavar="NAME", help="a view (image stem) of the run's scene, rendered at HR")
    cams.add_argument("--camera", type=Path, metavar="FILE",
                      help="a cameras.json-style file; every entry is rendered at its img_size")
    cams.add_argument("--orbit", type=int, metavar="N",
                      help="N lights circling the object about +z (through --light-pos), into one sheet PNG")
    p.add_argument("--scene", type=Path, metavar="DIR", help="scene folder for --view (default: the run's scene)")
    p.add_argument("--resolution", type=image_size, metavar="WxH",
                   help="render size (default: the camera's; 640x480 for the default camera)")
    p.add_argument("--material", action="append", default=[], metavar="SPEC", help=f"material edit: {SPEC_HELP}")
    p.add_argument("--shadows", action=argparse.BooleanOptionalAction, default=True,
                   help="shadow rays towards the light (default on)")
    p.add_argument("--ss", type=int, default=1, metavar="N", help="N x N rays per pixel (default 1)")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    p.add_argument("--out", required=True, type=Path, metavar="FILE.exr|FILE.png|DIR",
                   help="EXR = linear float; PNG = sRGB-encoded 8-bit; DIR = one .exr (+ .png preview) per image")
    p.set_defaults(func=run_relight)


# ----------------------------------------------------------------------------- argument parsing

def parse_floats(text: str, what: str, counts: tuple[int, ...]) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise SrvolError(f"{what} {text}: expected {' or '.join(map(str, counts))} comma-separated numbers") from None
    if len(vals) not in counts or not all(math.isfinite(v) for v in vals):
        raise SrvolError(f"{what} {text}: expected {' or '.join(map(str, counts))} finite comma-separated numbers")
    return vals


def parse_light(pos_text: str, intensity_text: str | None, default: tuple[float, float, float]) -> PointLight:
    pos = parse_floats(pos_text, "--light-pos", (3,))
    inten = list(default) if intensity_text is None else parse_floats(intensity_text, "--intensity", (1, 3))
    if any(v < 0 for v in inten):
        raise SrvolError(f"--intensity {intensity_text}: must not be negative")
    return PointLight.make(pos, inten if len(inten) == 3 else inten * 3)


def read_cameras_file(path: Path) -> list[NamedCamera]:
    """A cameras.json-style file (:func:`srvol.data.read_cameras_json`) -> cameras named by the keys' stems."""
    from srvol.data import read_cameras_json

    return [NamedCamera(Path(key).stem, camera) for key, camera in read_cameras_json(path).items()]


def view_camera(source: Source, scene_dir: Path | None, view: str) -> Camera:
    from srvol.data import load_scene

    root = scene_dir or source.scene_dir
    if root is None:
        raise SrvolError(f"--view {view}: no scene known for this source (give --scene DIR)")
    scene = load_scene(root, load_images=False)
    if view not in scene.views:
        raise SrvolError(f"--view {view}: no such view in {root} (views: {', '.join(list(scene.views)[:8])}...)")
    return scene.hr_camera(view)


def orbit_lights(light: PointLight, n: int) -> list[PointLight]:
    """``n`` copies of ``light`` rotated about +z by 360 k / n degrees (same height and radius)."""
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n
        c, s = math.cos(a), math.sin(a)
        x, y, z = light.position.tolist()
        out.append(PointLight.make([c * x - s * y, s * x + c * y, z], light.intensity.tolist()))
    return out


def plan_jobs(args, source: Source, light: PointLight) -> list[RelightJob]:
    size = args.resolution
    if args.camera is not None:
        cams = read_cameras_file(args.camera)
    elif args.view is not None:
        cams = [NamedCamera(args.view, view_camera(source, args.scene, args.view))]
    else:
        w, h = size or DEFAULT_RESOLUTION
        cams = [NamedCamera("default", default_camera(w, h))]
    if size is not None:
        cams = [NamedCamera(c.name, resize_camera(c.camera, *size)) for c in cams]
    if args.orbit is not None:
        if args.orbit < 1 or args.orbit > 64:
            raise SrvolError(f"--orbit {args.orbit}: must be 1..64")
        cam = cams[0]
        return [RelightJob(f"{cam.name}_light{k:02d}", cam.camera, lk)
                for k, lk in enumerate(orbit_lights(light, args.orbit))]
    return [RelightJob(c.name, c.camera, light) for c in cams]


# ----------------------------------------------------------------------------- running

def _check_lights(source: Source, jobs: list[RelightJob]) -> None:
    for job in jobs:
        if source.scene.contains(job.light.position):
            pos = ",".join(f"{v:g}" for v in job.light.position.tolist())
            what = "inside the mesh" if source.kind == "asset" else "SDF < 0"
            raise SrvolError(f"--light-pos {pos}: the light is inside the object ({what}); move it outside")


def run_relight(args) -> int:
    out: Path = args.out
    suffix = out.suffix.lower()
    if suffix and suffix not in IMAGE_SUFFIXES:
        raise SrvolError(f"--out {out}: use a .exr or .png file, or a folder (no suffix)")
    if args.ss < 1 or args.ss > 8:
        raise SrvolError(f"--ss {args.ss}: must be 1..8")
    edit = parse_material(args.material)
    source = load_source(args.source, args.builtin)
    light = parse_light(args.light_pos, args.intensity, source.intensity)
    jobs = plan_jobs(args, source, light)
    _check_lights(source, jobs)
    if args.orbit is not None and suffix == ".exr":
        raise SrvolError("--orbit writes a sheet: give --out FILE.png or a folder")
    if len(jobs) > 1 and suffix and args.orbit is None:
        raise SrvolError(f"--out {out}: {len(jobs)} cameras need an output folder, not one file")
    images = [(job, render_scene(source.scene, job.camera, job.light, edit, args.shadows, args.ss)) for job in jobs]
    write_outputs(out, images, args.orbit is not None, args.force, f"{source.label}  {edit.describe()}")
    print(f"wrote {out} ({len(images)} image{'s' if len(images) > 1 else ''}, material: {edit.describe()}, "
          f"shadows {'on' if args.shadows else 'off'})")
    return 0


def _orbit_sheet(path: Path, images: list[tuple[RelightJob, RelitImage]], title: str) -> None:
    from srvol.sheets import write_sheet

    per_row = 4
    tiles = [(f"light {','.join(f'{v:.2f}' for v in job.light.position.tolist())}", img.rgb) for job, img in images]
    write_sheet(path, [tiles[i:i + per_row] for i in range(0, len(tiles), per_row)], title=title)


def write_outputs(out: Path, images: list[tuple[RelightJob, RelitImage]], orbit: bool, force: bool,
                  title: str) -> None:
    from srvol.atomic import AtomicFolder
    from srvol.images import write_exr, write_png

    suffix = out.suffix.lower()
    if suffix:
        if out.exists() and not force:
            raise SrvolError(f"{out}: already exists (use --force to replace it)")
        if orbit:
            _orbit_sheet(out, images, title)
        elif suffix == ".exr":
            write_exr(out, images[0][1].rgb)
        else:
            write_png(out, images[0][1].rgb, srgb=True)
        return
    with AtomicFolder(out, force=force) as tmp:
        for job, img in images:
            write_exr(tmp / f"{job.name}.exr", img.rgb)
            write_png(tmp / f"{job.name}.png", img.rgb, srgb=True)
        if orbit:
            _orbit_sheet(tmp / "sheet.png", images, title)

