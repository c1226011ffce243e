"""The one BRDF as worked examples: closed forms, symmetries, energy, gradients, shading."""
from __future__ import annotations

import math

import pytest
import torch

from srvol.brdf import brdf, brdf_specular, ggx_d, shade
from srvol.types import PointLight, SurfaceMaterial

torch.set_default_dtype(torch.float32)

NORMAL_Z = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)


def material(n: int, albedo=(0.6, 0.5, 0.4), specular=0.04, alpha=0.2) -> SurfaceMaterial:
    return SurfaceMaterial.constant(n, albedo=albedo, specular=specular, alpha=alpha, dtype=torch.float64)


def upper_hemisphere(n: int, gen: torch.Generator, min_cos: float = 0.05) -> torch.Tensor:
    """(n, 3) random unit vectors with z >= min_cos."""
    out = torch.randn(4 * n, 3, generator=gen, dtype=torch.float64)
    out = out / out.norm(dim=-1, keepdim=True)
    out[:, 2] = out[:, 2].abs()
    return out[out[:, 2] >= min_cos][:n]


def direction(theta_deg: float, phi_deg: float = 0.0) -> torch.Tensor:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return torch.tensor([[math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]], dtype=torch.float64)


# ----------------------------------------------------------------------------- symmetry and closed forms

def test_reciprocity_at_random_directions():
    gen = torch.Generator().manual_seed(1)
    n = 200
    l, v = upper_hemisphere(n, gen), upper_hemisphere(n, gen)
    normal = NORMAL_Z.expand(n, 3)
    mat = SurfaceMaterial(albedo=torch.rand(n, 3, generator=gen, dtype=torch.float64),
                          specular=torch.rand(n, 1, generator=gen, dtype=torch.float64),
                          alpha=0.05 + 0.95 * torch.rand(n, 1, generator=gen, dtype=torch.float64))
    torch.testing.assert_close(brdf(mat, normal, l, v), brdf(mat, normal, v, l), rtol=1e-10, atol=0)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0, 85.0])
@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.7])
def test_colocated_closed_form(theta_deg, alpha):
    # l = v, so h = v, v.h = 1 and Schlick's F is exactly F0:
    #   f = rho/pi + D(n.v) G1(n.v)^2 F0 / (4 (n.v)^2)
    # with D(c) = a^2 / (pi (c^2 (a^2 - 1) + 1)^2) and G1(c) = 2c / (c + sqrt(a^2 + (1 - a^2) c^2)).
    rho, f0 = torch.tensor([0.6, 0.5, 0.4], dtype=torch.float64), 0.04
    v = direction(theta_deg, 40.0)
    c = math.cos(math.radians(theta_deg))
    a2 = alpha * alpha
    D = a2 / (math.pi * (c * c * (a2 - 1) + 1) ** 2)
    G1 = 2 * c / (c + math.sqrt(a2 + (1 - a2) * c * c))
    expected = rho / math.pi + D * G1 * G1 * f0 / (4 * c * c)
    got = brdf(material(1, specular=f0, alpha=alpha), NORMAL_Z, v, v)[0]
    torch.testing.assert_close(got, expected, rtol=1e-9, atol=0)


def test_colocated_normal_incidence_numbers():
    # n = v = l, alpha = 0.2, F0 = 0.04: D = 1/(pi a^2) = 7.9577, G = 1, spec = D F0 / 4 = 1/(4 pi).
    got = brdf(material(1, albedo=(0.0, 0.0, 0.0), specular=0.04, alpha=0.2), NORMAL_Z, NORMAL_Z, NORMAL_Z)
    torch.testing.assert_close(got, torch.full((1, 3), 1 / (4 * math.pi), dtype=torch.float64), rtol=1e-9, atol=0)


def test_schlick_fresnel_rises_to_one_at_grazing_half_angle():
    # l and v 89 deg either side of n: v.h = cos(89 deg), F ~ F0 + (1 - F0)(1 - 0.01745)^5 ~ 0.917 for F0 = 0
    l, v = direction(89.0, 0.0), direction(89.0, 180.0)
    n = NORMAL_Z
    mat0 = material(1, albedo=(0, 0, 0), specular=0.0, alpha=0.5)
    mat1 = material(1, albedo=(0, 0, 0), specular=1.0, alpha=0.5)
    ratio = (brdf_specular(mat0, n, l, v) / brdf_specular(mat1, n, l, v)).item()
    assert ratio == pytest.approx((1 - math.cos(math.radians(89.0))) ** 5, rel=1e-9)


# ----------------------------------------------------------------------------- energy

def half_vector_quadrature(n_theta: int = 1200, n_phi: int = 256) -> tuple[torch.Tensor, torch.Tensor]:
    """Midpoint rule over the hemisphere of half vectors: (M, 3) directions and (M,) solid angles."""
    th = (torch.arange(n_theta, dtype=torch.float64) + 0.5) * (math.pi / 2) / n_theta
    ph = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * 2 * math.pi / n_phi
    T, P = torch.meshgrid(th, ph, indexing="ij")
    h = torch.stack([T.sin() * P.cos(), T.sin() * P.sin(), T.cos()], -1).reshape(-1, 3)
    dw = (T.sin() * (math.pi / 2 / n_theta) * (2 * math.pi / n_phi)).reshape(-1)
    return h, dw


def test_ggx_d_is_normalised_projected_area():
    # integral of D(h) (n.h) over the hemisphere of h = 1 for every alpha
    h, dw = half_vector_quadrature()
    for alpha in (0.05, 0.3, 1.0):
        D = ggx_d(h[:, 2:3], torch.tensor(alpha, dtype=torch.float64))[:, 0]
        assert (D * h[:, 2] * dw).sum().item() == pytest.approx(1.0, abs=2e-3)


def test_diffuse_directional_albedo_is_one_for_white():
    # integral of (1/pi) cos(theta) over the hemisphere = 1: rho = 1 reflects all the light.
    n_theta, n_phi = 400, 64
    th = (torch.arange(n_theta, dtype=torch.float64) + 0.5) * (math.pi / 2) / n_theta
    ph = (torch.arange(n_phi, dtype=torch.float64) + 0.5) * 2 * math.pi / n_phi
    T, P = torch.meshgrid(th, ph, indexing="ij")
    l = torch.stack([T.sin() * P.cos(), T.sin() * P.sin(), T.cos()], -1).reshape(-1, 3)
    dw = (T.sin() * (math.pi / 2 / n_theta) * (2 * math.pi / n_phi)).reshape(-1)
    m = l.shape[0]
    for theta_v in (0.0, 45.0, 80.0):
        v = direction(theta_v).expand(m, 3)
        mat = material(m, albedo=(1.0, 1.0, 1.0), specular=0.0, alpha=1.0)
        f = brdf(mat, NORMAL_Z.expand(m, 3), l, v) - brdf_specular(mat, NORMAL_Z.expand(m, 3), l, v)
        albedo = (f[:, 0] * l[:, 2] * dw).sum().item()
        assert albedo == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.5, 1.0])
@pytest.mark.parametrize("theta_v", [0.0, 45.0, 75.0])
def test_specular_directional_albedo_at_most_one(alpha, theta_v):
    # E(v) = integral f_spec(l, v) (n.l) dw_l with F0 = 1 (F = 1 everywhere), computed over half
    # vectors: l = 2 (v.h) h - v, dw_l = 4 (v.h) dw_h. Smith G only removes energy, so E <= 1;
    # at normal incidence on a smooth surface almost nothing is lost.
    h, dw_h = half_vector_quadrature()
    m = h.shape[0]
    v = direction(theta_v, 30.0).expand(m, 3)
    vh = (v * h).sum(-1, keepdim=True)
    l = 2 * vh * h - v
    n = NORMAL_Z.expand(m, 3)
    spec = brdf_specular(material(m, specular=1.0, alpha=alpha), n, l, v)[:, 0]
    weight = (l[:, 2].clamp_min(0) * 4 * vh[:, 0].clamp_min(0) * dw_h)
    E = (spec * weight).sum().item()
    assert 0.25 < E <= 1.0 + 2e-3
    if alpha <= 0.2 and theta_v == 0.0:
        assert E == pytest.approx(1.0, abs=0.06)
    if alpha == 1.0 and theta_v == 0.0:
        # alpha = 1: D = 1/pi, G1(c) = 2c / (c + 1), and v = n gives
        # E = (1/2pi) integral mu / (mu + 1) dw = integral_0^1 mu / (mu + 1) dmu = 1 - ln 2
        assert E == pytest.approx(1.0 - math.log(2.0), abs=1e-3)


# ----------------------------------------------------------------------------- gradients

def test_autograd_matches_finite_differences():
    gen = torch.Generator().manual_seed(3)
    n = 6
    l, v = upper_hemisphere(n, gen, 0.3), upper_hemisphere(n, gen, 0.3)
    normal = (NORMAL_Z + 0.1 * torch.randn(n, 3, generator=gen, dtype=torch.float64))
    normal = (normal / normal.norm(dim=-1, keepdim=True)).requires_grad_(True)
    albedo = torch.rand(n, 3, generator=gen, dtype=torch.float64).requires_grad_(True)
    spec = (0.02 + 0.5 * torch.rand(n, 1, generator=gen, dtype=torch.float64)).requires_grad_(True)
    alpha = (0.1 + 0.8 * torch.rand(n, 1, generator=gen, dtype=torch.float64)).requires_grad_(True)

    def f(albedo, spec, alpha, normal):
        return brdf(SurfaceMaterial(albedo, spec, alpha), normal, l, v)

    assert torch.autograd.gradcheck(f, (albedo, spec, alpha, normal), eps=1e-6, atol=1e-6, rtol=1e-4)


# ----------------------------------------------------------------------------- shading

def shade_at(light_pos, normal=(0.0, 0.0, 1.0), intensity=2.0, visibility=None) -> torch.Tensor:
    mat = material(1, albedo=(0.8, 0.8, 0.8), specular=0.0, alpha=1.0)
    p = torch.zeros(1, 3, dtype=torch.float64)
    n = torch.tensor([normal], dtype=torch.float64)
    light = PointLight(torch.tensor(light_pos, dtype=torch.float64), torch.full((3,), intensity, dtype=torch.float64))
    return shade(mat, n, p, NORMAL_Z, light, visibility)


def test_shade_irradiance_falls_off_as_inverse_square_and_cosine():
    # Lambert + F0 = 0, seen along the normal. Off the normal the specular lobe with F0 = 0 still
    # reflects Schlick's (1 - v.h)^5 share, so the tilted case adds it explicitly.
    near, far = shade_at([0, 0, 1.0]), shade_at([0, 0, 2.0])
    torch.testing.assert_close(near / far, torch.full_like(near, 4.0), rtol=1e-12, atol=0)
    # light straight above at r = 1, I = 2, rho = 0.8: L = (0.8/pi + spec(n, n)) * 2; spec = 0 as F(1) = F0 = 0
    torch.testing.assert_close(near, torch.full_like(near, 0.8 / math.pi * 2.0), rtol=1e-12, atol=0)
    # 60 deg off the normal at r = 1: the diffuse part scales by cos 60 = 1/2
    mat = material(1, albedo=(0.8, 0.8, 0.8), specular=0.0, alpha=1.0)
    l60 = direction(60.0)
    spec = brdf_specular(mat, NORMAL_Z, l60, NORMAL_Z).expand(1, 3)
    tilted = shade_at(l60[0].tolist())
    torch.testing.assert_close(tilted, (0.8 / math.pi + spec) * 2.0 * 0.5, rtol=1e-12, atol=0)


def test_shade_is_zero_below_the_horizon():
    assert torch.all(shade_at([0.3, 0.0, -1.0]) == 0)
    assert torch.all(shade_at([1.0, 0.0, 0.0]) == 0)  # exactly grazing: cos = 0


def test_visibility_multiplies():
    lit = shade_at([0, 0, 1.5])
    torch.testing.assert_close(shade_at([0, 0, 1.5], visibility=torch.tensor([0.25], dtype=torch.float64)),
                               0.25 * lit, rtol=1e-12, atol=0)
    assert torch.all(shade_at([0, 0, 1.5], visibility=torch.zeros(1, dtype=torch.float64)) == 0)


def test_shade_colocated_equals_brdf_times_intensity_over_r2():
    # camera and light at (0, 0, 3), surface point at the origin facing them: L = f(v, v) I / 9
    mat = material(1)
    p = torch.zeros(1, 3, dtype=torch.float64)
    light = PointLight(torch.tensor([0, 0, 3.0], dtype=torch.float64), torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    got = shade(mat, NORMAL_Z, p, NORMAL_Z, light)
    f = brdf(mat, NORMAL_Z, NORMAL_Z, NORMAL_Z)
    torch.testing.assert_close(got, f * torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64) / 9.0, rtol=1e-12, atol=0)
