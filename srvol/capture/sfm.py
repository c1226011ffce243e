"""Poses of a capture's photos by structure from motion (pycolmap).

SIFT features, exhaustive matching for small sets (sequential matching beyond
:data:`EXHAUSTIVE_MAX`), one shared SIMPLE_PINHOLE camera per image size (its focal starts at the
EXIF prior where every photo of that size has one), incremental mapping, then the model that
registered the most photos. Photos outside it are listed as unregistered.

pycolmap reads the photos from a folder of upright 8-bit copies that :func:`write_sfm_image`
writes: what COLMAP reads itself would ignore the EXIF orientation of PNGs and TIFFs and cut
16-bit photos to 8 bits anyway; the copies are contrast-stretched (dim flash photos give SIFT few
features otherwise).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from srvol.capture.photos import PhotoInfo, notice
from srvol.errors import SrvolError
from srvol.types import Camera

EXHAUSTIVE_MAX = 150
"""Up to this many photos every pair is matched; beyond, each photo with its 20 neighbours in name order."""

MIN_TRACK = 3
MAX_POINT_ERROR_PX = 1.0
"""Sparse points kept: seen in at least MIN_TRACK photos, mean reprojection error at most this (COLMAP's
usual filter for a model's reliable points)."""

MAPPER_THRESHOLDS = ((50, 15), (30, 12))
"""(inliers to start a model, inliers to register a photo) of each mapping attempt; the next is tried
only while photos are left out. An object photographed against a far background: consecutive photos
share few object features, and the background's look like a pure rotation. COLMAP's defaults
(100, 30) left 12 of the 64 photos of the bunny capture out; (50, 15) registers all 64 (median
rotation error 0.35 deg)."""

SFM_MAX_SIDE = 1600
"""The SfM copies' longest side at most (COLMAP's own default is 3200; the keypoints are scaled back)."""

SFM_WORKING_MULTIPLE = 2
"""The SfM copies' longest side at most this many times the working (LR) resolution's: the poses need
to be exact at the resolution training sees, and SIFT's cost grows with the copy's area (features)
and its square (exhaustive matching). The 64-photo bunny capture registers at 0.24 deg median
rotation error from copies the working size itself; 100 photos of 12 MP made 1600-px copies with
~20k features each, and matching had done 432 of the 4950 pairs after 20 minutes on one thread."""


@dataclass(frozen=True)
class Registration:
    """Cameras of the registered photos (capture frame, upright photo size), keyed by view name;
    the sparse points (N, 3) in the same frame; the photos that did not register; where the poses
    came from ("sfm", "colmap", "transforms")."""

    cameras: dict[str, Camera]
    points: np.ndarray
    unregistered: tuple[str, ...]
    source: str


SFM_THREADS = 1
"""pycolmap's threads in every SfM stage. One thread makes an import reproducible: with two, the
20-photo capture of the tests imported to 0.36, 0.48 and 7.73 deg median rotation error in three
runs (the worker threads' RANSAC seeds, and the order in which extraction writes the images, vary);
with one, 0.30 deg four times out of four, 4.4 s instead of 3.4 s. One stage at a time on two
threads (matching, mapping or extraction) still varied."""


SHRUNK_FIRST_OCTAVE = 0
"""SIFT's first octave for copies shrunk from bigger photos (COLMAP's default -1, the image doubled,
stays for photos at their own size). Four 732-px copies of the 12 MP bunny capture: 16.3-17.4k
features each and 28 s to match a pair on one thread with -1 (4950 pairs for 100 photos: about 38
hours), 1.4k features and 0.1 s a pair with 0, still 87-316 inlier matches per pair (-1: 106-422)."""


def sfm_copy_side(working_side: int) -> int:
    """The longest side the SfM copies of photos worked at ``working_side`` (LR, longest) may have."""
    return min(SFM_MAX_SIDE, SFM_WORKING_MULTIPLE * working_side)


def sfm_copy_size(width: int, height: int, max_side: int = SFM_MAX_SIDE) -> tuple[int, int, float]:
    """(w, h, factor) of the SfM copy of a photo: longest side at most ``max_side``."""
    f = max(1.0, max(width, height) / max_side)
    return round(width / f), round(height / f), f


def write_sfm_image(path: Path, srgb: np.ndarray, max_side: int = SFM_MAX_SIDE) -> None:
    """An 8-bit JPEG copy of an upright sRGB photo (H, W, 3) for SIFT: shrunk to :func:`sfm_copy_size`
    (the mean over each copy pixel's area), stretched so that its 0.5th and 99.5th percentiles span
    the range, then locally equalised (CLAHE, at the copy's size: a dim background's texture gives
    features too)."""
    from PIL import Image
    from skimage.exposure import equalize_adapthist

    w, h, f = sfm_copy_size(srgb.shape[1], srgb.shape[0], max_side)
    x = srgb
    if f > 1:  # shrink first: the percentiles and the stretch of a 12 MP photo cost seconds
        t = torch.from_numpy(np.ascontiguousarray(srgb, np.float32)).permute(2, 0, 1)[None]
        x = torch.nn.functional.adaptive_avg_pool2d(t, (h, w))[0].permute(1, 2, 0).numpy()
    lo, hi = np.percentile(x, [0.5, 99.5])
    x = np.clip((x - lo) / max(hi - lo, 1e-3), 0, 1)
    # equalised in float: on this project's bunny capture, 0.31-0.35 deg median rotation error in
    # 4 runs vs 0.52-0.56 when the stretched copy was quantised to 8 bits first
    x = equalize_adapthist(x, clip_limit=0.02)
    Image.fromarray((x * 255 + 0.5).astype(np.uint8)).save(path, format="JPEG", quality=95)


def run_sfm(photos: list[PhotoInfo], image_dir: Path, work: Path, threads: int = SFM_THREADS,
            copy_sides: dict[tuple[int, int], int] | None = None) -> Registration:
    """Register ``photos`` whose SfM copies are ``image_dir/<name>.jpg``; COLMAP's files go to ``work``.
    ``copy_sides``: the copies' longest side at most, by photo size (default :data:`SFM_MAX_SIDE`)."""
    import pycolmap

    pycolmap.logging.minloglevel = 3  # fatal only: srvol prints its own progress and one-line errors
    pycolmap.set_random_seed(0)
    db = work / "database.db"
    if db.exists():
        db.unlink()
    eo = pycolmap.FeatureExtractionOptions()
    eo.num_threads = threads
    eo.use_gpu = False
    eo.max_image_size = SFM_MAX_SIDE
    groups: dict[tuple[int, int], list[PhotoInfo]] = {}
    for p in photos:
        groups.setdefault(p.size, []).append(p)
    for (w, h), group in groups.items():
        sw, sh, f = sfm_copy_size(w, h, (copy_sides or {}).get((w, h), SFM_MAX_SIDE))
        params = ""
        if all(p.focal is not None for p in group):
            focal = float(np.median([p.focal.pixels for p in group])) / f
            params = f"{focal},{sw / 2},{sh / 2}"
        else:
            notice(f"no EXIF focal length for {sum(p.focal is None for p in group)} of the {len(group)} "
                   f"photos of size {w}x{h}: structure from motion estimates it")
        # A copy shrunk from a bigger photo holds its detail already: SIFT's first octave (the copy
        # upsampled x2) finds mostly noise there -- SHRUNK_FIRST_OCTAVE
        eo.sift.first_octave = SHRUNK_FIRST_OCTAVE if f > 1 else -1
        ro = pycolmap.ImageReaderOptions(camera_model="SIMPLE_PINHOLE", camera_params=params)
        pycolmap.extract_features(db, image_dir, image_names=[f"{p.name}.jpg" for p in group],
                                  camera_mode=pycolmap.CameraMode.SINGLE, reader_options=ro,
                                  extraction_options=eo, device=pycolmap.Device.cpu)
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = threads
    mo.use_gpu = False
    # Guided matching re-matches each verified pair under its two-view geometry. Without it the
    # 20-photo bunny capture of the tests registered 2 to 20 photos depending on the JPEG quality
    # and CLAHE clip of the SfM copies (6 variants: 2, 2, 13, 20, 5, 20); with it, 20 in all six.
    mo.guided_matching = True
    if len(photos) <= EXHAUSTIVE_MAX:
        pycolmap.match_exhaustive(db, matching_options=mo, device=pycolmap.Device.cpu)
    else:
        po = pycolmap.SequentialPairingOptions()
        po.overlap = 20
        pycolmap.match_sequential(db, matching_options=mo, pairing_options=po, device=pycolmap.Device.cpu)
    models = {}
    for init_inliers, abs_inliers in MAPPER_THRESHOLDS:
        (work / "sparse").mkdir(parents=True, exist_ok=True)
        opts = pycolmap.IncrementalPipelineOptions()
        opts.num_threads = threads
        opts.random_seed = 0
        opts.mapper.init_min_num_inliers = init_inliers
        opts.mapper.abs_pose_min_num_inliers = abs_inliers
        opts.min_num_matches = 10
        tried = pycolmap.incremental_mapping(db, image_dir, work / "sparse", opts)
        if tried and (not models or _most_registered(tried) > _most_registered(models)):
            models = tried
        if models and _most_registered(models) == len(photos):
            break
    if not models:
        raise SrvolError(f"structure from motion registered none of the {len(photos)} photos "
                         f"(too few matching features: more overlap between photos, more texture)")
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    if len(models) > 1 and rec.num_reg_images() < len(photos):
        sizes = sorted((r.num_reg_images() for r in models.values()), reverse=True)
        notice(f"structure from motion made {len(models)} models ({', '.join(map(str, sizes))} photos): "
               f"the largest is kept")
    (work / "sparse" / "largest").mkdir(parents=True, exist_ok=True)
    rec.write(work / "sparse" / "largest")
    return registration_from_reconstruction(rec, [p.name for p in photos], {p.name: p.size for p in photos}, "sfm")


def _most_registered(models: dict) -> int:
    return max(r.num_reg_images() for r in models.values())


def registration_from_reconstruction(rec, names: list[str], sizes: dict[str, tuple[int, int]],
                                     source: str) -> Registration:
    """The cameras of a pycolmap ``Reconstruction`` for the photos ``names`` (matched by file stem),
    scaled to each photo's upright size; models with distortion are read as their pinhole part."""
    cams: dict[str, Camera] = {}
    distorted = set()
    for image in rec.images.values():
        if not image.has_pose:
            continue
        name = Path(image.name).stem
        if name not in sizes:
            continue
        cam = image.camera
        K = np.asarray(cam.calibration_matrix(), np.float64)
        if cam.model.name not in ("SIMPLE_PINHOLE", "PINHOLE"):
            distorted.add(cam.model.name)
        W, H = sizes[name]
        sx, sy = W / cam.width, H / cam.height
        if abs(sx - sy) > 0.01 * max(sx, sy):
            raise SrvolError(f"camera of '{image.name}' is {cam.width}x{cam.height}, the photo {W}x{H}: "
                             f"the aspect ratios differ")
        K[0] *= sx
        K[1] *= sy
        W2C = np.eye(4)
        W2C[:3, :] = np.asarray(image.cam_from_world().matrix(), np.float64)
        cams[name] = Camera(K=torch.from_numpy(K), W2C=torch.from_numpy(W2C), width=W, height=H)
    if distorted:
        notice(f"camera model(s) {', '.join(sorted(distorted))} read without their distortion terms")
    pts = np.array([p.xyz for p in rec.points3D.values()
                    if p.track.length() >= MIN_TRACK and p.error <= MAX_POINT_ERROR_PX], np.float64).reshape(-1, 3)
    unreg = tuple(n for n in names if n not in cams)
    return Registration(cameras={n: cams[n] for n in names if n in cams}, points=pts, unregistered=unreg,
                        source=source)
