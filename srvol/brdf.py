"""The one BRDF of srvol, and shading under a point light.

Used by training (co-located light), synthesis, relighting and export checks.

    f(l, v) = rho / pi + D(h; alpha) G(l, v; alpha) F(v.h) / (4 (n.l)(n.v))

* D: GGX / Trowbridge-Reitz, ``alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)``.
* G: separable Smith, ``G1(n.l) G1(n.v)`` with the GGX ``G1(c) = 2c / (c + sqrt(alpha^2 + (1 - alpha^2) c^2))``.
* F: Schlick, ``F0 + (1 - F0)(1 - v.h)^5``.

A co-located light is the case l = v (h = v, F = F0); there is no second code
path for it.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from srvol.types import PointLight, SurfaceMaterial

_EPS = 1e-7


def _dot(a: Tensor, b: Tensor) -> Tensor:
    return (a * b).sum(dim=-1, keepdim=True)


def ggx_d(n_dot_h: Tensor, alpha: Tensor) -> Tensor:
    a2 = alpha * alpha
    denom = n_dot_h * n_dot_h * (a2 - 1.0) + 1.0
    return a2 / (math.pi * denom * denom).clamp_min(_EPS)


def smith_g1(n_dot_x: Tensor, alpha: Tensor) -> Tensor:
    a2 = alpha * alpha
    c = n_dot_x.clamp_min(0.0)
    return 2.0 * c / (c + torch.sqrt(a2 + (1.0 - a2) * c * c)).clamp_min(_EPS)


def schlick_f(v_dot_h: Tensor, f0: Tensor) -> Tensor:
    return f0 + (1.0 - f0) * (1.0 - v_dot_h.clamp(0.0, 1.0)) ** 5


def brdf_diffuse(material: SurfaceMaterial) -> Tensor:
    """(N, 3) Lambertian lobe rho / pi."""
    return material.albedo / math.pi


def brdf_specular(material: SurfaceMaterial, normal: Tensor, light_dir: Tensor, view_dir: Tensor) -> Tensor:
    """(N, 1) microfacet lobe D G F / (4 (n.l)(n.v)); zero below either horizon."""
    h = light_dir + view_dir
    h = h / h.norm(dim=-1, keepdim=True).clamp_min(_EPS)
    n_l = _dot(normal, light_dir)
    n_v = _dot(normal, view_dir)
    n_h = _dot(normal, h).clamp_min(0.0)
    v_h = _dot(view_dir, h)
    D = ggx_d(n_h, material.alpha)
    G = smith_g1(n_l, material.alpha) * smith_g1(n_v, material.alpha)
    F = schlick_f(v_h, material.specular)
    above = (n_l > 0) & (n_v > 0)
    spec = D * G * F / (4.0 * n_l.clamp_min(_EPS) * n_v.clamp_min(_EPS))
    return torch.where(above, spec, torch.zeros_like(spec))


def brdf(material: SurfaceMaterial, normal: Tensor, light_dir: Tensor, view_dir: Tensor) -> Tensor:
    """(N, 3) BRDF value f(l, v) at N points. All directions unit length, (N, 3)."""
    return brdf_diffuse(material) + brdf_specular(material, normal, light_dir, view_dir)


def shade(material: SurfaceMaterial, normal: Tensor, points: Tensor, view_dir: Tensor,
          light: PointLight, visibility: Tensor | None = None) -> Tensor:
    """(N, 3) outgoing linear radiance towards ``view_dir`` under a point light.

    ``L = f(l, v) * I * max(0, n.l) / r^2 * visibility``; ``visibility`` (N,)
    in [0, 1] comes from a shadow test (1 = lit; None = no shadows).
    """
    to_light = light.position.to(points) - points
    r2 = (to_light * to_light).sum(dim=-1, keepdim=True).clamp_min(_EPS)
    light_dir = to_light * torch.rsqrt(r2)
    cos = _dot(normal, light_dir).clamp_min(0.0)
    radiance = brdf(material, normal, light_dir, view_dir) * light.intensity.to(points) * cos / r2
    if visibility is not None:
        radiance = radiance * visibility[:, None]
    return radiance
