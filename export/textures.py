"""Texture files written beside the formats: lossless float EXRs (raw/) and PNGs (textures/).

PNG encodings (declared here, read by every writer):

* albedo.png            8-bit sRGB RGB (linear albedo encoded to sRGB)
* roughness.png         16-bit grey, linear, perceptual roughness r = sqrt(alpha)
* specular.png          16-bit grey, linear, F0
* metallic_roughness.png 8-bit RGB, linear: R = 0, G = r, B = 0 (glTF metallic 0)
* specular_color.png    8-bit sRGB RGB, F0 / f0_ref (glTF KHR_materials_specular colour)
* normal.png            8-bit RGB, linear, tangent-space n * 0.5 + 0.5 (optional)
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from srvol.export.types import TextureSet
from srvol.atomic import atomic_path
from srvol.images import write_exr, write_png


@dataclass(frozen=True)
class TextureFiles:
    """Paths relative to the asset folder."""

    albedo_exr: str = "raw/albedo.exr"
    specular_exr: str = "raw/specular.exr"
    alpha_exr: str = "raw/alpha.exr"
    roughness_exr: str = "raw/roughness.exr"
    normal_exr: str | None = None
    albedo_png: str = "textures/albedo.png"
    roughness_png: str = "textures/roughness.png"
    specular_png: str = "textures/specular.png"
    metallic_roughness_png: str = "textures/metallic_roughness.png"
    specular_color_png: str = "textures/specular_color.png"
    normal_png: str | None = None


def specular_reference(textures: TextureSet) -> float:
    """F0 that specular_color.png's white stands for: the map's maximum (at least 0.04)."""
    return float(max(np.max(textures.specular), 0.04))


def ior_from_f0(f0: float) -> float:
    """Index of refraction whose normal-incidence Fresnel reflectance is ``f0``."""
    s = math.sqrt(min(max(f0, 1e-6), 0.99))
    return (1.0 + s) / (1.0 - s)


def write_png16(path: Path, image: np.ndarray) -> None:
    """A (H, W) or (H, W, 1) linear float in [0, 1] as a 16-bit greyscale PNG."""
    from PIL import Image

    img = np.clip(np.asarray(image, dtype=np.float32).reshape(image.shape[0], image.shape[1]), 0, 1)
    tmp = atomic_path(path)
    try:
        Image.fromarray((img * 65535.0 + 0.5).astype(np.uint16)).save(tmp, format="PNG", compress_level=3)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_textures(root: Path, textures: TextureSet) -> TextureFiles:
    """Write the EXRs and PNGs of ``textures`` under ``root``."""
    has_normal = textures.normal is not None
    files = TextureFiles(normal_exr="raw/normal.exr" if has_normal else None,
                         normal_png="textures/normal.png" if has_normal else None)
    (root / "raw").mkdir(parents=True, exist_ok=True)
    (root / "textures").mkdir(parents=True, exist_ok=True)
    r = textures.roughness
    mr = np.concatenate([np.zeros_like(r), r, np.zeros_like(r)], -1)
    sc = np.repeat(textures.specular / specular_reference(textures), 3, axis=-1)
    jobs = [(write_exr, root / files.albedo_exr, textures.albedo),
            (write_exr, root / files.specular_exr, textures.specular),
            (write_exr, root / files.alpha_exr, textures.alpha),
            (write_exr, root / files.roughness_exr, r),
            (lambda p, x: write_png(p, x, srgb=True), root / files.albedo_png, textures.albedo),
            (write_png16, root / files.roughness_png, r),
            (write_png16, root / files.specular_png, textures.specular),
            (lambda p, x: write_png(p, x, srgb=False), root / files.metallic_roughness_png, mr),
            (lambda p, x: write_png(p, x, srgb=True), root / files.specular_color_png, sc)]
    if has_normal:
        jobs += [(write_exr, root / files.normal_exr, textures.normal),
                 (lambda p, x: write_png(p, x, srgb=False), root / files.normal_png, textures.normal * 0.5 + 0.5)]
    # zlib and OpenEXR release the GIL: writing the files in threads uses every core.
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        for fut in [pool.submit(fn, path, img) for fn, path, img in jobs]:
            fut.result()
    return files
