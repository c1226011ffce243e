"""``export_fields``: fields -> asset folder (export/asset.py's contract), atomically.

Stages: extract (narrow-band marching cubes) -> simplify (auto or N faces) ->
unwrap (xatlas) -> bake (texel centres, gutters) -> write (raw EXRs and mesh
always, then the formats asked). The report carries per-stage seconds and the
choices made.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from srvol.atomic import AtomicFolder, atomic_write_text
from srvol.capture.frame import Similarity
from srvol.errors import SrvolError
from srvol.export.asset import ASSET_FORMAT
from srvol.export.bake import BakeOptions, auto_texture_size, bake
from srvol.export.extract import ExtractOptions, auto_resolution, extract_mesh
from srvol.export.simplify import SimplifyOptions, simplify
from srvol.export.textures import specular_reference, write_textures
from srvol.export.types import Mesh, TextureSet
from srvol.export.uv import unwrap
from srvol.geometry import sdf_normals
from srvol.types import MaterialFn, SdfFn

FORMATS = ("usd", "usdc", "usdz", "gltf", "glb", "obj", "blend")
ALL_FORMATS = ("usd", "usdz", "gltf", "glb", "obj", "blend")
TextureEdit = Callable[[TextureSet], TextureSet]
"""A material edit of baked maps (``srvol export --material``): handed in by the caller, so that
the exporter applies what the relighter renders without importing it."""
FILE_NAMES = {"usd": "model.usda", "usdc": "model.usdc", "usdz": "model.usdz", "gltf": "model.gltf",
              "glb": "model.glb", "obj": "model.obj", "blend": "model.blend"}


@dataclass(frozen=True)
class ExportOptions:
    """formats: subset of FORMATS; resolution / faces / texture_size: None = auto from
    hr_pixel_size (scene units per HR pixel at the object); sdf_cell: the SDF model's finest
    grid cell (None for MLP or exact fields) -- auto marching cubes uses cells of about
    one HR pixel, but no finer than a quarter of it (smoothstep-interpolated grid cells
    carry no shape detail below that); normal_map: bake a tangent-space normal map;
    gutter: dilation texels; force: replace an existing output folder; allow_dark: export a
    material that is black everywhere (otherwise refused as a collapsed run)."""

    formats: tuple[str, ...] = ("usd", "glb")
    resolution: int | None = None
    faces: int | None = None
    texture_size: int | None = None
    normal_map: bool = False
    hr_pixel_size: float = 0.005
    sdf_cell: float | None = None
    allow_dark: bool = False
    gutter: int = 8
    force: bool = False
    to_frame: Similarity | None = None
    frame_name: str = "scene"
    """to_frame: the USD / glTF / OBJ / .blend meshes are written in another frame, x -> s R x + t
    (``srvol export --frame capture``: an imported capture's own frame and units); the raw mesh and
    EXRs that srvol's relighter reads stay in the scene frame; asset.json records both."""


@dataclass
class ExportReport:
    out_dir: Path
    resolution: int = 0
    full_faces: int = 0
    faces: int = 0
    faces_auto: bool = False
    distance_p95: float = 0.0
    normal_mean_deg: float = 0.0
    within_tolerance: bool = True
    charts: int = 0
    texture_size: int = 0
    unfilled_fraction: float = 0.0
    files: dict[str, str] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    cpu_seconds: dict[str, float] = field(default_factory=dict)
    """CPU time of this process (all threads) per stage: wall time is inflated on a shared machine,
    CPU time is not (on 2 uncontended cores wall ~ CPU / 2 .. CPU). The .blend's Blender
    subprocess (stage "blend", wall time) is not counted."""

    def to_json(self) -> dict:
        d = asdict(self)
        d["out_dir"] = str(self.out_dir)
        return d

    def table(self) -> str:
        rows = [("resolution", f"{self.resolution}^3 (narrow band)"),
                ("faces", f"{self.faces} ({'auto' if self.faces_auto else 'asked'}; full {self.full_faces})"),
                ("distance p95", f"{self.distance_p95:.2e} (within tolerance: {self.within_tolerance})"),
                ("normal error", f"{self.normal_mean_deg:.2f} deg mean"),
                ("charts", str(self.charts)), ("texture", f"{self.texture_size}^2"),
                ("unfilled", f"{self.unfilled_fraction:.2%} of texels inside charts")]
        rows += [(f"time {k}", f"{v:.2f} s wall, {self.cpu_seconds.get(k, 0.0):.2f} s CPU")
                 for k, v in self.seconds.items()]
        rows.append(("files", ", ".join(self.files.values())))
        w = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


class _Timer:
    def __init__(self, report: ExportReport, name: str):
        self.report, self.name = report, name

    def __enter__(self):
        self.t0, self.c0 = time.perf_counter(), time.process_time()

    def __exit__(self, *exc):
        self.report.seconds[self.name] = time.perf_counter() - self.t0
        self.report.cpu_seconds[self.name] = time.process_time() - self.c0
        return False


DARK_REFLECTANCE = 0.005
"""Mean albedo + F0 over the surface below which a material counts as black (a collapsed run)."""


def check_not_dark(textures) -> None:
    """Refuse (one line) to export a material that reflects nothing anywhere: a run whose renders
    would be black must be reported, not silently exported."""
    cov = textures.coverage if textures.coverage is not None else np.ones(textures.albedo.shape[:2], bool)
    if not cov.any():
        return
    level = float(textures.albedo[cov][:, :3].mean() + textures.specular[cov][:, :1].mean())
    if level < DARK_REFLECTANCE:
        raise SrvolError(f"the baked material is black (mean albedo + F0 = {level:.4f} < {DARK_REFLECTANCE}): "
                         "a collapsed run? check `srvol eval`, or pass --allow-dark to export it anyway")


SDF_CELL_SUBDIVISION = 4
"""Marching-cubes cells per SDF grid cell: measured on the 360 s demo model, 256^3 (4 per cell)
relights 49.0 dB against the neural fields and 512^3 52.0 dB, at 0.33x the time."""


def mc_cell_size(hr_pixel_size: float, sdf_cell: float | None) -> float:
    """The marching-cubes cell: one HR pixel, or a quarter of the model's finest SDF cell if larger."""
    if sdf_cell is None:
        return hr_pixel_size
    return max(hr_pixel_size, sdf_cell / SDF_CELL_SUBDIVISION)


def surface_area(mesh: Mesh) -> float:
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces
    return float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum())


def _check_formats(formats: tuple[str, ...]) -> tuple[str, ...]:
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise SrvolError(f"unknown export format {bad[0]!r} (choose from {', '.join(FORMATS)}, all)")
    return tuple(dict.fromkeys(formats))


def export_fields(sdf_fn: SdfFn, material_fn: MaterialFn, out_dir: str | Path,
                  options: ExportOptions = ExportOptions(), texture_edit: TextureEdit | None = None) -> ExportReport:
    """Write the asset folder ``out_dir`` from the two field callables; see module docstring.
    ``texture_edit`` (None: none) changes the baked maps before anything is written."""
    formats = _check_formats(options.formats)
    out_dir = Path(out_dir)
    report = ExportReport(out_dir=out_dir)
    t_all, c_all = time.perf_counter(), time.process_time()
    with AtomicFolder(out_dir, options.force) as tmp:
        res = options.resolution or auto_resolution(mc_cell_size(options.hr_pixel_size, options.sdf_cell))
        with _Timer(report, "extract"):
            ext = extract_mesh(sdf_fn, ExtractOptions(resolution=res, normals=False))
        report.resolution, report.full_faces = res, len(ext.mesh.faces)
        with _Timer(report, "simplify"):
            # A normal map carries the field's normals: decimation then answers to distance alone.
            simp = simplify(sdf_fn, ext.mesh, SimplifyOptions(
                faces=options.faces, hr_pixel_size=options.hr_pixel_size,
                normal_deg=None if options.normal_map else SimplifyOptions.normal_deg))
        report.faces, report.faces_auto = simp.faces, options.faces is None
        report.distance_p95, report.normal_mean_deg = simp.error.distance_p95, simp.error.normal_mean_deg
        report.within_tolerance = simp.within_tolerance
        size = options.texture_size or auto_texture_size(surface_area(simp.mesh), options.hr_pixel_size)
        report.texture_size = size
        with _Timer(report, "unwrap"):
            uvr = unwrap(simp.mesh, size)
            vertices = torch.from_numpy(np.ascontiguousarray(uvr.mesh.vertices, np.float32))
            mesh = Mesh(vertices=uvr.mesh.vertices, faces=uvr.mesh.faces, uv=uvr.mesh.uv,
                        normals=sdf_normals(sdf_fn, vertices).numpy())
        report.charts = uvr.charts
        with _Timer(report, "bake"):
            baked = bake(sdf_fn, material_fn, mesh, BakeOptions(texture_size=size, gutter=options.gutter,
                                                                normal_map=options.normal_map))
        report.unfilled_fraction = baked.unfilled_fraction
        textures = baked.textures if texture_edit is None else texture_edit(baked.textures)
        if not options.allow_dark:
            check_not_dark(textures)
        _write_all(tmp, mesh, textures, formats, report, t_all, c_all, options)
    return report


def _write_all(tmp: Path, mesh: Mesh, textures: TextureSet, formats: tuple[str, ...], report: ExportReport,
               t_all: float, c_all: float, options: ExportOptions | None = None) -> None:
    """Files, .blend, manifest (with the report's stats) and permissions of an asset folder being built;
    with ``options.to_frame`` the formats get the mesh in that frame (the raw mesh stays in the scene's)."""
    to_frame = options.to_frame if options is not None else None
    with _Timer(report, "write"):
        report.files = write_asset_files(tmp, mesh, textures, formats, mesh_in_frame(mesh, to_frame))
    if "blend" in formats:  # last, from the USD, by Blender in a subprocess (timed on its own)
        from srvol.export.blender import write_blend

        with _Timer(report, "blend"):
            write_blend(tmp, tmp / FILE_NAMES["blend"], specular_reference(textures))
        report.files["blend"] = FILE_NAMES["blend"]
    report.seconds["total"] = time.perf_counter() - t_all
    report.cpu_seconds["total"] = time.process_time() - c_all
    stats = report.to_json()
    stats.pop("files")
    stats.pop("out_dir")
    if to_frame is not None:
        stats["frame"] = {"name": options.frame_name, "scene_to_frame": to_frame.to_json(), "raw_mesh": "scene frame"}
    _write_manifest(tmp, report.files, textures.normal is not None, stats)
    _make_readable(tmp)


def reexport_asset(src_dir: str | Path, out_dir: str | Path, formats: tuple[str, ...],
                   texture_edit: TextureEdit | None = None, force: bool = False) -> ExportReport:
    """A new asset folder from an existing one's mesh and lossless maps (no re-bake), with ``texture_edit``
    applied to the maps; written atomically, through the same writers as :func:`export_fields`."""
    from srvol.export.asset import load_asset

    formats = _check_formats(formats)
    src_dir, out_dir = Path(src_dir), Path(out_dir)
    if out_dir.resolve() == src_dir.resolve():
        raise SrvolError(f"{out_dir}: the output would replace the asset it is made from; choose another --out")
    asset = load_asset(src_dir)
    report = ExportReport(out_dir=out_dir, faces=len(asset.mesh.faces), texture_size=asset.textures.albedo.shape[0])
    t_all, c_all = time.perf_counter(), time.process_time()
    textures = asset.textures if texture_edit is None else texture_edit(asset.textures)
    with AtomicFolder(out_dir, force) as tmp:
        _write_all(tmp, asset.mesh, textures, formats, report, t_all, c_all)
    return report


def _make_readable(root: Path) -> None:
    """Temporary files and folders are created private (0600/0700); an asset is ordinary output."""
    root.chmod(0o755)
    for p in root.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)


def mesh_in_frame(mesh: Mesh, to_frame: Similarity | None) -> Mesh:
    """``mesh`` with its vertices mapped by ``to_frame`` and its normals rotated (itself if None)."""
    if to_frame is None:
        return mesh
    normals = None if mesh.normals is None else (mesh.normals.astype(np.float64) @ to_frame.rotation.T).astype(np.float32)
    return Mesh(vertices=to_frame.apply(mesh.vertices).astype(np.float32), faces=mesh.faces, uv=mesh.uv,
                normals=normals)


def write_asset_files(root: Path, mesh: Mesh, textures, formats: tuple[str, ...],
                      frame_mesh: Mesh | None = None) -> dict[str, str]:
    """raw/mesh.npz, raw/*.exr, textures/*.png and the asked formats under ``root`` (all but
    .blend, which Blender writes from the USD: see export_fields). The formats get ``frame_mesh``
    where given (the same mesh in another frame), raw/mesh.npz always ``mesh``."""
    from srvol.export.gltf import write_glb, write_gltf
    from srvol.export.obj import write_obj
    from srvol.export.usd import write_usd, write_usdz

    (root / "raw").mkdir(parents=True, exist_ok=True)
    np.savez(root / "raw" / "mesh.npz", vertices=mesh.vertices, faces=mesh.faces, uv=mesh.uv,
             normals=mesh.normals)
    tex = write_textures(root, textures)
    files: dict[str, str] = {}
    f0_ref = specular_reference(textures)
    mesh = frame_mesh if frame_mesh is not None else mesh
    for fmt in formats:
        path = root / FILE_NAMES[fmt]
        if fmt in ("usd", "usdc"):
            write_usd(path, mesh, tex)
        elif fmt == "usdz":
            write_usdz(path, mesh, tex)
        elif fmt == "glb":
            write_glb(path, mesh, root, tex, f0_ref)
        elif fmt == "gltf":
            write_gltf(path, mesh, root, tex, f0_ref)
        elif fmt == "obj":
            write_obj(path, mesh, tex)
        elif fmt == "blend":
            continue
        files[fmt] = path.name
    return files


def _write_manifest(root: Path, files: dict[str, str], has_normal: bool, stats: dict) -> None:
    textures = {"albedo": "raw/albedo.exr", "specular": "raw/specular.exr", "alpha": "raw/alpha.exr",
                "roughness": "raw/roughness.exr"}
    if has_normal:
        textures["normal"] = "raw/normal.exr"
    meta = {"format": ASSET_FORMAT, "mesh": "raw/mesh.npz", "textures": textures, "files": files, "stats": stats}
    atomic_write_text(root / "asset.json", json.dumps(meta, indent=1))
