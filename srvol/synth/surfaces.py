"""Exact ray casting of ground-truth surfaces, independent of the neural volume renderer.

Two kinds: an analytic SDF (sphere tracing in float64 with Newton refinement and
autograd normals) and a triangle mesh (embree through trimesh, smooth normals).
Both return a :class:`Hit` per ray; materials come from a callable on 3-D points.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from srvol.geometry import MeshRayCaster, ray_sphere, sdf_normals
from srvol.types import MaterialFn, Rays, SdfFn


@dataclass(frozen=True)
class Hit:
    """hit (N,) bool, t (N,) distance (inf on miss), points (N, 3), normals (N, 3) unit (zero on miss)."""

    hit: Tensor
    t: Tensor
    points: Tensor
    normals: Tensor


@dataclass
class AnalyticSurface:
    """A surface given by an SDF that may over-estimate distance by up to ``lipschitz``."""

    sdf: SdfFn
    material: MaterialFn
    lipschitz: float = 1.0
    bound: float = 1.0
    max_steps: int = 160
    eps: float = 1e-5

    def intersect(self, rays: Rays, t_max: Tensor | None = None) -> Hit:
        o = rays.origins.double()
        d = rays.directions.double()
        n = o.shape[0]
        near, far = ray_sphere(Rays(o, d), self.bound)
        if t_max is not None:
            far = torch.minimum(far, t_max.double())
        t = near.clone()
        hit = torch.zeros(n, dtype=torch.bool)
        idx = torch.nonzero(near < far).squeeze(-1)
        # March only the live rays, kept compact; finished ones are written back once.
        oa, da, ta, fa = o[idx], d[idx], t[idx], far[idx]
        step_scale = 1.0 / self.lipschitz
        for _ in range(self.max_steps):
            if idx.numel() == 0:
                break
            dist = self.sdf(oa + ta[:, None] * da)
            done = dist.abs() < self.eps
            ta = ta + dist * step_scale
            finished = done | (ta >= fa)
            if finished.any():
                hit[idx[done]] = True
                t[idx[finished]] = ta[finished]
                keep = ~finished
                idx, oa, da, ta, fa = idx[keep], oa[keep], da[keep], ta[keep], fa[keep]
        if idx.numel():  # grazing rays still creeping along the surface at the step limit
            t[idx] = ta
            hit[idx[self.sdf(oa + ta[:, None] * da).abs() < 50 * self.eps]] = True
        # Newton refinement along the ray: t <- t - d(t) / (dd/dt)
        idx = torch.nonzero(hit).squeeze(-1)
        if idx.numel():
            ti = t[idx]
            for _ in range(3):
                with torch.enable_grad():
                    x = (o[idx] + ti[:, None] * d[idx]).requires_grad_(True)
                    dist = self.sdf(x)
                    (g,) = torch.autograd.grad(dist.sum(), x)
                dd = (g * d[idx]).sum(-1)
                ti = ti - torch.where(dd.abs() > 1e-3, dist.detach() / dd, torch.zeros_like(dd))
            t[idx] = ti
        t = torch.where(hit, t, torch.full_like(t, float("inf")))
        pts = o + torch.where(hit, t, torch.zeros_like(t))[:, None] * d
        normals = torch.zeros_like(pts)
        if idx.numel():
            normals[idx] = sdf_normals(self.sdf, pts[idx])
        return Hit(hit=hit, t=t, points=pts, normals=normals)


@dataclass
class MeshSurface:
    """A triangle mesh (trimesh.Trimesh) with barycentric-interpolated vertex normals."""

    mesh: "object"
    material: MaterialFn

    def __post_init__(self):
        self._caster = MeshRayCaster.build(self.mesh)
        self._vn = np.asarray(self.mesh.vertex_normals, dtype=np.float64)

    def sdf(self, x: Tensor) -> Tensor:
        """Signed distance (negative inside) -- slow; used only for tests and the mesh GT."""
        import trimesh

        pq = trimesh.proximity.ProximityQuery(self.mesh)
        return -torch.from_numpy(pq.signed_distance(x.detach().cpu().numpy())).to(x)

    def intersect(self, rays: Rays, t_max: Tensor | None = None) -> Hit:
        o = rays.origins.detach().cpu().double().numpy()
        d = rays.directions.detach().cpu().double().numpy()
        n = o.shape[0]
        hits = self._caster.first_hits(o, d)
        t = np.full(n, np.inf)
        pts = o.copy()
        normals = np.zeros((n, 3))
        if len(hits.ray):
            t[hits.ray] = hits.t
            pts[hits.ray] = hits.points
            nn = self._caster.interpolate(hits, self._vn)
            # Keep shading normals on the side of the geometric face normal (outward on a closed mesh).
            flip = (nn * self._caster.face_normals[hits.face]).sum(-1) < 0
            nn[flip] *= -1
            normals[hits.ray] = nn / np.linalg.norm(nn, axis=-1, keepdims=True).clip(1e-12)
        hit = np.isfinite(t)
        if t_max is not None:
            tm = t_max.detach().cpu().double().numpy()
            hit &= t < tm
            t[~hit] = np.inf
            normals[~hit] = 0
        return Hit(hit=torch.from_numpy(hit), t=torch.from_numpy(t), points=torch.from_numpy(pts),
                   normals=torch.from_numpy(normals))


Surface = AnalyticSurface | MeshSurface
IntersectFn = Callable[[Rays], Hit]
