"""The normal-smoothness term as a worked example: zero on a plane and on a sphere much larger
than its offsets, large on a rippled plane whose gradient still has unit length almost everywhere."""
from __future__ import annotations

import torch

from srvol.losses import normal_smoothness


class Analytic:
    """Just what the term needs of SceneFields: an SDF and its gradient."""

    def __init__(self, sdf):
        self.sdf = sdf

    def sdf_and_gradient(self, x, create_graph):
        x = x.detach().requires_grad_(True)
        d = self.sdf(x)
        (g,) = torch.autograd.grad(d, x, torch.ones_like(d), create_graph=create_graph)
        return d, g


def _on_plane(n=512):
    gen = torch.Generator().manual_seed(0)
    xy = torch.rand(n, 2, generator=gen) * 2 - 1
    return torch.cat([xy, torch.zeros(n, 1)], -1)


def test_flat_and_gently_curved_surfaces_cost_nothing():
    gen = torch.Generator().manual_seed(1)
    plane = normal_smoothness(Analytic(lambda x: x[:, 2]), _on_plane(), 0.02, gen).detach()
    assert float(plane) < 1e-10
    big_sphere = Analytic(lambda x: (x - torch.tensor([0.0, 0.0, -10.0])).norm(dim=-1) - 10.0)
    assert float(normal_smoothness(big_sphere, _on_plane(), 0.02, gen).detach()) < 1e-4


def test_ripples_that_pass_the_eikonal_term_are_seen():
    gen = torch.Generator().manual_seed(1)
    # z - 0.01 sin(60 x): |grad| = sqrt(1 + 0.36 cos^2) -- close to 1 -- but the normal swings by ~30 deg
    rippled = Analytic(lambda x: x[:, 2] - 0.01 * torch.sin(60 * x[:, 0]))
    cost = float(normal_smoothness(rippled, _on_plane(), 0.02, gen).detach())
    assert cost > 0.02
    finer = float(normal_smoothness(rippled, _on_plane(), 0.002, gen).detach())
    assert finer < cost / 10  # offsets much shorter than the ripple see a smooth surface
