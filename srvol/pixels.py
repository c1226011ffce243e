"""Training pixels of a scene and the rays that estimate them under the PSF.

A batch is G groups; group g has R rays and P LR pixels, and pixel p of the group is
estimated as ``sum_r weights[g, p, r] * C(ray r)``. Per-pixel sampling (``none``, ``box``,
Monte Carlo ``gaussian``) is the case P = 1 with equal weights; the shared lattice (a
patch of LR pixels whose HR sub-pixel rays serve every pixel of the patch under the PSF)
has P = patch^2 and Gaussian weights.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from srvol.capture.terms import radial2
from srvol.config import TrainConfig, psf_rays_per_pixel, psf_sampler_of_stage, rays_per_step
from srvol.data import Scene
from srvol.error_map import ErrorMap
from srvol.errors import SrvolError
from srvol.psf import PsfSampler, SRMode
from srvol.types import Rays


@dataclass(frozen=True)
class PixelBatch:
    """G groups of P LR pixels estimated from R rays each (``rays`` has G * R entries, group-major).

    weights (G, P, R), rows summing to 1; target (G * P, 3) linear colour; mask (G * P,)
    foreground in {0, 1}; view (G * P,) the training view of each pixel and r2 (G * P,) its squared
    distance from the image centre over the squared half-diagonal (the capture terms' exposure and
    vignetting); ray_view (G * R,) the view of each ray (its flash position). Drawn by an error map
    (:mod:`srvol.error_map`): importance (G * P,) each pixel's weight in the step's means (uniform
    probability over drawn probability) and centre (G,) each group's centre pixel, an index into
    the bank's in-mask pixels; None for a uniform draw (every weight 1).
    """

    rays: Rays
    weights: Tensor
    target: Tensor
    mask: Tensor
    view: Tensor
    r2: Tensor
    ray_view: Tensor
    importance: Tensor | None = None
    centre: Tensor | None = None

    @property
    def n_rays(self) -> int:
        return self.weights.shape[0] * self.weights.shape[2]

    @property
    def n_pixels(self) -> int:
        return self.weights.shape[0] * self.weights.shape[1]

    def groups(self, lo: int, hi: int) -> "PixelBatch":
        """Groups [lo, hi) of the batch, with their pixels and rays (a data-parallel rank's share)."""
        G, P, R = self.weights.shape
        return PixelBatch(rays=self.rays[lo * R:hi * R], weights=self.weights[lo:hi],
                          target=self.target[lo * P:hi * P], mask=self.mask[lo * P:hi * P],
                          view=self.view[lo * P:hi * P], r2=self.r2[lo * P:hi * P],
                          ray_view=self.ray_view[lo * R:hi * R],
                          importance=None if self.importance is None else self.importance[lo * P:hi * P],
                          centre=None if self.centre is None else self.centre[lo:hi])

    @property
    def pixel_weight(self) -> Tensor:
        """(G * P,) each pixel's weight in the step's means: the foreground mask times its importance."""
        return self.mask if self.importance is None else self.mask * self.importance

    def estimate(self, per_ray: Tensor) -> Tensor:
        """Per-ray values (G * R, C) -> per-pixel PSF estimates (G * P, C)."""
        G, P, R = self.weights.shape
        return torch.einsum("gpr,grc->gpc", self.weights, per_ray.reshape(G, R, -1)).reshape(G * P, -1)


SILHOUETTE_MARGIN = 2
"""LR pixels added around each view's mask bounding box for the out-of-mask rays drawn near the object."""


class PixelBank:
    """All LR training pixels, split by the mask, with per-view camera tensors for batched rays."""

    def __init__(self, scene: Scene, device: torch.device):
        views = scene.train_views()
        self.device = device
        self.has_masks = scene.has_masks
        Ks = torch.stack([v.camera.K.float() for v in views])
        W2C = torch.stack([v.camera.W2C.float() for v in views])
        self.K_inv = torch.linalg.inv(Ks).to(device)
        self.R_T = W2C[:, :3, :3].transpose(1, 2).contiguous().to(device)
        self.centers = torch.stack([v.camera.center.float() for v in views]).to(device)
        colours, masks, vid, ij, sizes, start = [], [], [], [], [], [0]
        for k, v in enumerate(views):
            H, W = v.image.shape[:2]
            sizes.append((H, W))
            start.append(start[-1] + H * W)
            jj, ii = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
            colours.append(v.image.reshape(-1, 3))
            masks.append((v.mask if v.mask is not None else np.ones((H, W), bool)).reshape(-1))
            vid.append(np.full(H * W, k))
            ij.append(np.stack([ii.reshape(-1), jj.reshape(-1)], -1))
        self.colour = torch.from_numpy(np.concatenate(colours)).float().to(device)
        self.mask = torch.from_numpy(np.concatenate(masks)).to(device)
        self.view = torch.from_numpy(np.concatenate(vid)).long().to(device)
        self.ij = torch.from_numpy(np.concatenate(ij)).float().to(device)
        self.sizes = torch.tensor(sizes, dtype=torch.long, device=device)
        hw = self.sizes[self.view].float()  # (pixels, 2) = (H, W) of each pixel's view
        self.r2 = radial2(self.ij + 0.5, hw[:, 1], hw[:, 0])
        by_size = {s: k for k, s in enumerate(dict.fromkeys(sizes))}
        self.camera_of_view = torch.tensor([by_size[s] for s in sizes], dtype=torch.long, device=device)
        """One camera per image size (a phone's photos of one size share the lens: the vignetting)."""
        self.view_start = torch.tensor(start[:-1], dtype=torch.long, device=device)
        self.inside = torch.nonzero(self.mask).squeeze(-1)
        self.outside = torch.nonzero(~self.mask).squeeze(-1)
        self.outside_near = torch.nonzero(~self.mask & self._in_mask_box(SILHOUETTE_MARGIN)).squeeze(-1)

    def _in_mask_box(self, margin: int) -> Tensor:
        """Per pixel: inside its view's mask bounding box grown by ``margin`` LR pixels."""
        near = torch.zeros_like(self.mask)
        for k, (start, (H, W)) in enumerate(zip(self.view_start.tolist(), self.sizes.tolist())):
            m = self.mask[start:start + H * W].reshape(H, W)
            if not m.any():
                continue
            rows, cols = torch.nonzero(m.any(1)).squeeze(-1), torch.nonzero(m.any(0)).squeeze(-1)
            box = torch.zeros(H, W, dtype=torch.bool, device=m.device)
            box[max(0, int(rows[0]) - margin):int(rows[-1]) + margin + 1,
                max(0, int(cols[0]) - margin):int(cols[-1]) + margin + 1] = True
            near[start:start + H * W] = box.reshape(-1)
        return near

    def rays(self, view: Tensor, uv: Tensor) -> Rays:
        """Rays of views ``view`` (P,) through continuous pixel coordinates ``uv`` (P, S, 2)."""
        P, S, _ = uv.shape
        hom = torch.cat([uv, torch.ones(P, S, 1, device=uv.device)], -1)
        d_cam = torch.einsum("pij,psj->psi", self.K_inv[view], hom)
        d = torch.einsum("pij,psj->psi", self.R_T[view], d_cam)
        d = d / d.norm(dim=-1, keepdim=True)
        o = self.centers[view][:, None, :].expand(P, S, 3)
        return Rays(origins=o.reshape(-1, 3), directions=d.reshape(-1, 3))

    def sample(self, n: int, inside: bool, psf: PsfSampler, psf_samples: int, generator: torch.Generator,
               antithetic: bool = False, near_share: float = 0.0, error_map: ErrorMap | None = None) -> PixelBatch:
        """n pixels (in or out of the mask), each estimated by its own ``psf_samples`` rays (groups
        of one pixel). Out of the mask, ``near_share`` of them come from the silhouette's bounding
        box (the gaps between legs, under a seat, in a handle: where the shape is carved). In the
        mask, ``error_map`` draws them where the error is (with their importance weights)."""
        centre = importance = None
        if inside:
            pick, centre, importance = self._pick_inside(n, generator, error_map)
        elif near_share <= 0 or not len(self.outside_near):
            pick = self._pick(self.outside, n, generator)
        else:
            near = int(round(n * near_share))
            pick = torch.cat([self._pick(self.outside_near, near, generator),
                              self._pick(self.outside, n - near, generator)])
        offsets = psf.offsets(n, psf_samples, generator=generator, antithetic=antithetic).to(self.device)
        uv = self.ij[pick][:, None, :] + 0.5 + offsets
        S = offsets.shape[1]
        weights = torch.full((n, 1, S), 1.0 / S, device=self.device)
        view = self.view[pick]
        return PixelBatch(rays=self.rays(view, uv), weights=weights, target=self.colour[pick],
                          mask=self.mask[pick].float(), view=view, r2=self.r2[pick],
                          ray_view=view.repeat_interleave(S), importance=importance, centre=centre)

    def at_centres(self, rows: Tensor) -> PixelBatch:
        """The bank's pixels ``rows``, each estimated by one ray through its centre (groups of one)."""
        view = self.view[rows]
        n = len(rows)
        return PixelBatch(rays=self.rays(view, (self.ij[rows] + 0.5)[:, None, :]),
                          weights=torch.ones(n, 1, 1, device=self.device), target=self.colour[rows],
                          mask=self.mask[rows].float(), view=view, r2=self.r2[rows], ray_view=view)

    @staticmethod
    def _pick(pool: Tensor, n: int, generator: torch.Generator) -> Tensor:
        return pool[torch.randint(len(pool), (n,), generator=generator).to(pool.device)]

    def _pick_inside(self, n: int, generator: torch.Generator,
                     error_map: ErrorMap | None) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """n in-mask rows, drawn uniformly or by ``error_map``; with the map, each one's index into
        ``inside`` and its importance weight (None, None for a uniform draw)."""
        if error_map is None:
            return self._pick(self.inside, n, generator), None, None
        centre, importance = error_map.draw(n, generator)
        return self.inside[centre], centre, importance

    def patch_origin(self, pick: Tensor, patch: int) -> Tensor:
        """(n, 2) the (i, j) top-left pixel of the ``patch`` x ``patch`` patch a draw centred at rows
        ``pick`` covers: ``patch // 2`` before the centre, moved inside its view at the borders."""
        view = self.view[pick]
        H, W = self.sizes[view, 0], self.sizes[view, 1]
        x0 = torch.minimum((self.ij[pick, 0] - patch // 2).clamp(min=0), (W - patch).float())
        y0 = torch.minimum((self.ij[pick, 1] - patch // 2).clamp(min=0), (H - patch).float())
        return torch.stack([x0, y0], -1)

    def sample_patches(self, n: int, patch: int, cell: float, psf: PsfSampler,
                       generator: torch.Generator, error_map: ErrorMap | None = None) -> PixelBatch:
        """n patches of patch x patch LR pixels around random in-mask pixels, each estimated from
        one shared, randomly shifted lattice of rays (spacing ``cell`` LR px) under the Gaussian PSF.
        ``error_map``: the centres are drawn where the error is (with their importance weights)."""
        if int(self.sizes.min()) < patch:
            raise SrvolError(f"--psf-sampler lattice: {patch}x{patch}-pixel patches need images at least "
                             f"{patch} pixels wide and high")
        pick, centre, importance = self._pick_inside(n, generator, error_map)
        view = self.view[pick]
        W = self.sizes[view, 1]
        shift = torch.rand(n, 2, generator=generator).to(self.device)
        pix_off, ray_off, weights = psf.lattice(patch, cell, shift)
        origin = self.patch_origin(pick, patch)[:, None, :]
        uv = origin + ray_off  # (n, R, 2) continuous LR coordinates
        # pixels of each patch -> rows of the bank (views are stored one after another, row-major)
        px = (origin + pix_off - 0.5).round().long()  # (n, P, 2) integer (i, j)
        rows = self.view_start[view][:, None] + px[..., 1] * W[:, None] + px[..., 0]
        rows = rows.reshape(-1)
        P = pix_off.shape[-2]
        return PixelBatch(rays=self.rays(view, uv), weights=weights, target=self.colour[rows],
                          mask=self.mask[rows].float(), view=self.view[rows], r2=self.r2[rows],
                          ray_view=view.repeat_interleave(uv.shape[1]),
                          importance=None if importance is None else importance.repeat_interleave(P),
                          centre=centre)


def sample_pixels(bank: PixelBank, cfg: TrainConfig, psf: PsfSampler, stage: int, gen: torch.Generator,
                  progress: float = 1.0, error_map: ErrorMap | None = None) -> PixelBatch:
    """The in-mask pixels of one step of ``stage`` and their rays: per-pixel rays or shared lattice
    patches, as the config's PSF sampler of that stage says (``progress`` in [0, 1]: psf_warmup),
    drawn uniformly or, with ``error_map``, where the error is."""
    sampler = psf_sampler_of_stage(cfg, stage)
    if psf.mode == SRMode.GAUSSIAN and sampler == "lattice":
        n = patches_per_step(cfg, psf, stage)
        return bank.sample_patches(n, cfg.patch, cfg.lattice_cell, psf, gen, error_map)
    if psf.mode == SRMode.GAUSSIAN and sampler == "centre":
        return bank.sample(rays_per_step(cfg, stage), True, PsfSampler(SRMode.NONE, psf.psf), 1, gen,
                           error_map=error_map)
    ns = psf_rays_per_pixel(cfg, stage, progress)
    return bank.sample(rays_per_step(cfg, stage) // ns, True, psf, ns, gen, antithetic=sampler == "antithetic",
                       error_map=error_map)


def group_side(cfg: TrainConfig, psf: PsfSampler, stage: int) -> int:
    """Side in LR pixels of a group of a step of ``stage``: a lattice patch's, or 1 (one pixel)."""
    lattice = psf.mode == SRMode.GAUSSIAN and psf_sampler_of_stage(cfg, stage) == "lattice"
    return cfg.patch if lattice else 1


def patches_per_step(cfg: TrainConfig, psf: PsfSampler, stage: int) -> int:
    """Lattice patches a step of ``stage`` draws (its rays over a patch's lattice rays)."""
    return max(1, round(rays_per_step(cfg, stage) / psf.lattice_size(cfg.patch, cfg.lattice_cell) ** 2))
