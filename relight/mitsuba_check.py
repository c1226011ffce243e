"""Independent check of the asset path: render the same asset with Mitsuba 3 and compare.

Mitsuba (``scalar_rgb``) sees the asset's mesh (positions, shading normals, UVs) and its
linear float textures, a ``point`` emitter and a ``perspective`` sensor; the ``direct``
integrator with one emitter sample gives the single-bounce image srvol's renderer computes
(point lights need no Monte Carlo: the only noise is the pixel footprint, averaged by a box
filter over ``spp`` stratified samples, which srvol matches with ss x ss sub-pixel rays).

**BSDF mapping.** srvol's BRDF is ``rho/pi + D G F / (4 (n.l)(n.v))`` with GGX D, separable
Smith G (GGX G1) and Schlick F = F0 + (1 - F0)(1 - v.h)^5. In Mitsuba:

* ``diffuse`` (reflectance = rho) is exactly ``rho / pi``;
* ``roughconductor`` with ``distribution = ggx``, ``alpha`` = our GGX alpha (not r), and
  ``material = none`` (a perfect mirror Fresnel, F = 1) scaled by ``specular_reflectance`` =
  F0 is ``D G F0 / (4 (n.l)(n.v))`` -- Mitsuba's GGX D and its G = G1(wi) G1(wo) with
  ``G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2))`` are the same functions as ours;
* the sum is a ``blendbsdf`` with weight 0.5 of the two, each given twice its value (2 rho and
  2 F0; textures are passed ``raw`` so values above 1 are not clipped).

The one term Mitsuba's BSDFs cannot express is Schlick's angular rise: ours adds
``(1 - F0)(1 - v.h)^5`` to F0. For an angle g between light and view at the surface
v.h = cos(g / 2): at g = 60 deg the term is 4e-5 (0.1 % of F0 = 0.04), at 90 deg 0.002 (5 %),
at 120 deg 0.03. The check therefore uses lights within ~90 deg of the camera direction and
reports the PSNR it measures; a dielectric Fresnel (``eta`` from F0) would be further from
Schlick than F = F0 in that range.

**Units.** Mitsuba's point ``intensity`` is radiant intensity (W/sr), as srvol's; radiance
comes out in the same linear units.

**Camera.** OpenCV camera space (x right, y down, z forward) is Mitsuba's (x left, y up,
z forward) turned by 180 deg about z: ``to_world = C2W @ diag(-1, -1, 1, 1)``; the vertical
field of view comes from f_y. Only centred principal points, square pixels and zero skew are
mapped (a SrvolError says so otherwise).

**UVs.** Mitsuba reads a bitmap with row 0 at v = 0; srvol's UVs have v up (texel row =
(1 - v) H), so the mesh is handed v' = 1 - v.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from srvol.errors import SrvolError
from srvol.export.types import Asset
from srvol.metrics import psnr
from srvol.relight.render import render_asset
from srvol.types import Camera, PointLight

VARIANT = "scalar_rgb"


def import_mitsuba():
    """Mitsuba 3 in the scalar_rgb variant, or a one-line SrvolError."""
    try:
        import mitsuba as mi
    except ImportError as e:
        raise SrvolError(f"the Mitsuba check needs the 'mitsuba' package ({e})") from None
    mi.set_variant(VARIANT)
    return mi


@dataclass(frozen=True)
class MitsubaCheck:
    """srvol's and Mitsuba's renders (H, W, 3) linear, their PSNR (dB, peak 1) and seconds each."""

    srvol_rgb: np.ndarray
    mitsuba_rgb: np.ndarray
    psnr: float
    srvol_seconds: float
    mitsuba_seconds: float


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, uv: np.ndarray) -> None:
    """A binary little-endian PLY with x y z nx ny nz u v per vertex (Mitsuba's PLY reader)."""
    n, f = len(vertices), len(faces)
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float nx\nproperty float ny\nproperty float nz\nproperty float u\nproperty float v\n"
              f"element face {f}\nproperty list uchar int vertex_indices\nend_header\n")
    vert = np.concatenate([vertices, normals, uv], axis=1).astype("<f4")
    face = np.zeros(f, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"] = 3
    face["i"] = faces
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vert.tobytes())
        fh.write(face.tobytes())


def _sensor(camera: Camera, spp: int) -> dict:
    mi = import_mitsuba()
    K = camera.K.double().numpy()
    W, H = camera.width, camera.height
    if abs(K[0, 2] - W / 2) > 1e-3 * W or abs(K[1, 2] - H / 2) > 1e-3 * H or abs(K[0, 1]) > 1e-9 \
            or abs(K[0, 0] - K[1, 1]) > 1e-6 * K[0, 0]:
        raise SrvolError("Mitsuba check: only cameras with a centred principal point, fx = fy and no skew")
    c2w = np.linalg.inv(camera.W2C.double().numpy()) @ np.diag([-1.0, -1.0, 1.0, 1.0])
    fov_y = math.degrees(2 * math.atan(H / 2 / K[1, 1]))
    return {"type": "perspective", "fov": fov_y, "fov_axis": "y", "near_clip": 1e-3, "far_clip": 100.0,
            "to_world": mi.ScalarTransform4f(c2w.tolist()),
            "film": {"type": "hdrfilm", "width": W, "height": H, "pixel_format": "rgb",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "stratified", "sample_count": spp, "jitter": True}}


def _bitmap(mi, image: np.ndarray) -> dict:
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    return {"type": "bitmap", "bitmap": mi.Bitmap(img), "raw": True, "filter_type": "bilinear",
            "wrap_mode": "clamp"}


def mitsuba_render(asset: Asset, camera: Camera, light: PointLight, spp: int = 64) -> np.ndarray:
    """(H, W, 3) linear radiance of ``asset`` under ``light`` rendered by Mitsuba 3 (no shadows off: Mitsuba always shadows)."""
    mi = import_mitsuba()
    m, t = asset.mesh, asset.textures
    if m.uv is None:
        raise SrvolError("Mitsuba check: the asset's mesh has no UVs")
    normals = m.normals
    if normals is None:
        import trimesh
        normals = np.asarray(trimesh.Trimesh(m.vertices, m.faces, process=False).vertex_normals, np.float32)
    uv = np.stack([m.uv[:, 0], 1.0 - m.uv[:, 1]], axis=1)
    bsdf = {"type": "blendbsdf", "weight": 0.5,
            "diffuse": {"type": "diffuse", "reflectance": _bitmap(mi, 2.0 * t.albedo[..., :3])},
            "specular": {"type": "roughconductor", "distribution": "ggx", "material": "none",
                         "alpha": _bitmap(mi, np.clip(t.alpha[..., :1], 1e-3, 1.0)),
                         "specular_reflectance": _bitmap(mi, 2.0 * t.specular[..., :1])}}
    with tempfile.TemporaryDirectory(prefix="srvol-mitsuba-") as tmp:
        ply = Path(tmp) / "asset.ply"
        write_ply(ply, m.vertices, m.faces, normals, uv)
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
            "sensor": _sensor(camera, spp),
            "light": {"type": "point", "position": [float(x) for x in light.position.tolist()],
                      "intensity": {"type": "rgb", "value": [float(x) for x in light.intensity.tolist()]}},
            "asset": {"type": "ply", "filename": str(ply), "face_normals": False, "bsdf": bsdf},
        })
        image = mi.render(scene, spp=spp)
    return np.asarray(image, dtype=np.float32)[..., :3]


def check_asset(asset: Asset, camera: Camera, light: PointLight, spp: int = 64, ss: int = 4) -> MitsubaCheck:
    """Render ``asset`` with srvol (ss x ss rays per pixel, shadows) and with Mitsuba; PSNR between them."""
    t0 = time.perf_counter()
    ours = render_asset(asset, camera, light, shadows=True, ss=ss).rgb
    t1 = time.perf_counter()
    theirs = mitsuba_render(asset, camera, light, spp)
    t2 = time.perf_counter()
    return MitsubaCheck(srvol_rgb=ours, mitsuba_rgb=theirs, psnr=psnr(ours, theirs),
                        srvol_seconds=t1 - t0, mitsuba_seconds=t2 - t1)
