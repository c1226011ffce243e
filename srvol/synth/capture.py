"""``srvol synth NAME --capture``: what a phone gives, and the ground truth kept apart.

A capture is a folder of JPEG photos with an EXIF focal length (35 mm equivalent) and nothing
else: no poses, no masks, no scene.json. The photos are taken along a hand-held path around the
object (distance, aim and roll vary from photo to photo), lit by a flash a few centimetres off the
lens, and carry what a phone adds: auto-exposure, vignetting, sensor noise, a weak ambient light
and a dim, non-black backdrop. ``srvol import`` turns the folder into a scene (DESIGN.md section 4).

::

    OUT/photos/IMG_0001.jpg ...       the capture (sRGB JPEG, EXIF FocalLengthIn35mmFilm)
    OUT/gt/photo_cameras.json         the photos' cameras in the GT frame, keyed by file name
    OUT/gt/photo_masks/<stem>.png     the photos' object masks (coverage > 0.5)
    OUT/gt/hr_cameras.json, hr/, normal/, albedo/, relit.json, relit/, mesh.ply
                                      held-out views as in a synthetic scene's gt/ (co-located
                                      flash, black background, no exposure, vignetting or ambient)
    OUT/gt/capture.json               how the photos were made: flash offset, per-photo gains,
                                      vignetting, ambient, noise, backdrop

The GT frame is the built-in scene's frame (object in the unit sphere, +z up). The photos are
rendered with the same exact ray caster and BRDF as ``srvol synth`` (:mod:`srvol.synth.render`).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from srvol.atomic import AtomicFolder, atomic_write_text
from srvol.brdf import shade
from srvol.camera_rig import CAMERA_DISTANCE, RIG_LIGHT_INTENSITY, rig_intrinsics
from srvol.data import camera_to_json
from srvol.errors import SrvolError
from srvol.images import linear_to_srgb, write_exr, write_png
from srvol.psf import DEFAULT_SIGMA_LR_PX, blur_decimate
from srvol.synth.generate import gt_mesh, moved_lights
from srvol.synth.render import render, shadow_visibility
from srvol.synth.scenes import get_scene
from srvol.synth.surfaces import Surface
from srvol.types import Camera, PointLight, Rays

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
"""The diagonal of a 36 x 24 mm frame: the 35 mm-equivalent focal length is f_px * 43.27 / diagonal_px."""


@dataclass(frozen=True)
class CaptureOptions:
    """photos: number of photos; arc_deg: the walk's turn about the object (360: all around; a
    smaller arc keeps a few photos as close together as many around); size: (W, H) of each photo; ss: render factor per photo side (each
    photo is rendered at ss x its size and blurred by the camera's Gaussian PSF of ``psf_sigma``
    photo pixels while decimated); test_views / relit_views / hr_factor: held-out GT views at
    hr_factor x the photo size; fill: the frame height the object's bounding sphere fills at the
    mean distance; distance_jitter: relative spread of the camera distance; aim_jitter: spread of
    the aimed-at point (scene units); roll_deg: spread of the roll; flash_offset: the flash in the
    camera frame (scene units; the object's radius is ~0.8, so 0.12 is ~1.5 cm for a 20 cm
    object); ambient: radiance added per unit albedo; backdrop: the backdrop sphere's radius and
    albedo; vignetting: (k1, k2) of 1 + k1 r^2 + k2 r^4, r = 1 at the corners; exposure_target:
    auto-exposure puts the 99.5th percentile of the object at this linear value; noise: (a, b)
    of the variance a x + b; jpeg_quality: of the written JPEGs."""

    photos: int = 64
    arc_deg: float = 360.0
    size: tuple[int, int] = (320, 240)
    ss: int = 2
    psf_sigma: float = DEFAULT_SIGMA_LR_PX
    test_views: int = 4
    relit_views: int = 3
    hr_factor: int = 2
    fill: float = 0.9
    distance_jitter: float = 0.08
    aim_jitter: float = 0.05
    roll_deg: float = 6.0
    flash_offset: tuple[float, float, float] = (0.12, -0.03, 0.0)
    ambient: float = 0.01
    backdrop_radius: float = 6.0
    backdrop_albedo: float = 0.2
    vignetting: tuple[float, float] = (-0.25, -0.05)
    exposure_target: float = 0.7
    noise: tuple[float, float] = (2e-4, 2e-5)
    jpeg_quality: int = 92
    seed: int = 0
    mesh_resolution: int = 256

    def validate(self) -> None:
        W, H = self.size
        if W < 16 or H < 16:
            raise SrvolError(f"capture photo size {W}x{H}: too small (at least 16x16)")
        if self.photos < 3:
            raise SrvolError(f"capture photos {self.photos}: need at least 3")
        if not 1 <= self.ss <= 8 or not 1 <= self.hr_factor <= 8:
            raise SrvolError("capture ss and hr_factor must be 1..8")
        if not 0 < self.arc_deg <= 360:
            raise SrvolError(f"capture arc {self.arc_deg} deg: must be in (0, 360]")
        if self.test_views < 1:
            raise SrvolError("capture test views must be >= 1")


@dataclass(frozen=True)
class PhotoPose:
    """One hand-held shot: camera (photo size, GT frame) and the flash's position (GT frame)."""

    name: str
    camera: Camera
    flash: np.ndarray  # (3,)


# ----------------------------------------------------------------------------- the path

def capture_intrinsics(opts: CaptureOptions) -> torch.Tensor:
    """(3, 3) intrinsics of the phone: the rig's, with the object's sphere filling ``fill`` of the height."""
    W, H = opts.size
    K = rig_intrinsics(W, H).clone()
    K[0, 0] = K[1, 1] = K[0, 0] * opts.fill / 0.95
    return K


def handheld_cameras(opts: CaptureOptions, n: int, rng: np.random.Generator, phase: float = 0.0) -> list[Camera]:
    """``n`` cameras along a walk around the object: one turn in azimuth, the elevation waving
    between ~5 and ~55 degrees, the distance, the aimed-at point and the roll jittered."""
    W, H = opts.size
    K = capture_intrinsics(opts)
    cams = []
    for k in range(n):
        u = (k + phase) / n
        az = math.radians(opts.arc_deg) * u + rng.normal(0, 0.03)
        el = math.radians(30 + 25 * math.sin(2 * math.pi * 2.5 * u + 0.7 * phase) + rng.normal(0, 2))
        dist = CAMERA_DISTANCE * (1 + opts.distance_jitter * (math.sin(2 * math.pi * 1.5 * u) + rng.normal(0, 0.4)))
        eye = dist * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        target = rng.normal(0, opts.aim_jitter, 3)
        roll = math.radians(float(np.clip(rng.normal(0, opts.roll_deg), -2.5 * opts.roll_deg, 2.5 * opts.roll_deg)))
        cam = Camera.look_at(eye, target, [0, 0, 1], K, W, H)
        c, s = math.cos(roll), math.sin(roll)
        W2C = cam.W2C.clone()
        W2C[:3, :] = torch.tensor([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=torch.float64) @ W2C[:3, :]
        cams.append(Camera(K=cam.K, W2C=W2C, width=W, height=H))
    return cams


def flash_position(camera: Camera, offset) -> np.ndarray:
    """(3,) the flash, ``offset`` away from the lens in the camera frame (x right, y down, z forward)."""
    R = camera.W2C[:3, :3].numpy()
    return camera.center.numpy() + R.T @ np.asarray(offset, np.float64)


# ----------------------------------------------------------------------------- image formation

def backdrop_pattern(q: torch.Tensor) -> torch.Tensor:
    """(N,) relative albedo of the backdrop at unit directions ``q`` (N, 3): a grey photo texture
    (scikit-image's gravel), as a room or a cloth behind an object has one, laid on the six faces
    of a cube, each face a different part of the texture: a repeated pattern would show two
    places of the backdrop as one to SfM, and a spherical mapping pinches at the poles."""
    from srvol.synth.assets import sample_texture, texture

    axis = q.abs().argmax(-1)
    sign = torch.gather(q, 1, axis[:, None])[:, 0] >= 0
    face = 2 * axis + sign.long()  # 0..5
    a = torch.gather(q, 1, ((axis + 1) % 3)[:, None])[:, 0]
    b = torch.gather(q, 1, ((axis + 2) % 3)[:, None])[:, 0]
    m = torch.gather(q.abs(), 1, axis[:, None])[:, 0].clamp_min(1e-9)
    u0 = (face % 3).double() / 3
    v0 = (face // 3).double() / 2
    u = u0 + 0.15 * (a / m + 1)
    v = v0 + 0.15 * (b / m + 1)
    return 0.2 + 1.8 * sample_texture(texture("gravel"), u, v).mean(-1)


def backdrop_radiance(rays: Rays, flash: PointLight, radius: float, albedo: float, ambient: float) -> torch.Tensor:
    """(N, 3) radiance of a Lambertian backdrop sphere of ``radius`` about the origin, seen from inside:
    a faint pattern on a grey albedo, lit by the flash and the ambient light."""
    o, d = rays.origins.double(), rays.directions.double()
    b = (o * d).sum(-1)
    c = (o * o).sum(-1) - radius ** 2
    t = -b + (b * b - c).clamp_min(0).sqrt()
    p = o + t[:, None] * d
    n = -p / radius
    to_l = flash.position.double() - p
    r2 = (to_l * to_l).sum(-1)
    cos = ((to_l / r2.sqrt()[:, None]) * n).sum(-1).clamp_min(0)
    rho = albedo * backdrop_pattern(p / radius)
    E = flash.intensity.double()[None, :] * (cos / r2)[:, None]
    return rho[:, None] * (E / math.pi + ambient)


def capture_radiance(surface: Surface, rays: Rays, flash: PointLight, opts: CaptureOptions) -> tuple[torch.Tensor, torch.Tensor]:
    """(N, 3) radiance and (N,) hit of a photo's rays: the object under the off-lens flash (with the
    shadows the offset casts) plus the ambient light, else the backdrop."""
    out = backdrop_radiance(rays, flash, opts.backdrop_radius, opts.backdrop_albedo, opts.ambient)
    hit = surface.intersect(rays)
    idx = torch.nonzero(hit.hit).squeeze(-1)
    if idx.numel():
        p, n = hit.points[idx], hit.normals[idx]
        mat = surface.material(p)
        light = flash.to("cpu", torch.float64)
        vis = shadow_visibility(surface, p, n, light)
        out[idx] = shade(mat, n, p, -rays.directions[idx].double(), light, vis) + opts.ambient * mat.albedo.double()
    return out, hit.hit


def render_photo_linear(surface: Surface, pose: PhotoPose, intensity: float, opts: CaptureOptions) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) linear radiance of a photo (rendered at ss x, blurred by the PSF, decimated) and its
    (H, W) object coverage."""
    cam = pose.camera.scaled(opts.ss).to("cpu", torch.float64)
    flash = PointLight(torch.as_tensor(pose.flash, dtype=torch.float64), torch.full((3,), float(intensity), dtype=torch.float64))
    rays = cam.rays_at(cam.pixel_centers())
    rgb, hit = [], []
    for s in range(0, len(rays), 1 << 17):
        c, h = capture_radiance(surface, rays[s:s + (1 << 17)], flash, opts)
        rgb.append(c)
        hit.append(h.double())
    H, W = cam.height, cam.width
    hr = torch.cat(rgb).reshape(H, W, 3).float().numpy()
    cov = torch.cat(hit).reshape(H, W).float().numpy()
    return blur_decimate(hr, opts.ss, opts.psf_sigma), blur_decimate(cov, opts.ss, opts.psf_sigma)


def vignetting_map(width: int, height: int, k: tuple[float, float]) -> np.ndarray:
    """(H, W) gain 1 + k1 r^2 + k2 r^4, r the distance from the centre over the half-diagonal."""
    y, x = np.mgrid[0:height, 0:width] + 0.5
    r2 = ((x - width / 2) ** 2 + (y - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
    return (1 + k[0] * r2 + k[1] * r2 * r2).astype(np.float32)


def auto_exposure_gain(linear: np.ndarray, coverage: np.ndarray, target: float) -> float:
    """The gain that puts the 99.5th percentile of the object's luminance at ``target``."""
    lum = linear.mean(-1)[coverage > 0.5]
    top = float(np.percentile(lum, 99.5)) if lum.size else float(linear.max())
    return target / max(top, 1e-6)


def develop(linear: np.ndarray, gain: float, vignette: np.ndarray, noise: tuple[float, float],
            rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8 sRGB photo of linear radiance: exposure gain, vignetting, Poisson-Gaussian
    noise, clipping, sRGB encoding."""
    x = linear * gain * vignette[..., None]
    x = x + rng.normal(0, 1, x.shape) * np.sqrt(noise[0] * np.clip(x, 0, None) + noise[1])
    return (linear_to_srgb(np.clip(x, 0, 1)) * 255 + 0.5).astype(np.uint8)


def write_jpeg_with_focal(path: Path, pixels: np.ndarray, focal_35mm: float, quality: int) -> None:
    """An sRGB JPEG with the EXIF a phone writes: FocalLengthIn35mmFilm (whole mm), make and model."""
    import os

    from PIL import Image

    from srvol.atomic import atomic_path

    exif = Image.Exif()
    exif[0x010F] = "srvol"  # Make
    exif[0x0110] = "synthetic capture"  # Model
    exif[0x0112] = 1  # Orientation: upright
    exif.get_ifd(0x8769)[0xA405] = int(round(focal_35mm))  # FocalLengthIn35mmFilm
    tmp = atomic_path(path)
    try:
        Image.fromarray(pixels).save(tmp, format="JPEG", quality=quality, exif=exif.tobytes())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def focal_35mm(camera: Camera) -> float:
    """The 35 mm-equivalent focal length (mm) of ``camera``: f_px over the diagonal, times 43.27 mm."""
    return float(camera.K[0, 0]) * FULL_FRAME_DIAGONAL_MM / math.hypot(camera.width, camera.height)


# ----------------------------------------------------------------------------- the whole capture

def photo_name(i: int) -> str:
    return f"IMG_{i + 1:04d}"


def synthesize_capture(name: str, out: Path, opts: CaptureOptions | None = None, force: bool = False,
                       progress: bool = True) -> Path:
    """Write the capture of built-in scene ``name`` into ``out`` (photos/ and gt/), atomically."""
    opts = opts or CaptureOptions()
    opts.validate()
    spec = get_scene(name)
    folder = AtomicFolder(out, force=force)
    rng = np.random.default_rng(opts.seed)
    torch.manual_seed(opts.seed)
    surface = spec.make_surface()
    intensity = RIG_LIGHT_INTENSITY
    cams = handheld_cameras(opts, opts.photos, rng)
    poses = [PhotoPose(photo_name(i), c, flash_position(c, opts.flash_offset)) for i, c in enumerate(cams)]
    W, H = opts.size
    vignette = vignetting_map(W, H, opts.vignetting)
    f35 = focal_35mm(cams[0])
    t0 = time.time()
    with folder as tmp:
        photo_cams, gains = {}, {}
        for pose in tqdm(poses, desc=f"capture {name}", unit="photo", disable=not progress):
            linear, cov = render_photo_linear(surface, pose, intensity, opts)
            gain = auto_exposure_gain(linear, cov, opts.exposure_target)
            pixels = develop(linear, gain, vignette, opts.noise, rng)
            write_jpeg_with_focal(tmp / "photos" / f"{pose.name}.jpg", pixels, f35, opts.jpeg_quality)
            write_png(tmp / "gt" / "photo_masks" / f"{pose.name}.png", (cov > 0.5).astype(np.float32), srgb=False)
            photo_cams[f"{pose.name}.jpg"] = camera_to_json(pose.camera)
            gains[pose.name] = gain
        _write_held_out(surface, tmp / "gt", opts, intensity, rng, progress)
        gt = tmp / "gt"
        atomic_write_text(gt / "photo_cameras.json", json.dumps(photo_cams, indent=1))
        gt_mesh(surface, opts.mesh_resolution).export(gt / "mesh.ply")
        atomic_write_text(gt / "capture.json", json.dumps(
            {"scene": name, "options": asdict(opts), "light_intensity": intensity, "focal_35mm": f35,
             "exposure_gains": gains, "flashes": {p.name: p.flash.tolist() for p in poses},
             "seconds": round(time.time() - t0, 2)}, indent=1))
    return out


def _write_held_out(surface: Surface, gt: Path, opts: CaptureOptions, intensity: float,
                    rng: np.random.Generator, progress: bool) -> None:
    """Held-out HR views (co-located flash, black background), normals, albedo, moved-light renders."""
    test_cams = handheld_cameras(opts, opts.test_views, rng, phase=0.5)
    hr_cams, relit = {}, []
    for i, cam in enumerate(tqdm(test_cams, desc="held-out views", unit="view", disable=not progress)):
        stem = f"test_{i:02d}"
        hr = cam.scaled(opts.hr_factor)
        r = render(surface, hr, PointLight.at_camera(hr, (intensity,) * 3), ss=2, shadows=False, maps=True)
        hr_cams[stem] = camera_to_json(hr)
        write_exr(gt / "hr" / f"{stem}.exr", r.rgb)
        write_exr(gt / "normal" / f"{stem}.exr", r.normal)
        write_exr(gt / "albedo" / f"{stem}.exr", r.albedo)
        if i < opts.relit_views:
            flash = PointLight.at_camera(cam, (intensity,) * 3)
            for light in moved_lights(flash, 1, rng, first=i):
                rname = f"{stem}_l{i}"
                rr = render(surface, hr, light, ss=2, shadows=True, maps=False)
                write_exr(gt / "relit" / f"{rname}.exr", rr.rgb)
                relit.append({"name": rname, "camera": stem, "light_pos": light.position.tolist(),
                              "intensity": light.intensity.tolist()})
    atomic_write_text(gt / "hr_cameras.json", json.dumps(hr_cams, indent=1))
    atomic_write_text(gt / "relit.json", json.dumps(relit, indent=1))
