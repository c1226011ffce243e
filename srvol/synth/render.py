"""Ground-truth image formation: supersampled ray casting + the one BRDF + shadows."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from srvol.brdf import shade
from srvol.psf import box_offsets
from srvol.synth.surfaces import Hit, Surface
from srvol.types import Camera, PointLight, Rays

CHUNK = 1 << 17


@dataclass(frozen=True)
class GTRender:
    """rgb (H, W, 3) linear radiance, coverage (H, W) in [0, 1], and at the pixel
    centre: normal (H, W, 3) world-space unit (zero outside), albedo (H, W, 3)."""

    rgb: np.ndarray
    coverage: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray


def shadow_visibility(surface: Surface, points: torch.Tensor, normals: torch.Tensor,
                      light: PointLight) -> torch.Tensor:
    """(N,) 1 where the segment from each surface point to the light is free, else 0."""
    to_light = light.position.double() - points
    dist = to_light.norm(dim=-1)
    dirs = to_light / dist[:, None].clamp_min(1e-12)
    origins = points + 2e-4 * normals + 1e-4 * dirs
    occ = surface.intersect(Rays(origins, dirs), t_max=dist - 2e-4)
    return (~occ.hit).double()


def radiance(surface: Surface, rays: Rays, light: PointLight, shadows: bool) -> tuple[torch.Tensor, Hit]:
    """(N, 3) radiance along rays (0 where they miss) and the hits."""
    out = torch.zeros(len(rays), 3, dtype=torch.float64)
    hit = surface.intersect(rays)
    idx = torch.nonzero(hit.hit).squeeze(-1)
    if idx.numel():
        p, n = hit.points[idx], hit.normals[idx]
        mat = surface.material(p)
        vis = shadow_visibility(surface, p, n, light) if shadows else None
        out[idx] = shade(mat, n, p, -rays.directions[idx].double(), light.to("cpu", torch.float64), vis)
    return out, hit


def render(surface: Surface, camera: Camera, light: PointLight, ss: int = 2, shadows: bool = False,
           maps: bool = True) -> GTRender:
    """Render ``camera``'s image: each pixel the mean of an ss x ss grid of sub-pixel rays.

    ``maps``: also trace the pixel centres for the normal and albedo maps (else they are zero).
    """
    cam = camera.to("cpu", torch.float64)
    H, W = cam.height, cam.width
    centers = cam.pixel_centers()
    offsets = box_offsets(ss).double()
    rgb = torch.zeros(H * W, 3, dtype=torch.float64)
    cov = torch.zeros(H * W, dtype=torch.float64)
    for off in offsets:
        for s in range(0, H * W, CHUNK):
            rays = cam.rays_at(centers[s:s + CHUNK] + off)
            c, hit = radiance(surface, rays, light, shadows)
            rgb[s:s + CHUNK] += c
            cov[s:s + CHUNK] += hit.hit.double()
    rgb /= len(offsets)
    cov /= len(offsets)
    normal = torch.zeros(H * W, 3, dtype=torch.float64)
    albedo = torch.zeros(H * W, 3, dtype=torch.float64)
    for s in range(0, H * W if maps else 0, CHUNK):
        hit = surface.intersect(cam.rays_at(centers[s:s + CHUNK]))
        idx = torch.nonzero(hit.hit).squeeze(-1)
        if idx.numel():
            normal[s + idx] = hit.normals[idx]
            albedo[s + idx] = surface.material(hit.points[idx]).albedo.double()
    return GTRender(rgb=rgb.reshape(H, W, 3).float().numpy(), coverage=cov.reshape(H, W).float().numpy(),
                    normal=normal.reshape(H, W, 3).float().numpy(), albedo=albedo.reshape(H, W, 3).float().numpy())
