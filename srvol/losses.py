"""The training loss (DESIGN.md section 3), each term normalised by its batch size:

    L = L1(LR pixel estimate, input)  over in-mask pixels
      + lambda1 * mean (|grad d| - 1)^2  over random points and the ray samples
      + lambda2 * BCE(opacity, mask)     over in- and out-of-mask pixels
      + lambda_s * mean |n(x) - n(x + e)|^2  over points on the rendered surface (optional; not the paper's)

An LR pixel is estimated from the rays the stage's PSF sampler gives it
(:func:`srvol.pixels.sample_pixels`). Stage 2 (geometry frozen) keeps the photometric term only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from srvol.capture.terms import CaptureTerms
from srvol.config import TrainConfig, sampler_of_stage
from srvol.fields import SceneFields
from srvol.pixels import PixelBank, PixelBatch, sample_pixels
from srvol.psf import PsfSampler
from srvol.render import volume_render
from srvol.types import PointLight, Rays


SMOOTH_SPREAD_MLP = 0.01
"""The normal-smoothness offset scale of MLP fields (no grid cell to take it from)."""


@dataclass(frozen=True)
class LossTerms:
    """One step's loss: ``total`` carries the graph; the terms are for the log. ``squared_error``
    is the sum over the step's foreground pixels of their mean squared error (colours clamped to
    [0, 1]) and ``pixels`` their count: PSNR over several steps is -10 log10(sum SE / sum pixels)."""

    total: Tensor
    photometric: float
    eikonal: float
    mask: float
    smooth: float
    squared_error: float
    pixels: float


def psnr_of(squared_error: float, pixels: float) -> float:
    """PSNR of a summed per-pixel squared error over ``pixels`` pixels (signal peak 1)."""
    return float(-10 * math.log10(max(squared_error / max(pixels, 1.0), 1e-10)))


def photometric_l1(estimate: Tensor, batch: PixelBatch) -> Tensor:
    """Mean L1 over the batch's foreground pixels (a lattice patch may reach past the silhouette)."""
    fg = batch.mask
    return ((estimate - batch.target).abs().mean(-1) * fg).sum() / fg.sum().clamp_min(1.0)


def eikonal(gradients: Tensor) -> Tensor:
    """mean (|grad d| - 1)^2 over the given SDF gradients (N, 3)."""
    return ((gradients.norm(dim=-1) - 1.0) ** 2).mean()


def normal_smoothness(fields: SceneFields, points: Tensor, spread: float, gen: torch.Generator) -> Tensor:
    """mean |n(x) - n(x + e)|^2 over ``points`` (N, 3), e ~ N(0, spread^2 I), n the unit SDF normal.

    Ripples whose gradient still has unit length pass the eikonal term; they turn the normal over a
    short distance, and this term sees that. Edges sharper than ``spread`` are rounded to it."""
    e = torch.randn(points.shape, generator=gen).to(points) * spread
    _, g = fields.sdf_and_gradient(torch.cat([points, points + e]), create_graph=True)
    n = F.normalize(g, dim=-1)
    a, b = n.chunk(2)
    return ((a - b) ** 2).sum(-1).mean()


def surface_points(rays: Rays, depth: Tensor, opacity: Tensor, n: int, gen: torch.Generator) -> Tensor:
    """Up to ``n`` points (detached) where rays of opacity > 0.5 meet the surface (their expected depth)."""
    hit = torch.nonzero(opacity.detach() > 0.5).squeeze(-1)
    if len(hit) > n:
        hit = hit[torch.randperm(len(hit), generator=gen)[:n].to(hit.device)]
    return (rays.origins[hit] + depth.detach()[hit, None] * rays.directions[hit]).detach()


def mask_bce(opacity_in: Tensor, mask_in: Tensor, opacity_out: Tensor) -> Tensor:
    """BCE of accumulated opacity against the mask: in-mask pixels (their PSF estimates, target the
    mask value) and rays outside the silhouette (target 0)."""
    op = torch.cat([opacity_in, opacity_out]).clamp(1e-4, 1 - 1e-4)
    return F.binary_cross_entropy(op, torch.cat([mask_in, torch.zeros_like(opacity_out)]))


def squared_error(estimate: Tensor, batch: PixelBatch) -> tuple[float, float]:
    """(sum over foreground pixels of the mean squared error of their clamped colours, pixel count)."""
    fg = batch.mask
    sq = (estimate.detach().clamp(0, 1) - batch.target.clamp(0, 1)) ** 2
    return float((sq.mean(-1) * fg).sum()), float(fg.sum())


def compute_loss(fields: SceneFields, bank: PixelBank, cfg: TrainConfig, psf: PsfSampler, stage: int,
                 gen: torch.Generator, intensity: Tensor, progress: float = 1.0,
                 capture: CaptureTerms | None = None) -> LossTerms:
    """L1 on in-mask pixels (PSF estimates) + lambda_e eikonal + lambda_m mask BCE (stage 1 only).
    ``progress`` in [0, 1] (share of the run done) selects the PSF rays per pixel (psf_warmup).
    ``capture``: each ray is lit by its photo's flash, and the pixel estimates pass through the
    photo's exposure, vignetting and ambient term before they meet the photo."""
    train_geo = stage == 1
    batch = sample_pixels(bank, cfg, psf, stage, gen, progress)
    rays, ray_view = batch.rays, batch.ray_view
    use_mask = train_geo and bank.has_masks and len(bank.outside) > 0
    if use_mask:
        out = bank.sample(cfg.batch_out, False, psf, 1, gen, near_share=cfg.silhouette_rays)
        rays = Rays(torch.cat([rays.origins, out.rays.origins]), torch.cat([rays.directions, out.rays.directions]))
        ray_view = torch.cat([ray_view, out.ray_view])
    n_pix_rays = batch.n_rays
    light_at = rays.origins  # co-located: at each ray's camera
    if capture is not None:
        origins, directions = capture.refine_rays(rays.origins, rays.directions, ray_view)
        rays = Rays(origins, directions)
        w2c = bank.R_T[batch.ray_view].transpose(1, 2)
        light_at = torch.cat([capture.flash_position(origins[:n_pix_rays], w2c), origins[n_pix_rays:]])
    light = PointLight(position=light_at, intensity=intensity)
    shade_rays = torch.arange(len(rays), device=rays.origins.device) < n_pix_rays
    vr = volume_render(fields, rays, light, sampler_of_stage(cfg, stage), train_geometry=train_geo,
                       shade_rays=shade_rays, with_albedo=capture is not None)
    rgb = batch.estimate(vr.result.rgb[:n_pix_rays])
    if capture is not None:
        rgb = capture.apply(rgb, batch.estimate(vr.albedo[:n_pix_rays]), batch.view, batch.r2)
    photometric = photometric_l1(rgb, batch)
    total = photometric
    eik = torch.zeros(())
    mask_loss = torch.zeros(())
    smooth = torch.zeros(())
    if train_geo:
        pts = (torch.rand(cfg.batch_eikonal, 3, generator=gen) * 2 - 1).to(rgb.device)
        _, g_rand = fields.sdf_and_gradient(pts, create_graph=True)
        eik = eikonal(torch.cat([g_rand, vr.sdf_gradients]))
        total = total + cfg.lambda_eikonal * eik
        if use_mask:
            op_in = batch.estimate(vr.result.opacity[:n_pix_rays, None])[:, 0]
            mask_loss = mask_bce(op_in, batch.mask, vr.result.opacity[n_pix_rays:])
            total = total + cfg.lambda_mask * mask_loss
        if cfg.lambda_smooth > 0:
            pts = surface_points(Rays(rays.origins[:n_pix_rays], rays.directions[:n_pix_rays]),
                                 vr.result.depth[:n_pix_rays], vr.result.opacity[:n_pix_rays], cfg.batch_smooth, gen)
            if len(pts):
                smooth = normal_smoothness(fields, pts, fields.finest_sdf_cell() or SMOOTH_SPREAD_MLP, gen)
                total = total + cfg.lambda_smooth * smooth
    se, pixels = squared_error(rgb, batch)
    return LossTerms(total=total, photometric=float(photometric.detach()), eikonal=float(eik.detach()),
                     mask=float(mask_loss.detach()), smooth=float(smooth.detach()), squared_error=se, pixels=pixels)
