"""``srvol synth``: write a built-in scene in the format of DESIGN.md section 4.

The paper's protocol: render each view at HR (sr x LR) with the co-located
point light, supersampled; blur with the Gaussian PSF; decimate to LR. Test
views also get HR renders, normals, albedo and renders under moved lights
(with shadows), and the scene gets its GT mesh.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from srvol.atomic import AtomicFolder, atomic_write_text
from srvol.camera_rig import CAMERA_DISTANCE, RIG_LIGHT_INTENSITY, rig_camera
from srvol.data import SceneInfo, View, camera_to_json, write_scene_folder
from srvol.images import write_exr
from srvol.psf import blur_decimate
from srvol.synth.options import SynthOptions
from srvol.synth.render import render
from srvol.synth.scenes import get_scene
from srvol.synth.surfaces import MeshSurface, Surface
from srvol.types import Camera, PointLight


def fibonacci_directions(n: int, offset: float) -> np.ndarray:
    """n unit vectors spread evenly over the sphere; ``offset`` in [0, 1) shifts the spiral."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    golden = math.pi * (3 - math.sqrt(5))
    phi = golden * i + 2 * math.pi * offset
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def make_cameras(opts: SynthOptions, n: int, offset: float) -> list[Camera]:
    """``n`` LR cameras of the rig (:mod:`srvol.camera_rig`) spread over the sphere, +z up."""
    W, H = opts.lr
    cams = []
    for d in fibonacci_directions(n, offset):
        d = 0.97 * d + 0.03 * np.array([0, 0, 1.0])  # keep off the exact poles
        d /= np.linalg.norm(d)
        cams.append(aim_camera(rig_camera(d, W, H, distance=CAMERA_DISTANCE / opts.zoom), opts.aim))
    return cams


def aim_camera(cam: Camera, aim: tuple[float, float]) -> Camera:
    """``cam`` turned about its centre so that the point on its optical axis shows at ``aim``
    (fractions of the half-width and half-height from the image centre, x right, y down)."""
    if aim == (0.0, 0.0):
        return cam
    q = torch.tensor([aim[0] * cam.width / 2 / cam.K[0, 0].item(), aim[1] * cam.height / 2 / cam.K[1, 1].item(),
                      1.0], dtype=torch.float64)
    q = q / q.norm()
    # the rotation taking the optical axis z onto q (Rodrigues, axis z x q)
    v = torch.linalg.cross(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), q)
    vx = torch.tensor([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]], dtype=torch.float64)
    turn = torch.eye(3, dtype=torch.float64) + vx + vx @ vx / (1 + q[2])
    W2C = cam.W2C.clone()
    W2C[:3, :3] = turn @ cam.W2C[:3, :3]
    W2C[:3, 3] = -W2C[:3, :3] @ cam.center.double()
    return Camera(K=cam.K, W2C=W2C, width=cam.width, height=cam.height)


def flash_intensity(opts: SynthOptions) -> float:
    """The co-located light's intensity: the default's times the exposure, over zoom^2 (the
    irradiance on the object does not depend on the zoom)."""
    return RIG_LIGHT_INTENSITY * opts.exposure / opts.zoom ** 2


def moved_lights(flash: PointLight, count: int, rng: np.random.Generator, first: int = 0) -> list[PointLight]:
    """Lights away from a view's ``flash`` (its co-located light): the flash's position rotated about
    the vertical axis by 40-80 deg, raised or lowered, moved to distance 2.2 from the origin, and its
    intensity scaled by (2.2 / flash distance)^2 so that the object receives about the same irradiance.

    Pattern k alternates the side (k even: left, odd: right) and lifts every third light above.
    """
    c = flash.position.numpy()
    out = []
    for k in range(first, first + count):
        ang = math.radians((40 + 40 * rng.random()) * (1 if k % 2 == 0 else -1))
        rot = np.array([[math.cos(ang), -math.sin(ang), 0], [math.sin(ang), math.cos(ang), 0], [0, 0, 1]])
        p = rot @ c
        p[2] += (0.8 if k % 3 == 2 else -0.4) * (1 + 0.2 * rng.random())
        p = p / np.linalg.norm(p) * 2.2
        scale = (2.2 / float(np.linalg.norm(c))) ** 2
        out.append(PointLight.make(p.tolist(), (flash.intensity * scale).tolist()))
    return out


def gt_mesh(surface: Surface, resolution: int = 256):
    """The GT surface as a triangle mesh (marching cubes of the analytic SDF, or the mesh itself).

    The grid has the spacing of ``resolution`` samples across [-1, 1] but covers only the
    surface's bounding sphere, and is evaluated one x-slab at a time (no full-size point array).
    """
    import trimesh
    from skimage.measure import marching_cubes

    if isinstance(surface, MeshSurface):
        return surface.mesh
    step = 2.0 / (resolution - 1)
    half = min(surface.bound + 2 * step, 1.0)
    lin = torch.arange(-half, half + 0.5 * step, step, dtype=torch.float64)
    n = len(lin)
    Y, Z = torch.meshgrid(lin, lin, indexing="ij")
    yz = torch.stack([Y.reshape(-1), Z.reshape(-1)], -1)
    vol = np.empty((n, n, n), dtype=np.float32)
    for i in range(n):
        pts = torch.cat([lin[i].expand(n * n, 1), yz], -1)
        vol[i] = surface.sdf(pts).reshape(n, n).numpy()
    v, f, _, _ = marching_cubes(vol, level=0.0, spacing=(step,) * 3)
    v = v + lin[0].item()
    # skimage's default winding faces away from the negative (inside) values: outward normals
    return trimesh.Trimesh(vertices=v, faces=f, process=True)


def synthesize(name: str, out: Path, opts: SynthOptions | None = None, force: bool = False,
               progress: bool = True) -> Path:
    """Write built-in scene ``name`` into ``out`` (atomically) and return its path; ``opts``
    defaults to the scene's own (``SCENES[name].synth``)."""
    spec = get_scene(name)
    opts = opts or spec.synth
    opts.validate()
    folder = AtomicFolder(out, force=force)  # refuses an existing --out before any work
    torch.manual_seed(opts.seed)
    rng = np.random.default_rng(opts.seed)
    surface = spec.make_surface()
    train_cams = make_cameras(opts, opts.views, offset=0.0)
    test_cams = make_cameras(opts, opts.test_views, offset=0.37)
    names_train = [f"{i:03d}" for i in range(opts.views)]
    names_test = [f"{opts.views + i:03d}" for i in range(opts.test_views)]
    intensity = (flash_intensity(opts),) * 3  # the flash of every view; moved lights derive theirs from it
    info = SceneInfo(color_space="linear", light_intensity=intensity, psf_sigma_lr_px=opts.psf_sigma,
                     sr_factor=opts.sr, train=tuple(names_train), test=tuple(names_test))
    t0 = time.time()
    with folder as tmp:
        views: list[View] = []
        hr_cams = {}
        jobs = list(zip(names_train + names_test, train_cams + test_cams))
        bar = tqdm(jobs, desc=f"synth {name}", unit="view", disable=not progress)
        for stem, cam in bar:
            hr_cam = cam.scaled(opts.sr)
            light = PointLight.at_camera(cam, intensity)
            is_test = stem in names_test
            # Training views are blurred by the PSF (sigma_hr = 1.5 px at x4), so one ray per
            # HR pixel suffices there; test views are GT and get ss x ss sub-pixel rays.
            r = render(surface, hr_cam, light, ss=opts.ss if is_test else 1, shadows=False, maps=is_test)
            lr = blur_decimate(r.rgb, opts.sr, opts.psf_sigma)
            cov = blur_decimate(r.coverage, opts.sr, opts.psf_sigma)
            views.append(View(name=stem, camera=cam, image=lr, mask=cov > 0.5))
            if is_test:
                hr_cams[stem] = camera_to_json(hr_cam)
                write_exr(tmp / "gt" / "hr" / f"{stem}.exr", r.rgb)
                write_exr(tmp / "gt" / "normal" / f"{stem}.exr", r.normal)
                write_exr(tmp / "gt" / "albedo" / f"{stem}.exr", r.albedo)
        relit = []
        for i, (stem, cam) in enumerate(list(zip(names_test, test_cams))[: opts.relit_views]):
            flash = PointLight.at_camera(cam, intensity)
            for k, light in enumerate(moved_lights(flash, opts.lights_per_view, rng, first=i)):
                rname = f"{stem}_l{i + k}"
                r = render(surface, cam.scaled(opts.sr), light, ss=opts.ss, shadows=True, maps=False)
                write_exr(tmp / "gt" / "relit" / f"{rname}.exr", r.rgb)
                relit.append({"name": rname, "camera": stem, "light_pos": light.position.tolist(),
                              "intensity": light.intensity.tolist()})
        write_scene_folder(tmp, views, info)
        atomic_write_text(tmp / "gt" / "hr_cameras.json", json.dumps(hr_cams, indent=1))
        atomic_write_text(tmp / "gt" / "relit.json", json.dumps(relit, indent=1))
        gt_mesh(surface, opts.mesh_resolution).export(tmp / "gt" / "mesh.ply")
        atomic_write_text(tmp / "gt" / "synth.json", json.dumps(
            {"scene": name, "options": {**opts.__dict__, "lr": list(opts.lr)},
             "seconds": round(time.time() - t0, 2)}, indent=1))
    return out
