"""Exact fields for the export tests: a sphere and a material known in closed form."""
from __future__ import annotations

import torch

from srvol.types import SurfaceMaterial

RADIUS = 0.5


def sphere_sdf(x: torch.Tensor) -> torch.Tensor:
    return x.norm(dim=-1) - RADIUS


def colour_material(x: torch.Tensor) -> SurfaceMaterial:
    """albedo = 0.5 + 0.4 x / R (a colour ramp along each axis), F0 = 0.04 + 0.1 (z/R + 1)/2,
    alpha = 0.09 + 0.3 (x/R + 1)/2: every texel's expected value is known in closed form."""
    u = x / RADIUS
    albedo = (0.5 + 0.4 * u).clamp(0.0, 1.0)
    spec = 0.04 + 0.05 * (u[:, 2:3] + 1.0)
    alpha = 0.09 + 0.15 * (u[:, 0:1] + 1.0)
    return SurfaceMaterial(albedo=albedo, specular=spec, alpha=alpha)
