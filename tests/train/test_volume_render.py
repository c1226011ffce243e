"""VolSDF quadrature as worked examples, and the renderer on an analytic sphere."""
import math

import torch

from srvol.render import (SamplerConfig, laplace_density, render_weight_from_density, sample_from_weights,
                          volume_render)
from srvol.types import PointLight, Rays
from sphere_fields import sphere_fields


def test_laplace_density_hand_values():
    beta = torch.tensor(0.1)
    d = torch.tensor([0.0, 0.1, -0.1])
    # sigma(0) = 0.5 / beta; sigma(beta) = 0.5 e^-1 / beta; sigma(-beta) = (1 - 0.5 e^-1) / beta
    expect = torch.tensor([5.0, 5.0 * math.exp(-1), (1 - 0.5 * math.exp(-1)) / 0.1])
    assert torch.allclose(laplace_density(d, beta), expect, atol=1e-6)


def test_weights_hand_computed_case():
    # two samples, sigma = [1, 2], delta = [0.5, 0.5]:
    # w0 = 1 - e^-0.5; w1 = e^-0.5 (1 - e^-1)
    w = render_weight_from_density(torch.tensor([[1.0, 2.0]]), torch.tensor([[0.5, 0.5]]))
    assert torch.allclose(w, torch.tensor([[1 - math.exp(-0.5), math.exp(-0.5) * (1 - math.exp(-1))]]))
    assert float(w.sum()) <= 1.0


def test_weights_sum_at_most_one_for_random_densities():
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(200, 64, generator=g) * 50
    deltas = torch.rand(200, 64, generator=g) * 0.1
    w = render_weight_from_density(sigma, deltas)
    assert (w >= 0).all() and (w.sum(1) <= 1 + 1e-6).all()


def test_importance_samples_follow_the_weights():
    t = torch.linspace(0, 1, 11)[None].expand(1000, 11).contiguous()
    w = torch.zeros(1000, 11)
    w[:, 7] = 1.0  # all mass in the bin centred at 0.7, width 0.1
    s = sample_from_weights(t, w, 16, generator=torch.Generator().manual_seed(0))
    inside = ((s > 0.65) & (s < 0.75)).float().mean()
    assert inside > 0.98


def test_render_of_initial_sphere_is_opaque_inside_and_empty_outside():
    f = sphere_fields(0.5, 0.005)
    o = torch.tensor([[0.0, 0.0, -3.0], [0.0, 0.0, -3.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.8, 1.0]])
    d = d / d.norm(dim=-1, keepdim=True)
    rays = Rays(o, d)
    vr = volume_render(f, rays, PointLight(position=o, intensity=torch.full((3,), 9.0)),
                       SamplerConfig(n_coarse=64, n_importance=32, n_uniform=4), train_geometry=False, jitter=False)
    op = vr.result.opacity
    assert op[0] > 0.99 and op[1] < 0.01
    # expected depth of the central ray: the sphere at t = 2.5 (within a few beta)
    assert abs(float((vr.result.depth[0] / op[0]).detach()) - 2.5) < 0.02
    # expected normal faces the camera
    n = (vr.result.normal[0] / vr.result.normal[0].norm()).detach()
    assert float(n @ torch.tensor([0.0, 0.0, -1.0])) > 0.999


def test_colocated_render_matches_closed_form_at_the_centre():
    """Head-on, co-located: L = f * I / r^2 with f = rho/pi + D(1) G1(1)^2 F0 / 4."""
    from srvol.brdf import brdf
    from srvol.types import SurfaceMaterial

    f = sphere_fields(0.5, 0.002)
    o = torch.tensor([[0.0, 0.0, -3.0]])
    rays = Rays(o, torch.tensor([[0.0, 0.0, 1.0]]))
    vr = volume_render(f, rays, PointLight(position=o, intensity=torch.full((3,), 9.0)),
                       SamplerConfig(n_coarse=64, n_importance=64, n_uniform=0), train_geometry=False, jitter=False)
    with torch.no_grad():
        mat = f.material(torch.tensor([[0.0, 0.0, -0.5]]))
    n = torch.tensor([[0.0, 0.0, -1.0]])
    expect = brdf(mat, n, n, n) * 9.0 / 2.5 ** 2
    assert torch.allclose(vr.result.rgb, expect, rtol=0.02)


def test_stage2_samples_per_ray_match_a_dense_render_once_the_surface_is_fixed():
    """With beta small the VolSDF weight sits within a few beta of the first crossing: stage 2's
    16 locating + 4 gradient samples give the colour of a 128 + 68-sample render to 0.5% on average."""
    from srvol.presets import STAGE2_SAMPLER

    f = sphere_fields(0.5, 0.001)
    g = torch.Generator().manual_seed(0)
    r, a = 0.45 * torch.rand(400, generator=g).sqrt(), 2 * math.pi * torch.rand(400, generator=g)
    xy = torch.stack([r * torch.cos(a), r * torch.sin(a)], -1)  # a disc inside the sphere's silhouette
    o = torch.tensor([0.0, 0.0, -3.0]).expand(400, 3)
    d = torch.cat([xy / 3.0, torch.ones(400, 1)], -1)
    rays = Rays(o, d / d.norm(dim=-1, keepdim=True))
    light = PointLight(position=o, intensity=torch.full((3,), 9.0))
    dense = volume_render(f, rays, light, SamplerConfig(n_coarse=128, n_importance=64, n_uniform=4),
                          train_geometry=False, jitter=False).result
    few = volume_render(f, rays, light, STAGE2_SAMPLER, train_geometry=False, jitter=True).result
    assert dense.opacity.min() > 0.99 and few.opacity.min() > 0.99
    err = ((few.rgb - dense.rgb).abs() / dense.rgb.mean()).detach()
    assert float(err.mean()) < 0.005 and float(err.max()) < 0.05  # the largest at grazing rays near the rim


def test_refinement_brackets_a_plate_thinner_than_the_sample_spacing():
    """One ray along z through a plate |z| <= 0.01, samples at t = 0, 0.4, 0.8 (z = -0.5, -0.1, 0.3;
    d = 0.49, 0.09, 0.29): no sample inside, no sign change. A distance moves by at most the
    distance travelled, so the surface can lie between two samples only if d + d' < their spacing:
    0.49 + 0.09 > 0.4 (not in the first interval), 0.09 + 0.29 < 0.4 (maybe in the second). Three
    samples there (t = 0.5, 0.6, 0.7) put one inside the plate, and the crossing is found at its
    near face: t = 0.4 + 0.1 * 0.09 / (0.09 + 0.01) = 0.49."""
    from srvol.render import first_crossing, refine_first_possible_crossing

    def sdf_at(t):  # the ray starts at z = -0.5, so z = t - 0.5
        return (t - 0.5).abs() - 0.01

    t = torch.tensor([[0.0, 0.4, 0.8]])  # z = -0.5, -0.1, 0.3: d = 0.49, 0.09, 0.29
    d = sdf_at(t)
    assert not first_crossing(t, d)[1].any()  # the plate at z in [-0.01, 0.01] lies between samples
    t2, d2 = refine_first_possible_crossing(t, d, sdf_at, 3)
    assert torch.allclose(t2, torch.tensor([[0.0, 0.4, 0.5, 0.6, 0.7, 0.8]]))
    root, has = first_crossing(t2, d2)
    assert has.all() and abs(float(root) - 0.49) < 1e-5  # the plate's near face, z = -0.01


def test_the_locating_pass_finds_thin_plates_that_coarse_samples_step_over():
    """A plate 0.01 thick seen face-on from 2.6 away: 32 coarse samples over the unit sphere's chord
    (0.06 apart) land inside it for about half the rays; with 8 refining samples every ray finds it."""
    from types import SimpleNamespace

    from srvol.render import sample_along_rays

    g = torch.Generator().manual_seed(0)
    n = 2000
    origins = torch.cat([torch.rand(n, 2, generator=g) * 0.6 - 0.3, torch.full((n, 1), 2.6)], -1)
    targets = torch.cat([torch.rand(n, 2, generator=g) * 0.6 - 0.3, torch.zeros(n, 1)], -1)
    rays = Rays(origins, torch.nn.functional.normalize(targets - origins, dim=-1))
    plate = SimpleNamespace(sdf=lambda x: x[:, 2].abs() - 0.005, beta=torch.tensor(1e-3))

    def found(cfg):
        t = sample_along_rays(plate, rays, cfg, jitter=False).t
        return float((plate.sdf(rays.at(t).reshape(-1, 3)).reshape(t.shape) < 0).any(-1).float().mean())

    assert found(SamplerConfig()) < 0.7
    assert found(SamplerConfig(n_refine=8)) == 1.0


def test_regula_falsi_centres_the_gradient_band_on_a_curved_surface():
    """A sphere of radius 0.3 seen from z = 2, rays aimed across it: 16 locating samples over the
    unit sphere's chord (0.125 apart). The linear interpolation of the first sign change is off by
    up to ~1e-2 near the rim, more than a +-4 beta band is wide once beta is 1e-3; three regula falsi
    steps on the same bracket put every root within 1e-4 of the exact one, and ``sample_along_rays``
    then places the gradient samples on both sides of the surface on every ray."""
    from types import SimpleNamespace

    from srvol.render import _stratified, first_crossing, sample_along_rays
    from srvol.geometry import ray_sphere

    g = torch.Generator().manual_seed(1)
    n = 4000
    origins = torch.tensor([[0.0, 0.0, 2.0]]).expand(n, 3)
    targets = torch.cat([torch.rand(n, 2, generator=g) * 0.6 - 0.3, torch.zeros(n, 1)], -1)
    rays = Rays(origins, torch.nn.functional.normalize(targets - origins, dim=-1))
    ball = SimpleNamespace(sdf=lambda x: x.norm(dim=-1) - 0.3, beta=torch.tensor(1e-3))

    # exact first hit of |o + t d| = 0.3
    b = (rays.origins * rays.directions).sum(-1)
    disc = b ** 2 - (rays.origins.pow(2).sum(-1) - 0.09)
    hits = disc > 0
    exact = -b - disc.clamp_min(0).sqrt()

    near, far = ray_sphere(rays, 1.0)
    t = _stratified(near, far, 16, False)
    d = ball.sdf(rays.at(t).reshape(-1, 3)).reshape(t.shape)

    def sdf_at(tr):
        return ball.sdf(rays.at(tr).reshape(-1, 3)).reshape(tr.shape)

    linear, has = first_crossing(t, d)
    refined, has2 = first_crossing(t, d, sdf_at, 3)
    assert torch.equal(has, has2) and has.sum() > 0.5 * hits.sum()
    assert (linear - exact)[has].abs().max() > 4e-3  # wider than the band at beta 1e-3
    assert (refined - exact)[has].abs().max() < 1e-4

    ts = sample_along_rays(ball, rays, SamplerConfig(n_coarse=16, n_importance=4, n_uniform=0), jitter=False).t
    ds = ball.sdf(rays.at(ts).reshape(-1, 3)).reshape(ts.shape)
    straddles = (ds > 0).any(-1) & (ds < 0).any(-1)
    assert straddles[has].all()
