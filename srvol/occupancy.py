"""Which rays can meet the surface: a coarse occupancy grid of a trained SDF, for evaluation.

The volume renderer locates the surface along every ray with ~40 SDF queries before it places the
gradient samples. At evaluation most pixels of an HR view are background (a 640x480 view of the
stool: 80 %), and their locating pass finds nothing. An SDF bounds where its surface can be: a cell
whose centre reads ``d`` holds no point closer to the surface than ``|d| - h`` (``h`` the cell's
half-diagonal) when ``|grad d| <= 1``. A ray that crosses no cell within reach of the surface gets
zero opacity from VolSDF's density, so it is not traced at all.

The bound is kept conservative: the learned SDF is only approximately 1-Lipschitz (the eikonal
loss pulls its gradient to unit length near the samples), so a cell counts as occupied when
``d < LIPSCHITZ_SLACK * h + DENSITY_REACH * beta``, and the occupied set is dilated by one cell
before rays are marched through it at half-cell steps.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from srvol.geometry import ray_sphere
from srvol.types import Rays, SdfFn

LIPSCHITZ_SLACK = 2.0
"""The SDF may change up to twice as fast as distance (a learned grid's |grad d| stays well below)."""

DENSITY_REACH = 20.0
"""VolSDF's density at d = 20 beta is exp(-20) / (2 beta) of its surface value: below 1e-6 opacity
over the whole bounding sphere for any beta a run ends with."""


@dataclass(frozen=True)
class OccupancyGrid:
    """``occupied`` (R, R, R) bool over the cube [-bound, bound]^3 (index order x, y, z), already
    dilated by one cell: a ray that samples none of its cells at half-cell steps cannot meet the
    surface."""

    occupied: Tensor
    bound: float

    @property
    def resolution(self) -> int:
        return self.occupied.shape[0]

    @property
    def cell(self) -> float:
        return 2.0 * self.bound / self.resolution

    @property
    def fraction(self) -> float:
        """Share of the cube's cells counted as occupied (after the dilation)."""
        return float(self.occupied.float().mean())

    @staticmethod
    def of_sdf(sdf: SdfFn, beta: float, bound: float = 1.0, resolution: int = 64,
               chunk: int = 1 << 16) -> "OccupancyGrid":
        """Query ``sdf`` at the cell centres; ``beta`` the density's scale (the run's final beta)."""
        cell = 2.0 * bound / resolution
        c = (torch.arange(resolution, dtype=torch.float32) + 0.5) * cell - bound
        pts = torch.stack(torch.meshgrid(c, c, c, indexing="ij"), -1).reshape(-1, 3)
        device = _device_of(sdf)
        with torch.no_grad():
            d = torch.cat([sdf(pts[s:s + chunk].to(device)).float().cpu() for s in range(0, len(pts), chunk)])
        reach = LIPSCHITZ_SLACK * 0.5 * math.sqrt(3.0) * cell + DENSITY_REACH * beta
        occ = (d < reach).reshape(resolution, resolution, resolution)
        dilated = F.max_pool3d(occ[None, None].float(), kernel_size=3, stride=1, padding=1)[0, 0] > 0
        return OccupancyGrid(occupied=dilated, bound=bound)

    def box(self) -> tuple[Tensor, Tensor]:
        """Corners (3,), (3,) of the axis-aligned box around the occupied cells (an empty grid: a
        box behind every ray, lo > hi)."""
        idx = torch.nonzero(self.occupied)
        if len(idx) == 0:
            return torch.ones(3), -torch.ones(3)
        return (idx.min(0).values.float() * self.cell - self.bound,
                (idx.max(0).values.float() + 1) * self.cell - self.bound)

    def rays_that_may_hit(self, rays: Rays, radius: float, chunk: int = 16384) -> Tensor:
        """(N,) bool: rays whose segment inside the sphere of ``radius`` (the sampler's bound)
        passes through an occupied cell. Rays are clipped to the occupied cells' box first (most
        background rays miss it), then marched through it at half-cell steps."""
        device = rays.origins.device
        occ = self.occupied.to(device)
        lo_c, hi_c = (c.to(device) for c in self.box())
        R = self.resolution
        step = 0.5 * self.cell
        n_steps = int(math.ceil(float((hi_c - lo_c).clamp_min(0).norm()) / step)) + 2
        s = torch.arange(n_steps, dtype=rays.origins.dtype, device=device) * step
        out = torch.zeros(len(rays), dtype=torch.bool, device=device)
        for lo in range(0, len(rays), chunk):
            r = rays[lo:lo + chunk]
            near, far = ray_sphere(r, radius)
            inv = 1.0 / torch.where(r.directions.abs() < 1e-12, torch.full_like(r.directions, 1e-12), r.directions)
            ta, tb = (lo_c - r.origins) * inv, (hi_c - r.origins) * inv
            t0 = torch.maximum(torch.minimum(ta, tb).amax(-1), near)
            t1 = torch.minimum(torch.maximum(ta, tb).amin(-1), far)
            cand = torch.nonzero(t1 >= t0).squeeze(-1)
            if cand.numel() == 0:
                continue
            rc, t0, t1 = r[cand], t0[cand], t1[cand]
            t = torch.minimum(t0[:, None] + s[None, :], t1[:, None])  # the last sample sits on the exit
            idx = ((rc.at(t) + self.bound) / self.cell).floor().long().clamp(0, R - 1)
            out[lo + cand] = occ[idx[..., 0], idx[..., 1], idx[..., 2]].any(-1)
        return out


def _device_of(sdf: SdfFn) -> torch.device:
    """The device of a module's (or bound method's module's) parameters; CPU for plain functions."""
    owner = getattr(sdf, "__self__", sdf)
    params = getattr(owner, "parameters", None)
    if params is not None:
        for p in params():
            return p.device
    return torch.device("cpu")
