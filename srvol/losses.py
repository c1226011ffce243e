"""The training loss (DESIGN.md section 3), each term normalised by its batch size:

    L = L1(LR pixel estimate, input)  over in-mask pixels
      + lambda1 * mean (|grad d| - 1)^2  over random points and the ray samples
      + lambda2 * BCE(opacity, mask)     over in- and out-of-mask pixels
      + lambda_s * mean |n(x) - n(x + e)|^2  over points on the rendered surface (optional; not the paper's)
      + lambda_a * (mean max(|d(p)| - tol, 0) + mean max(-d(x), 0))  over stereo points p of the
                                         views and x on their lines of sight (optional; srvol.anchors)

An LR pixel is estimated from the rays the stage's PSF sampler gives it
(:func:`srvol.pixels.sample_pixels`). Stage 2 keeps the photometric term, and while its SDF learns
(``TrainConfig.trains_geometry``) the eikonal and smoothness terms; never the mask.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from srvol.anchors import AnchorPoints, anchor_terms
from srvol.capture.terms import CaptureTerms
from srvol.config import TrainConfig, psf_rays_per_pixel, sampler_of_stage
from srvol.distributed import SINGLE, Shard
from srvol.error_map import ErrorMap, patch_sums
from srvol.errors import SrvolError
from srvol.fields import SceneFields
from srvol.pixels import PixelBank, PixelBatch, group_side, sample_pixels
from srvol.psf import PsfSampler
from srvol.render import RayRows, SamplerConfig, volume_render
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


def photometric_l1(estimate: Tensor, batch: PixelBatch, count: float | None = None, clip: float = 0.0) -> Tensor:
    """Mean L1 over the batch's foreground pixels (a lattice patch may reach past the silhouette),
    each weighted by its importance when an error map drew them; ``count``: divide by this instead
    (all ranks' weighted foreground pixels). ``clip`` > 0: a photo at or above that white level is
    saturated, as on a sensor, and an estimate there costs only what it falls short of white; below
    white the L1 is unchanged (an estimate past white where the photo is not still costs its excess)."""
    fg = batch.pixel_weight
    target = batch.target
    if clip > 0:
        saturated = target >= clip
        estimate = torch.where(saturated, estimate.clamp(max=clip), estimate)
        target = target.clamp(max=clip)
    per_pixel = (estimate - target).abs().mean(-1) * fg
    return per_pixel.sum() / (fg.sum().clamp_min(1.0) if count is None else max(count, 1.0))


def eikonal(gradients: Tensor, count: float | None = None) -> Tensor:
    """mean (|grad d| - 1)^2 over the given SDF gradients (N, 3) (``count``: sum / count)."""
    sq = (gradients.norm(dim=-1) - 1.0) ** 2
    return sq.mean() if count is None else sq.sum() / max(count, 1.0)


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


def mask_bce(opacity_in: Tensor, mask_in: Tensor, opacity_out: Tensor, count: float | None = None) -> Tensor:
    """BCE of accumulated opacity against the mask: in-mask pixels (their PSF estimates, target the
    mask value) and rays outside the silhouette (target 0). ``count``: sum / count, not the mean."""
    op = torch.cat([opacity_in, opacity_out]).clamp(1e-4, 1 - 1e-4)
    target = torch.cat([mask_in, torch.zeros_like(opacity_out)])
    if count is None:
        return F.binary_cross_entropy(op, target)
    return F.binary_cross_entropy(op, target, reduction="sum") / max(count, 1.0)


def pixel_squared_error(estimate: Tensor, batch: PixelBatch) -> Tensor:
    """(G * P,) each pixel's mean squared error of its clamped colours, 0 off the foreground."""
    return ((estimate.detach().clamp(0, 1) - batch.target.clamp(0, 1)) ** 2).mean(-1) * batch.mask


def squared_error(estimate: Tensor, batch: PixelBatch) -> tuple[float, float]:
    """(sum over foreground pixels of the mean squared error of their clamped colours, pixel count),
    both weighted by the pixels' importance when an error map drew them."""
    w = batch.pixel_weight
    return float((pixel_squared_error(estimate, batch) * w).sum()), float(w.sum())


def group_squared_error(estimate: Tensor, batch: PixelBatch) -> Tensor:
    """(G,) each group's summed squared error over its foreground pixels (unweighted): what an
    error map records of the group's centre cell."""
    G = batch.weights.shape[0]
    return pixel_squared_error(estimate, batch).reshape(G, -1).sum(-1)


def flash_lit(bank: PixelBank, rays: Rays, ray_view: Tensor, n_lit: int, intensity: Tensor,
              capture: CaptureTerms | None) -> tuple[Rays, PointLight]:
    """The rays (pose-refined with ``capture``) and the flash lighting each: co-located with its
    camera, or at the capture's learned offset from the lens for the first ``n_lit`` rays."""
    if capture is None:
        return rays, PointLight(position=rays.origins, intensity=intensity)
    origins, directions = capture.refine_rays(rays.origins, rays.directions, ray_view)
    w2c = bank.R_T[ray_view[:n_lit]].transpose(1, 2)
    light_at = torch.cat([capture.flash_position(origins[:n_lit], w2c), origins[n_lit:]])
    return Rays(origins, directions), PointLight(position=light_at, intensity=intensity)


PROBE_PIXELS = 512
"""In-mask training pixels of the log's probe PSNR, drawn once per run."""


def probe_pixels(bank: PixelBank, cfg: TrainConfig, psf: PsfSampler) -> PixelBatch:
    """Fixed pixels and PSF rays for :func:`probe_psnr` (its own seed: the run's draws are untouched)."""
    gen = torch.Generator().manual_seed(cfg.seed + 7919)
    return bank.sample(PROBE_PIXELS, True, psf, psf_rays_per_pixel(cfg, 1, 1.0), gen)


def probe_psnr(fields: SceneFields, bank: PixelBank, probe: PixelBatch, cfg: TrainConfig, stage: int,
               intensity: Tensor, capture: CaptureTerms | None = None) -> float:
    """Train PSNR on the same pixels, rays and sample positions every time (no jitter): it changes
    only when the model does. The step's own PSNR also moves with which pixels a step drew: a few
    patches on an edge or a dark pip can take it down by 10 dB for a log line."""
    return psnr_of(*squared_error(render_pixels(fields, bank, probe, cfg, stage, intensity, capture), probe))


def render_pixels(fields: SceneFields, bank: PixelBank, batch: PixelBatch, cfg: TrainConfig, stage: int,
                  intensity: Tensor, capture: CaptureTerms | None = None) -> Tensor:
    """(G * P, 3) the batch's pixel estimates as ``stage`` renders them, without jitter or a graph."""
    rays, light = flash_lit(bank, batch.rays, batch.ray_view, batch.n_rays, intensity, capture)
    vr = volume_render(fields, rays, light, sampler_of_stage(cfg, stage), train_geometry=False, jitter=False,
                       with_albedo=capture is not None)
    rgb = batch.estimate(vr.result.rgb.detach())
    if capture is not None:
        rgb = capture.apply(rgb, batch.estimate(vr.albedo.detach()), batch.view, batch.r2).detach()
    return rgb.detach()


ERROR_MAP_CHUNK = 4096
"""Pixels rendered at a time for an error map's first measurement."""


def centre_squared_errors(fields: SceneFields, bank: PixelBank, rows: Tensor, cfg: TrainConfig,
                          intensity: Tensor, capture: CaptureTerms | None = None) -> Tensor:
    """(all bank rows,) the squared error of one stage-2 ray through the centre of each of the
    bank's pixels ``rows`` (rendered ERROR_MAP_CHUNK at a time), 0 at the other rows."""
    pixel_se = torch.zeros(len(bank.colour), device=bank.colour.device)
    with torch.no_grad():
        for lo in range(0, len(rows), ERROR_MAP_CHUNK):
            batch = bank.at_centres(rows[lo:lo + ERROR_MAP_CHUNK])
            pixel_se[rows[lo:lo + ERROR_MAP_CHUNK]] = pixel_squared_error(
                render_pixels(fields, bank, batch, cfg, 2, intensity, capture), batch)
    return pixel_se


def measure_error_map(fields: SceneFields, bank: PixelBank, cfg: TrainConfig, psf: PsfSampler,
                      intensity: Tensor, capture: CaptureTerms | None = None) -> ErrorMap:
    """Stage 2's error map (:mod:`srvol.error_map`, share ``cfg.stage2_importance``): one centre ray
    at every in-mask pixel, and each cell the mean over its pixels of the error of the group (patch)
    centred there."""
    error_map = ErrorMap(bank, cfg.stage2_importance)
    pixel_se = centre_squared_errors(fields, bank, bank.inside, cfg, intensity, capture)
    error_map.fill(patch_sums(bank, pixel_se, group_side(cfg, psf, 2)))
    return error_map


STAGE2_FIDELITY_DB = 0.25
"""Stage 2's few samples per ray must render the frozen model within this of stage 1's on the
probe pixels. On bumpy they do (16 + 4 gave +0.21 dB in 90 s against +0.10 at 32 + 12,
stage2_table.md); on the tuning scenes stool and airplane (thin parts, B-spline SDF) they lost
0.91 and 0.36 dB, and a step of stage 2 then fits the BRDF to the sampler's error."""

STAGE2_FAITHFUL_IMPORTANCE = 6
"""Gradient-carrying samples around the crossing in stage 2's fuller sampler (with stage 1's locating
samples): on stool's finished model it renders the probe pixels to 0.05 dB of stage 1's 32 + 12 (16 + 4:
0.91 dB below), at ~1.5x the cheap sampler's cost."""


@dataclass(frozen=True)
class Stage2Samples:
    """The sampler stage 2 trains with and why: the probe PSNR with stage 1's sampler and with stage
    2's cheap one (nan where there was no choice to make)."""

    sampler: SamplerConfig
    probe_stage1: float
    probe_cheap: float

    @property
    def widened(self) -> bool:
        return self.probe_stage1 - self.probe_cheap > STAGE2_FIDELITY_DB

    @property
    def measured(self) -> bool:
        """Whether there was a choice to make (stage 2 samples differently from stage 1)."""
        return not math.isnan(self.probe_stage1)


def choose_stage2_samples(fields: SceneFields, bank: PixelBank, probe: PixelBatch, cfg: TrainConfig,
                          intensity: Tensor, capture: CaptureTerms | None = None) -> Stage2Samples:
    """Once the geometry is frozen: keep stage 2's cheap sampler if it renders the probe pixels
    within STAGE2_FIDELITY_DB of stage 1's, else take stage 1's locating samples and
    STAGE2_FAITHFUL_IMPORTANCE gradient samples (the surface is where it was; only the
    quadrature changes)."""
    cheap, full = sampler_of_stage(cfg, 2), sampler_of_stage(cfg, 1)
    if cheap == full:
        return Stage2Samples(cheap, math.nan, math.nan)
    p_full = probe_psnr(fields, bank, probe, replace(cfg, stage2_sampler=full), 2, intensity, capture)
    p_cheap = probe_psnr(fields, bank, probe, cfg, 2, intensity, capture)
    choice = Stage2Samples(cheap, p_full, p_cheap)
    return Stage2Samples(faithful_stage2_sampler(cfg), p_full, p_cheap) if choice.widened else choice


def faithful_stage2_sampler(cfg: TrainConfig) -> SamplerConfig:
    """Stage 2's sampler with stage 1's locating samples and STAGE2_FAITHFUL_IMPORTANCE gradient ones."""
    cheap, full = sampler_of_stage(cfg, 2), sampler_of_stage(cfg, 1)
    return replace(cheap, n_coarse=max(cheap.n_coarse, full.n_coarse),
                   n_importance=max(cheap.n_importance, STAGE2_FAITHFUL_IMPORTANCE))


def anchor_fade(progress: float, cfg: TrainConfig) -> float:
    """The factor on the anchor terms (``lambda_anchor``, ``lambda_free_space``) at ``progress`` of
    the run: 1 falling linearly to 0 at ``anchor_fade``; 0 when both terms are off."""
    if not cfg.uses_stereo() or cfg.anchor_fade <= 0:
        return 0.0
    return max(0.0, 1.0 - progress / cfg.anchor_fade)


def compute_loss(fields: SceneFields, bank: PixelBank, cfg: TrainConfig, psf: PsfSampler, stage: int,
                 gen: torch.Generator, intensity: Tensor, progress: float = 1.0,
                 capture: CaptureTerms | None = None, shard: Shard = SINGLE,
                 anchors: AnchorPoints | None = None, error_map: ErrorMap | None = None) -> LossTerms:
    """L1 on in-mask pixels (PSF estimates) + lambda_e eikonal + lambda_m mask BCE (stage 1 only).
    ``progress`` in [0, 1] (share of the run done) selects the PSF rays per pixel (psf_warmup).
    ``capture``: each ray is lit by its photo's flash, and the pixel estimates pass through the
    photo's exposure, vignetting and ambient term before they meet the photo. ``shard``: this
    rank's share of the step; each term is divided by its count over all ranks, so the ranks'
    gradients sum to the whole step's (:mod:`srvol.distributed`). ``error_map``: draw the in-mask
    pixels where the error is, and write what this step measured back into it."""
    train_geo = cfg.trains_geometry(stage)
    whole = sample_pixels(bank, cfg, psf, stage, gen, progress, error_map)
    g_lo, g_hi = shard.span(whole.weights.shape[0])
    batch = whole.groups(g_lo, g_hi)
    rays, ray_view = batch.rays, batch.ray_view
    R = whole.weights.shape[2]
    rows = [torch.arange(g_lo * R, g_hi * R)]  # the rank's rays among the whole step's
    use_mask = stage == 1 and bank.has_masks and len(bank.outside) > 0
    if use_mask:
        o_lo, o_hi = shard.span(cfg.batch_out)
        out = bank.sample(cfg.batch_out, False, psf, 1, gen, near_share=cfg.silhouette_rays).groups(o_lo, o_hi)
        rays = Rays(torch.cat([rays.origins, out.rays.origins]), torch.cat([rays.directions, out.rays.directions]))
        ray_view = torch.cat([ray_view, out.ray_view])
        rows.append(whole.n_rays + torch.arange(o_lo, o_hi))
    jitter = True if shard.world == 1 else RayRows(torch.cat(rows).to(rays.origins.device),
                                                   whole.n_rays + (cfg.batch_out if use_mask else 0))
    n_pix_rays = batch.n_rays
    rays, light = flash_lit(bank, rays, ray_view, n_pix_rays, intensity, capture)
    shade_rays = torch.arange(len(rays), device=rays.origins.device) < n_pix_rays
    vr = volume_render(fields, rays, light, sampler_of_stage(cfg, stage), train_geometry=train_geo, jitter=jitter,
                       shade_rays=shade_rays, with_albedo=capture is not None)
    rgb = batch.estimate(vr.result.rgb[:n_pix_rays])
    if capture is not None:
        rgb = capture.apply(rgb, batch.estimate(vr.albedo[:n_pix_rays]), batch.view, batch.r2)
    eik = torch.zeros(())
    mask_loss = torch.zeros(())
    smooth = torch.zeros(())
    if train_geo:
        e_lo, e_hi = shard.span(cfg.batch_eikonal)
        pts = (torch.rand(cfg.batch_eikonal, 3, generator=gen) * 2 - 1)[e_lo:e_hi].to(rgb.device)
        _, g_rand = fields.sdf_and_gradient(pts, create_graph=True)
        gradients = torch.cat([g_rand, vr.sdf_gradients])
    else:
        gradients = torch.zeros(0, 3)
    n_mask = batch.n_pixels + len(rays) - n_pix_rays if use_mask else 0
    fg_count, eik_count, mask_count = shard.total(float(batch.pixel_weight.sum()), len(gradients), n_mask)
    photometric = photometric_l1(rgb, batch, fg_count, cfg.photometric_clip)
    total = photometric
    if train_geo:
        eik = eikonal(gradients, eik_count)
        total = total + cfg.lambda_eikonal * eik
        if use_mask:
            op_in = batch.estimate(vr.result.opacity[:n_pix_rays, None])[:, 0]
            mask_loss = mask_bce(op_in, batch.mask, vr.result.opacity[n_pix_rays:], mask_count)
            total = total + cfg.lambda_mask * mask_loss
        if cfg.lambda_smooth > 0:
            if shard.world > 1:
                raise SrvolError("--normal-smoothness does not run with --distributed")
            pts = surface_points(Rays(rays.origins[:n_pix_rays], rays.directions[:n_pix_rays]),
                                 vr.result.depth[:n_pix_rays], vr.result.opacity[:n_pix_rays], cfg.batch_smooth, gen)
            if len(pts):
                smooth = normal_smoothness(fields, pts, fields.finest_sdf_cell() or SMOOTH_SPREAD_MLP, gen)
                total = total + cfg.lambda_smooth * smooth
        fade = anchor_fade(progress, cfg)
        if anchors is not None and fade > 0:
            # every rank draws the same points (one generator state): its share is 1 / world of the terms
            at = anchor_terms(fields.sdf, anchors.points, anchors.eyes, cfg.batch_anchor, gen, cfg.sampler.bound)
            total = total + fade * (cfg.lambda_anchor * at.pull + cfg.lambda_free_space * at.free_space) / shard.world
    se, pixels = squared_error(rgb, batch)
    if error_map is not None and whole.centre is not None:  # every rank writes the whole step's errors
        error_map.update(whole.centre, shard.gather_span(group_squared_error(rgb, batch), g_lo, len(whole.centre)))
    # the logged figures speak of the whole step: sums over the ranks (each rank's share of a mean)
    se, pixels, ph, ek, mk = shard.total(se, pixels, float(photometric.detach()), float(eik.detach()),
                                         float(mask_loss.detach()))
    return LossTerms(total=total, photometric=ph, eikonal=ek, mask=mk, smooth=float(smooth.detach()),
                     squared_error=se, pixels=pixels)
