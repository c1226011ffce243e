"""``srvol import PHOTOS --out SCENE``: a folder of photos -> a scene folder (DESIGN.md section 4).

read (upright, linear, working resolution; SfM copies) -> poses (pycolmap, or --colmap / --transforms)
-> normalisation (object sphere from the sparse points most views see -> unit sphere, up -> +z)
-> masks (automatic, or --masks) -> scene (image/*.exr linear, mask/*.png, cameras.json, scene.json
with the PSF sigma of the decimation and the normalisation; capture/points.ply: the sparse points,
capture/object_points.ply: those the object's sphere came from, both in the capture frame;
capture/sparse/largest: the COLMAP model; capture/import.json: what the import did).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from srvol.atomic import AtomicFolder, atomic_write_text
from srvol.capture import masks as masks_mod
from srvol.capture.frame import (ObjectSphere, Similarity, normalization, object_sphere_from_cameras,
                                 object_sphere_from_points, up_direction)
from srvol.capture.photos import PhotoInfo, list_photos, notice, read_photo_srgb
from srvol.capture.resolution import WorkingResolution, choose_resolution, scale_intrinsics, to_working
from srvol.capture.sfm import SFM_THREADS, Registration, run_sfm, sfm_copy_side, write_sfm_image
from srvol.data import SceneInfo, View, write_scene_folder
from srvol.errors import SrvolError
from srvol.images import srgb_to_linear
from srvol.types import Camera

MIN_REGISTERED = 0.5
"""Fewer registered photos than this share is an error (listing the unregistered ones)."""


@dataclass(frozen=True)
class ImportOptions:
    """lr: working size (W, H) or None (default from the photo size); colmap / transforms: existing
    poses instead of SfM; masks: a folder of given masks instead of automatic ones; threads: for
    pycolmap; force: replace ``out``; progress: progress bars."""

    lr: tuple[int, int] | None = None
    colmap: Path | None = None
    transforms: Path | None = None
    masks: Path | None = None
    threads: int = SFM_THREADS
    force: bool = False
    progress: bool = True


@dataclass(frozen=True)
class ImportReport:
    """What an import did (written to SCENE/capture/import.json)."""

    photos: int
    registered: list[str]
    unregistered: list[str]
    pose_source: str
    focal_sources: dict[str, int]
    photo_size: list[int]
    working_size: list[int]
    factor: int
    psf_sigma_lr_px: float
    normalization: dict
    object_points: int
    masks: str
    seconds: dict[str, float]


def import_capture(photos_dir: Path, out: Path, opts: ImportOptions = ImportOptions()) -> ImportReport:
    """Write the scene of the capture in ``photos_dir`` into ``out`` (atomically)."""
    t0 = time.time()
    if opts.colmap is not None and opts.transforms is not None:
        raise SrvolError("give --colmap or --transforms, not both")
    photos = list_photos(Path(photos_dir))
    res = _working_resolution(photos, opts.lr)
    folder = AtomicFolder(out, force=opts.force)
    seconds: dict[str, float] = {}
    with folder as tmp:
        work = tmp / "capture"
        sfm_dir = work / "sfm_images"
        sfm_dir.mkdir(parents=True)
        use_sfm = opts.colmap is None and opts.transforms is None
        lr_images: dict[str, np.ndarray] = {}
        copy_sides = {p.size: sfm_copy_side(max(res[p.name].size)) for p in photos}  # SfM copies, by photo size
        for p in tqdm(photos, desc="read photos", unit="photo", disable=not opts.progress):
            srgb = read_photo_srgb(p.path)
            if srgb.shape[:2] != (p.height, p.width):
                raise SrvolError(f"{p.path}: size changed while reading")
            if use_sfm:
                write_sfm_image(sfm_dir / f"{p.name}.jpg", srgb, copy_sides[p.size])
            lr_images[p.name] = to_working(srgb_to_linear(srgb), res[p.name])
        seconds["read"] = time.time() - t0
        t1 = time.time()
        reg = _register(photos, opts, sfm_dir, work, copy_sides)
        seconds["poses"] = time.time() - t1
        _check_registered(photos, reg)
        sim, sphere = _normalize(reg)
        cams = {n: _to_scene(sim, c, res[n].factor) for n, c in reg.cameras.items()}
        _warn_close_cameras(cams)
        t2 = time.time()
        masks = _masks(reg, lr_images, cams, res, opts)
        seconds["masks"] = time.time() - t2
        views = [View(name=n, camera=cams[n], image=lr_images[n], mask=masks[n]) for n in reg.cameras]
        sigma = res[photos[0].name].psf_sigma_lr_px
        info = SceneInfo(color_space="linear", light_intensity=None, psf_sigma_lr_px=sigma, sr_factor=4,
                         train=tuple(reg.cameras), test=())
        write_scene_folder(tmp, views, info)
        scene_json = {**info.to_json(), "normalization": sim.to_json()}
        atomic_write_text(tmp / "scene.json", json.dumps(scene_json, indent=1))
        _write_points(work / "points.ply", reg.points)
        if sphere.points is not None:
            _write_points(work / "object_points.ply", sphere.points)
        _drop_sfm_scratch(work)
        seconds["total"] = time.time() - t0
        r0 = res[photos[0].name]
        report = ImportReport(
            photos=len(photos), registered=list(reg.cameras), unregistered=list(reg.unregistered),
            pose_source=reg.source, focal_sources=_focal_sources(photos), photo_size=list(photos[0].size),
            working_size=list(r0.size), factor=r0.factor, psf_sigma_lr_px=sigma,
            normalization=sim.to_json(), object_points=sphere.points_used,
            masks="given" if opts.masks else "automatic", seconds={k: round(v, 2) for k, v in seconds.items()})
        atomic_write_text(work / "import.json", json.dumps(asdict(report), indent=1))
    return report


def _working_resolution(photos: list[PhotoInfo], lr) -> dict[str, WorkingResolution]:
    """The working resolution of each photo; photos of several sizes must share the PSF."""
    by_size = {p.size: choose_resolution(p.size, lr) for p in photos}
    if len({r.psf_sigma_lr_px for r in by_size.values()}) > 1:
        a, b = list(by_size)[:2]
        pa = next(p for p in photos if p.size == a)
        pb = next(p for p in photos if p.size == b)
        raise SrvolError(f"photos of different sizes need different decimations: {pa.path.name} is "
                         f"{a[0]}x{a[1]}, {pb.path.name} is {b[0]}x{b[1]} (import them separately)")
    return {p.name: by_size[p.size] for p in photos}


def _register(photos: list[PhotoInfo], opts: ImportOptions, sfm_dir: Path, work: Path,
              copy_sides: dict[tuple[int, int], int]) -> Registration:
    if opts.colmap is not None:
        from srvol.capture.external import load_colmap

        return load_colmap(opts.colmap, photos)
    if opts.transforms is not None:
        from srvol.capture.external import load_transforms

        return load_transforms(opts.transforms, photos)
    print(f"structure from motion: {len(photos)} photos (pycolmap: SIFT, "
          f"{'exhaustive' if len(photos) <= 150 else 'sequential'} matching, incremental mapping)", flush=True)
    return run_sfm(photos, sfm_dir, work, threads=opts.threads, copy_sides=copy_sides)


def _check_registered(photos: list[PhotoInfo], reg: Registration) -> None:
    n, k = len(photos), len(reg.cameras)
    if reg.unregistered:
        listed = ", ".join(reg.unregistered[:20]) + (" ..." if len(reg.unregistered) > 20 else "")
        if k < MIN_REGISTERED * n or k < 3:
            raise SrvolError(f"only {k} of {n} photos registered (need at least half); unregistered: {listed}")
        notice(f"{len(reg.unregistered)} of {n} photos did not register and are left out: {listed}")


def _normalize(reg: Registration) -> tuple[Similarity, ObjectSphere]:
    cams = list(reg.cameras.values())
    if len(reg.points) >= 20:
        sphere = object_sphere_from_points(reg.points, cams)
    else:
        notice("no sparse points: the object's sphere is estimated from where the cameras look")
        sphere = object_sphere_from_cameras(cams)
    return normalization(sphere, up_direction(cams)), sphere


def _to_scene(sim: Similarity, cam: Camera, factor: int) -> Camera:
    c = sim.camera(cam)
    K = torch.from_numpy(scale_intrinsics(c.K.numpy(), factor))
    return Camera(K=K, W2C=c.W2C, width=cam.width // factor, height=cam.height // factor)


def _warn_close_cameras(cams: dict[str, Camera]) -> None:
    close = [n for n, c in cams.items() if float(c.center.norm()) < 1.05]
    if close:
        notice(f"{len(close)} camera(s) lie inside the scene bound after normalisation: {', '.join(close[:8])}")


def _masks(reg: Registration, images: dict[str, np.ndarray], cams: dict[str, Camera],
           res: dict[str, WorkingResolution], opts: ImportOptions) -> dict[str, np.ndarray]:
    if opts.masks is not None:
        return {n: masks_mod.read_given_mask(opts.masks, n, res[n]) for n in reg.cameras}
    raw = {n: masks_mod.threshold_mask(images[n], masks_mod.outside_bound(cams[n])) for n in reg.cameras}
    out = masks_mod.consistent_masks(raw, cams)
    empty = [n for n, m in out.items() if not m.any()]
    if empty:
        raise SrvolError(f"no object found in photo(s) {', '.join(empty[:8])} (the flash-lit object should be "
                         f"brighter than the background; or give --masks)")
    return out


def _write_points(path: Path, points: np.ndarray) -> None:
    import trimesh

    path.parent.mkdir(parents=True, exist_ok=True)
    if len(points):
        trimesh.PointCloud(points).export(path)


def _drop_sfm_scratch(work: Path) -> None:
    """Keep the sparse model (capture/sfm/sparse/largest), drop the SfM copies and the database."""
    import shutil

    shutil.rmtree(work / "sfm_images", ignore_errors=True)
    (work / "database.db").unlink(missing_ok=True)
    sparse = work / "sparse"
    if sparse.is_dir():
        for p in sparse.iterdir():
            if p.name != "largest":
                shutil.rmtree(p, ignore_errors=True)


def _focal_sources(photos: list[PhotoInfo]) -> dict[str, int]:
    out: dict[str, int] = {}
    for p in photos:
        key = p.focal.source if p.focal else "none"
        out[key] = out.get(key, 0) + 1
    return out
