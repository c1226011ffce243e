"""SuperRVol training: stage 1 learns geometry and BRDF, stage 2 freezes geometry and refines the BRDF.

Loss (DESIGN.md section 3), each term normalised by its batch size:

    L = L1(LR pixel estimate, input)  over in-mask pixels
      + lambda1 * mean (|grad d| - 1)^2  over random points and the ray samples
      + lambda2 * BCE(opacity, mask)     over in- and out-of-mask pixels

An LR pixel is estimated as the mean of S rays through sub-pixel offsets drawn
from the PSF (``--sr gaussian``), through the HR pixel centres (``box``), or
one ray through the centre (``none``).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from srvol.checkpoint import CONFIG_VERSION, load_checkpoint, save_checkpoint, save_snapshot, write_model
from srvol.data import Scene
from srvol.errors import SrvolError
from srvol.fields import FieldConfig, SceneFields
from srvol.pixels import PixelBank, PixelBatch
from srvol.psf import SRMode, lattice_size
from srvol.render import SamplerConfig, volume_render
from srvol.types import PointLight, Rays


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a run; saved as config.json (plain JSON, versioned)."""

    preset: str
    fields: FieldConfig
    sampler: SamplerConfig
    sr: str = "gaussian"
    psf_samples: int = 4
    """gaussian: rays per LR pixel (Monte Carlo) / rays-per-pixel budget of a lattice step."""
    psf_sampler: str = "mc"
    """gaussian only: "mc" (the paper: psf_samples i.i.d. rays per pixel), "antithetic" (psf_samples
    rays per pixel in rotated antithetic groups {g, -g, Jg, -Jg}) or "lattice" (shared, randomly
    shifted lattice of rays over patch x patch LR pixels)."""
    psf_warmup: float = 0.0
    """gaussian per-pixel samplers (mc, antithetic) only: for this fraction of training (time or iterations) each LR pixel
    gets one ray at a Gaussian-distributed sub-pixel offset and a step takes psf_samples times as
    many pixels (same rays per step); then psf_samples rays per pixel. The first phase settles the
    geometry from many pixels; the second resolves the PSF integral. 0 = the paper's schedule."""
    stage2_psf_sampler: str = ""
    """gaussian only: the sampler of stage 2 (geometry frozen), "" = psf_sampler. A lattice suits
    stage 2: its deterministic Gaussian weights give the BRDF low-noise gradients, and the
    argument against it in stage 1 (4x4-pixel patches show the geometry fewer, less varied
    pixels per step) no longer applies."""
    stage2_sampler: SamplerConfig | None = None
    """Samples per ray in stage 2 (geometry and beta frozen), None = ``sampler``. With the surface
    fixed and beta small, a few samples around the first crossing carry the whole VolSDF weight, and
    the locating pass only has to bracket a surface it no longer moves."""
    patch: int = 4
    lattice_cell: float = 0.5
    """Lattice spacing in LR pixels."""
    batch_in: int = 256
    batch_out: int = 256
    batch_eikonal: int = 256
    batch_stage2: int = 700
    lr: float = 5e-3
    lr_final: float = 5e-4
    lr_grid: float = 1e-2
    lr_spec: float = 1e-3
    lr_beta: float = 1e-2
    lambda_eikonal: float = 0.1
    lambda_mask: float = 0.1
    iters: int = 0
    """Total iterations of both stages; 0 = run until ``time_budget``."""
    time_budget: float = 600.0
    stage2_fraction: float = 0.15
    checkpoint_every: int = 200
    log_every: int = 25
    snapshots: int = 0
    """Save the fields this many times, evenly over training, in RUN/snapshots/ (for quality-vs-time charts)."""
    seed: int = 0
    device: str = "cpu"
    reasons: tuple[str, ...] = ()

    def to_json(self) -> dict:
        d = asdict(self)
        d["fields"] = self.fields.to_json()
        d["reasons"] = list(self.reasons)
        d["version"] = CONFIG_VERSION
        return d

    @staticmethod
    def from_json(d: dict) -> "TrainConfig":
        d = dict(d)
        d.pop("version", None)
        d["fields"] = FieldConfig.from_json(d["fields"])
        d["sampler"] = SamplerConfig(**d["sampler"])
        if d.get("stage2_sampler"):
            d["stage2_sampler"] = SamplerConfig(**d["stage2_sampler"])
        d["reasons"] = tuple(d.get("reasons", ()))
        known = TrainConfig.__dataclass_fields__
        return TrainConfig(**{k: v for k, v in d.items() if k in known})


@dataclass(frozen=True)
class LossTerms:
    total: torch.Tensor
    photometric: float
    eikonal: float
    mask: float
    psnr: float


@dataclass
class TrainState:
    step: int = 0
    stage: int = 1
    elapsed: float = 0.0
    lr_scale: float = 1.0
    rollbacks: int = 0


def paper_config(sr: str = "gaussian", psf_samples: int = 25, iters: int = 300_000) -> TrainConfig:
    """The paper's recipe (meant for a GPU: days of training)."""
    return TrainConfig(preset="paper", fields=FieldConfig(kind="paper"),
                       sampler=SamplerConfig(n_coarse=64, n_importance=32, n_uniform=2),
                       sr=sr, psf_samples=psf_samples, batch_in=100, batch_out=500, batch_eikonal=1000,
                       batch_stage2=700, lr=5e-4, lr_final=5e-5, lr_grid=5e-4, lr_spec=1e-5, lr_beta=5e-4, iters=iters,
                       time_budget=0.0, stage2_fraction=0.1)


STAGE2_SAMPLER = SamplerConfig(n_coarse=16, n_importance=3, n_uniform=1)
"""The fast presets' stage-2 samples per ray: on the default scene's finished 600 s run its colours
differ from a 128 + 68-sample render by 0.001 on average (the stage-1 sampler's: 0.0002) and a
stage-2 step takes 2.1x less time (bench/results/stage2_table.md)."""


AUTO_STAGE2_FRACTION = 0.3
"""auto's share of the time budget for stage 2 (BRDF refinement on frozen geometry)."""


def fast_config(sr: str = "gaussian", psf_samples: int = 4) -> TrainConfig:
    return TrainConfig(preset="fast", fields=FieldConfig(kind="grid"), sampler=SamplerConfig(),
                       stage2_sampler=STAGE2_SAMPLER, sr=sr, psf_samples=psf_samples)


def hr_pixel_size(scene: Scene) -> float:
    """Scene units covered by one HR pixel at the object's distance (median over training views)."""
    sizes = []
    for v in scene.train_views():
        dist = float(v.camera.center.norm())
        sizes.append(dist / float(v.camera.K[0, 0]) / scene.info.sr_factor)
    return float(np.median(sizes))


MTF_FLOOR = 0.1
"""Frequencies the PSF attenuates below this contrast are treated as lost (not recoverable by SR)."""


def recoverable_cell_hr_px(sigma_hr_px: float) -> float:
    """Half the shortest period (in HR pixels) that a Gaussian PSF of ``sigma_hr_px`` passes
    with contrast >= MTF_FLOOR: the finest cell a reconstruction can be supervised at.

    The Gaussian's MTF is exp(-2 pi^2 sigma^2 f^2); it falls to MTF_FLOOR at
    f = sqrt(ln(1 / MTF_FLOOR) / 2) / (pi sigma) cycles per HR pixel. Finer detail is below
    1/10 contrast in every LR image, so grid cells finer than this only fit noise (hash
    collisions and Monte Carlo PSF noise show as grain). Never below one HR pixel.
    For the default scene (sigma 1.5 HR px): f = 0.23, period 4.4 px, cell 2.2 HR px.
    """
    if sigma_hr_px <= 0:
        return 1.0
    f = math.sqrt(math.log(1.0 / MTF_FLOOR) / 2.0) / (math.pi * sigma_hr_px)
    return max(1.0, 0.5 / f)


def auto_config(scene: Scene, sr: str, time_budget: float, capacity: float = 1.0) -> TrainConfig:
    """Capacity derived from the scene: resolution from the HR pixel footprint, PSF samples
    from the PSF width, batch from the object's footprint; reasons are printed and saved.

    ``capacity`` scales the derived model (grid resolutions, hash table, head widths) for
    the capacity study: 0.5 = half, 2 = double; 1 is what the scene needs.
    """
    hr = hr_pixel_size(scene)
    reasons = [f"HR pixel footprint {hr:.4f} scene units (object distance / focal / sr)"]
    # Material detail: the finest hash level resolves the shortest period the LR images still carry.
    detail_px = recoverable_cell_hr_px(scene.info.psf_sigma_lr_px * scene.info.sr_factor)
    mat_max = int(2 ** math.ceil(math.log2(2.0 / (detail_px * hr))))
    mat_max = max(64, min(mat_max, 2048))
    # Geometry: finest SDF level ~ 6 HR pixels per cell (smoothstep interpolation keeps
    # normals continuous; finer shape detail shows through shading); three levels, each x2.
    fine = int(min(128, max(32, round(2.0 / (6 * hr) / 8) * 8)))
    base = FieldConfig()
    table_log2, hidden = base.mat_table_log2, base.sdf_hidden
    if capacity != 1.0:
        fine = max(8, int(round(fine * capacity / 4)) * 4)
        mat_max = max(16, int(round(mat_max * capacity)))
        table_log2 = max(10, base.mat_table_log2 + int(round(3 * math.log2(capacity))))
        hidden = max(8, int(round(base.sdf_hidden * capacity)))
        reasons.append(f"capacity x{capacity:g} of what the scene needs (study setting)")
    reasons.append(f"material hash grid finest level {mat_max} (cell {2 / mat_max:.4f}; the PSF leaves detail "
                   f"down to {detail_px:.1f} HR pixels of {hr:.4f})")
    levels = (max(4, fine // 4), max(4, fine // 2), fine)
    reasons.append(f"SDF grids {levels} (finest cell {2 / fine:.4f} ~ {2 / fine / hr:.0f} HR pixels)")
    mode = SRMode(sr)
    sigma = scene.info.psf_sigma_lr_px
    cell = 0.5
    if mode == SRMode.GAUSSIAN:
        # The Monte Carlo PSF estimate is unbiased for any count, so the count trades the noise of
        # each pixel's estimate against pixels per step (the geometry learns from many, varied
        # pixels). One antithetic pair {g, -g} per (0.4 LR px)^2 of PSF spread: 2 rays for the
        # default scene's sigma 0.375. Measured there at 600 s (256 pixels x 2 rays per step vs
        # 128 x 4 and 512 x 1, the same 512 rays): 39.80 dB HR PSNR vs 39.45 and 38.63 (views 040-042).
        ns = int(min(16, 2 * math.ceil((sigma / 0.4) ** 2)))
        reasons.append(f"PSF samples {ns} per LR pixel and step (sigma {sigma} LR px; one antithetic pair "
                       f"per (0.4 LR px)^2 of PSF spread)")
        # The shared lattice (--psf-sampler lattice) would use a spacing of ~4/3 sigma, between one
        # HR pixel and half an LR pixel. Measured at 600 s on the default scene it was not better than
        # i.i.d. Monte Carlo rays (38.25 vs 38.39 dB, normals 3.4 vs 3.1 deg: 4x4-pixel patches give
        # the geometry less varied pixels per step); antithetic groups beat both (train_table.md).
        cell = float(min(0.5, max(1.0 / scene.info.sr_factor, 4.0 * sigma / 3.0)))
        reasons.append("PSF rays in antithetic pairs {g, -g} (rotated groups {g, -g, Jg, -Jg} from 4 rays): each "
                       "still drawn from the Gaussian, the group's error is zero where the image varies linearly")
        reasons.append("stage 2 (geometry frozen): shared ray lattices with Gaussian weights -- low-noise PSF "
                       "estimates for the BRDF (90 more seconds of stage 2 on a finished 600 s run, 32 + 12 samples "
                       "per ray: +0.10 dB HR PSNR vs -1.44 dB with antithetic pairs, -1.95 dB with 2 i.i.d. rays -- "
                       "the L1 of a noisy estimate pulls towards images flat within each pixel -- and -0.05 dB for "
                       "noSR; stage2_table.md)")
    elif mode == SRMode.BOX:
        ns = scene.info.sr_factor ** 2
        reasons.append(f"box PSF: {ns} rays per LR pixel (sr {scene.info.sr_factor})")
    else:
        ns = 1
    n_in = int(sum(v.mask.sum() if v.mask is not None else v.image.shape[0] * v.image.shape[1]
                   for v in scene.train_views()))
    # Rays per step bounded so that one step stays ~0.1-0.2 s on 2 cores.
    batch_in = int(max(64, min(512, 512 // ns)))
    batch_stage2 = int(max(64, TrainConfig.batch_stage2 // ns))  # the paper's 700 rays per step
    fields = FieldConfig(kind="grid", sdf_levels=levels, mat_max_res=mat_max, mat_table_log2=table_log2,
                         sdf_hidden=hidden, mat_hidden=hidden)
    stage1 = SamplerConfig()
    reasons.append(f"stage 2 (geometry frozen): {STAGE2_SAMPLER.n_coarse} locating + "
                   f"{STAGE2_SAMPLER.gradient_samples} gradient samples per ray (stage 1: {stage1.n_coarse} + "
                   f"{stage1.gradient_samples}): the surface no longer moves and beta is small, so a few samples "
                   "around the crossing carry its weight; 2.1x the stage-2 steps in the same time, +0.21 dB in 90 s "
                   "vs +0.10 (stage2_table.md)")
    reasons.append(f"stage 2 takes {AUTO_STAGE2_FRACTION:.0%} of the budget (paper: 10%): its steps are cheap and it "
                   "keeps gaining (default scene, 600 s, 8 held-out views: 38.79 dB HR PSNR at 30% vs 38.22 at 15%; "
                   "train_table.md)")
    cfg = TrainConfig(preset="auto", fields=fields, sampler=stage1, stage2_sampler=STAGE2_SAMPLER,
                      stage2_fraction=AUTO_STAGE2_FRACTION, sr=sr, psf_samples=ns,
                      psf_sampler="antithetic" if mode == SRMode.GAUSSIAN else "mc",
                      stage2_psf_sampler="lattice" if mode == SRMode.GAUSSIAN else "", patch=4, lattice_cell=cell,
                      batch_in=batch_in, batch_out=max(64, batch_in // 2), batch_stage2=batch_stage2,
                      time_budget=time_budget)
    reasons.append(f"{n_in} in-mask training pixels; {batch_in} per step x {ns} rays "
                   f"(stage 2: {rays_per_step(cfg, 2)} rays per step)")
    reasons.append(f"time budget {time_budget:.0f} s for both stages")
    return replace(cfg, reasons=tuple(reasons))


# ----------------------------------------------------------------------------- optimisation

def make_optimizers(fields: SceneFields, cfg: TrainConfig, stage: int) -> list[torch.optim.Optimizer]:
    albedo_p, spec_p, table_p = fields.material_groups()
    opts: list[torch.optim.Optimizer] = []
    groups = []
    if stage == 1:
        if cfg.fields.kind == "grid":
            grid_p = [fields.sdf_net.grids.table]
            head_p = list(fields.sdf_net.head.parameters())
            groups += [{"params": grid_p, "lr": cfg.lr_grid, "base_lr": cfg.lr_grid},
                       {"params": head_p, "lr": cfg.lr, "base_lr": cfg.lr}]
        else:
            groups.append({"params": list(fields.sdf_net.parameters()), "lr": cfg.lr, "base_lr": cfg.lr})
        groups.append({"params": [fields.log_beta], "lr": cfg.lr_beta, "base_lr": cfg.lr_beta})
    groups += [{"params": albedo_p, "lr": cfg.lr, "base_lr": cfg.lr},
               {"params": spec_p, "lr": cfg.lr_spec, "base_lr": cfg.lr_spec}]
    if table_p:
        groups.append({"params": table_p, "lr": cfg.lr_grid, "base_lr": cfg.lr_grid})
    if fields.log_intensity.requires_grad:
        groups.append({"params": [fields.log_intensity], "lr": cfg.lr, "base_lr": cfg.lr})
    # fused Adam: one kernel over all parameters (large grids), ~7x faster than the loop on CPU
    opts.append(torch.optim.Adam(groups, betas=(0.9, 0.99), eps=1e-15, fused=True))
    return opts


def set_learning_rate(opts, progress: float, cfg: TrainConfig, scale: float) -> None:
    """Exponential decay from base_lr to base_lr * lr_final / lr over training."""
    decay = (cfg.lr_final / cfg.lr) ** min(max(progress, 0.0), 1.0)
    for opt in opts:
        for g in opt.param_groups:
            g["lr"] = g["base_lr"] * decay * scale


def psf_sampler_of_stage(cfg: TrainConfig, stage: int) -> str:
    """The PSF sampler in use in ``stage`` (1 or 2)."""
    return cfg.stage2_psf_sampler if stage == 2 and cfg.stage2_psf_sampler else cfg.psf_sampler


def sampler_of_stage(cfg: TrainConfig, stage: int) -> SamplerConfig:
    """The samples per ray in ``stage`` (1 or 2)."""
    return cfg.stage2_sampler if stage == 2 and cfg.stage2_sampler is not None else cfg.sampler


def describe_ray_samples(cfg: TrainConfig) -> str:
    """Samples per ray, in words (printed by train)."""
    def words(s: SamplerConfig) -> str:
        return f"{s.n_coarse} locating + {s.gradient_samples} gradient samples per ray"

    text = words(cfg.sampler)
    if cfg.stage2_sampler is not None and cfg.stage2_sampler != cfg.sampler and cfg.stage2_fraction > 0:
        text += f" (stage 2: {words(cfg.stage2_sampler)})"
    return text


def describe_psf_rays(cfg: TrainConfig, sigma_lr_px: float) -> str:
    """How each LR pixel is estimated, in words (printed by train, shown by report and the benchmark)."""
    gaussian = cfg.sr == SRMode.GAUSSIAN.value

    def words(sampler: str) -> str:
        if gaussian and sampler == "lattice":
            k, p = lattice_size(cfg.patch, cfg.lattice_cell, sigma_lr_px), cfg.patch
            return f"shared {k}x{k} lattices over {p}x{p} LR pixels ({k * k / p ** 2:.1f} rays per LR pixel)"
        text = f"{cfg.psf_samples} {'ray' if cfg.psf_samples == 1 else 'rays'} per LR pixel"
        if gaussian and sampler == "antithetic" and cfg.psf_samples > 1:
            text += " as an antithetic pair" if cfg.psf_samples == 2 else " in rotated antithetic groups"
        return text

    text = words(cfg.psf_sampler)
    if gaussian and cfg.psf_warmup > 0:
        text += f" (1 for the first {cfg.psf_warmup:.0%} of training)"
    second = psf_sampler_of_stage(cfg, 2)
    if gaussian and second != cfg.psf_sampler and cfg.stage2_fraction > 0:
        text += f"; stage 2: {words(second)}"
    return text


def psf_rays_per_pixel(cfg: TrainConfig, stage: int, progress: float) -> int:
    """Monte Carlo PSF rays per LR pixel at this point of training (see TrainConfig.psf_warmup)."""
    per_pixel = cfg.psf_sampler in ("mc", "antithetic")
    if cfg.sr == SRMode.GAUSSIAN.value and per_pixel and stage == 1 and progress < cfg.psf_warmup:
        return 1
    return cfg.psf_samples


def rays_per_step(cfg: TrainConfig, stage: int) -> int:
    """In-mask rays a step of ``stage`` traces (the lattice samplers round it to whole patches)."""
    return (cfg.batch_in if stage == 1 else cfg.batch_stage2) * cfg.psf_samples


def take_step(opts: list[torch.optim.Optimizer], loss: torch.Tensor) -> None:
    """One optimiser step on ``loss``."""
    for o in opts:
        o.zero_grad(set_to_none=True)
    loss.backward()
    for o in opts:
        o.step()


def sample_pixels(bank: PixelBank, cfg: TrainConfig, sigma: float, sr: int, stage: int,
                  gen: torch.Generator, progress: float = 1.0) -> PixelBatch:
    """The in-mask pixels of one step and their rays: per-pixel rays or shared lattice patches."""
    mode = SRMode(cfg.sr)
    sampler = psf_sampler_of_stage(cfg, stage)
    if mode == SRMode.GAUSSIAN and sampler == "lattice":
        rays_per_patch = lattice_size(cfg.patch, cfg.lattice_cell, sigma) ** 2
        n = max(1, round(rays_per_step(cfg, stage) / rays_per_patch))
        return bank.sample_patches(n, cfg.patch, cfg.lattice_cell, sigma, gen)
    ns = psf_rays_per_pixel(cfg, stage, progress)
    return bank.sample(rays_per_step(cfg, stage) // ns, True, mode, ns, sigma, sr, gen,
                       antithetic=sampler == "antithetic")


def compute_loss(fields: SceneFields, bank: PixelBank, cfg: TrainConfig, sigma: float, sr: int, stage: int,
                 gen: torch.Generator, intensity: torch.Tensor, progress: float = 1.0) -> LossTerms:
    """L1 on in-mask pixels (PSF estimates) + lambda_e eikonal + lambda_m mask BCE (stage 1 only).
    ``progress`` in [0, 1] (share of the run done) selects the PSF rays per pixel (psf_warmup)."""
    mode = SRMode(cfg.sr)
    train_geo = stage == 1
    batch = sample_pixels(bank, cfg, sigma, sr, stage, gen, progress)
    rays = batch.rays
    use_mask = train_geo and bank.has_masks and len(bank.outside) > 0
    if use_mask:
        out = bank.sample(cfg.batch_out, False, mode, 1, sigma, sr, gen)
        rays = Rays(torch.cat([rays.origins, out.rays.origins]), torch.cat([rays.directions, out.rays.directions]))
    light = PointLight(position=rays.origins, intensity=intensity)
    n_pix_rays = batch.n_rays
    shade_rays = torch.arange(len(rays), device=rays.origins.device) < n_pix_rays
    vr = volume_render(fields, rays, light, sampler_of_stage(cfg, stage), train_geometry=train_geo,
                       shade_rays=shade_rays)
    rgb = batch.estimate(vr.result.rgb[:n_pix_rays])
    # photometric term on foreground pixels only (a lattice patch may reach past the silhouette)
    fg = batch.mask
    photometric = ((rgb - batch.target).abs().mean(-1) * fg).sum() / fg.sum().clamp_min(1.0)
    total = photometric
    eik = torch.zeros(())
    mask_loss = torch.zeros(())
    if train_geo:
        pts = (torch.rand(cfg.batch_eikonal, 3, generator=gen) * 2 - 1).to(rgb.device)
        _, g_rand = fields.sdf_and_gradient(pts, create_graph=True)
        g_all = torch.cat([g_rand, vr.sdf_gradients])
        eik = ((g_all.norm(dim=-1) - 1.0) ** 2).mean()
        total = total + cfg.lambda_eikonal * eik
        if use_mask:
            op_in = batch.estimate(vr.result.opacity[:n_pix_rays, None])[:, 0]
            op_out = vr.result.opacity[n_pix_rays:]
            op = torch.cat([op_in, op_out]).clamp(1e-4, 1 - 1e-4)
            tgt = torch.cat([batch.mask, torch.zeros_like(op_out)])
            mask_loss = F.binary_cross_entropy(op, tgt)
            total = total + cfg.lambda_mask * mask_loss
    sq = (rgb.detach().clamp(0, 1) - batch.target.clamp(0, 1)) ** 2
    mse = ((sq.mean(-1) * fg).sum() / fg.sum().clamp_min(1.0)).clamp_min(1e-10)
    return LossTerms(total=total, photometric=float(photometric.detach()), eikonal=float(eik.detach()),
                     mask=float(mask_loss.detach()),
                     psnr=float(-10 * torch.log10(mse)))


def check_not_collapsed(fields: SceneFields, device) -> str | None:
    """A one-line reason when the SDF has no surface (all positive or all negative) in the unit sphere."""
    with torch.no_grad():
        g = torch.linspace(-0.95, 0.95, 24, device=device)
        pts = torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        pts = pts[pts.norm(dim=-1) < 0.95]
        d = fields.sdf(pts)
    if not torch.isfinite(d).all():
        return "the SDF became non-finite"
    if (d > 0).all():
        return "the SDF collapsed: no surface inside the unit sphere (everything is empty)"
    if (d < 0).all():
        return "the SDF collapsed: the unit sphere is entirely inside the object"
    return None


# ----------------------------------------------------------------------------- the loop

@dataclass(frozen=True)
class TrainSummary:
    iterations: int
    train_seconds: float
    final_psnr: float
    rollbacks: int


def train(scene: Scene, cfg: TrainConfig, run_dir: Path, resume: bool = False, progress: bool = True,
          say=print) -> TrainSummary:
    """Train on ``scene`` into ``run_dir`` (config.json, checkpoints/, log.jsonl, model.pt)."""
    device = torch.device(cfg.device)
    run_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    learn_I = scene.info.light_intensity is None
    fields = SceneFields(cfg.fields, learn_intensity=learn_I).to(device)
    fixed_I = None if learn_I else torch.tensor(scene.info.light_intensity, dtype=torch.float32, device=device)
    bank = PixelBank(scene, device)
    state = TrainState()
    ckpt_dir = run_dir / "checkpoints"
    opts = make_optimizers(fields, cfg, 1)
    if resume:
        loaded = load_checkpoint(ckpt_dir, fields)
        if loaded is None:
            raise SrvolError(f"{ckpt_dir}: nothing to resume (no checkpoint)")
        state, opt_states, gen_state = loaded
        opts = make_optimizers(fields, cfg, state.stage)
        for o, s in zip(opts, opt_states):
            o.load_state_dict(s)
        gen.set_state(gen_state)
        say(f"resuming at step {state.step} (stage {state.stage}, {state.elapsed:.0f} s trained)")
    sigma, sr = scene.info.psf_sigma_lr_px, scene.info.sr_factor
    budget = cfg.time_budget if cfg.iters == 0 else 0.0
    stage2_at = int(cfg.iters * (1 - cfg.stage2_fraction)) if cfg.iters else None
    log_path = run_dir / "log.jsonl"
    t_start = time.time() - state.elapsed
    bar = tqdm(total=cfg.iters or int(budget), disable=not progress, unit="it" if cfg.iters else "s",
               desc="train", initial=state.step if cfg.iters else int(state.elapsed))
    last = None
    last_good_step = state.step
    snaps_done = len(list((run_dir / "snapshots").glob("*.pt"))) if cfg.snapshots else 0
    step_seconds = 0.0  # the last step's duration: the estimate of the next one's
    stage2_skipped = False
    while True:
        elapsed = time.time() - t_start
        if cfg.iters:
            if state.step >= cfg.iters:
                break
            progress_frac = state.step / cfg.iters
            want_stage = 2 if state.step >= stage2_at and cfg.stage2_fraction > 0 else 1
        else:
            progress_frac = elapsed / budget
            want_stage = 2 if progress_frac >= 1 - cfg.stage2_fraction and cfg.stage2_fraction > 0 else 1
            # Stop when the next step would end past the budget (a paper-preset step on a CPU takes
            # ~25 s). The first step of stage 2 is estimated from stage 1's by their rays per step;
            # when it would not fit, stage 1 goes on instead.
            if want_stage != state.stage:
                first = step_seconds * rays_per_step(cfg, want_stage) / rays_per_step(cfg, state.stage)
                if elapsed + first >= budget:
                    if not stage2_skipped:
                        say(f"stage 2 skipped: its first step (~{first:.0f} s) would end past the budget")
                        stage2_skipped = True
                    want_stage = state.stage
            if elapsed + step_seconds >= budget:
                break
        if want_stage != state.stage:
            state.stage = want_stage
            for p in fields.geometry_parameters():
                p.requires_grad_(False)
            opts = make_optimizers(fields, cfg, 2)
            say(f"stage 2 at step {state.step}: geometry frozen, refining the BRDF "
                f"({rays_per_step(cfg, 2)} rays per step)")
        set_learning_rate(opts, progress_frac, cfg, state.lr_scale)
        intensity = fixed_I if fixed_I is not None else fields.intensity
        terms = compute_loss(fields, bank, cfg, sigma, sr, state.stage, gen, intensity, progress_frac)
        if not torch.isfinite(terms.total):
            state.rollbacks += 1
            if state.rollbacks > 5:
                raise SrvolError("training diverged: the loss stayed non-finite after 5 rollbacks")
            loaded = load_checkpoint(ckpt_dir, fields)
            state.lr_scale *= 0.5
            if loaded is not None:
                st, opt_states, gen_state = loaded
                state.step, state.stage = st.step, st.stage
                opts = make_optimizers(fields, cfg, state.stage)
                for o, s in zip(opts, opt_states):
                    o.load_state_dict(s)
            say(f"non-finite loss at step {state.step}: rolled back to step {last_good_step} "
                f"with learning rate x{state.lr_scale:g}")
            continue
        take_step(opts, terms.total)
        state.step += 1
        last = terms
        state.elapsed = time.time() - t_start
        step_seconds = state.elapsed - elapsed
        if state.step % cfg.log_every == 0:
            rec = {"step": state.step, "stage": state.stage, "seconds": round(state.elapsed, 2),
                   "loss": round(float(terms.total.detach()), 6), "l1": round(terms.photometric, 6),
                   "eikonal": round(terms.eikonal, 6), "mask": round(terms.mask, 6),
                   "psnr": round(terms.psnr, 3), "beta": round(float(fields.beta.detach()), 6)}
            with open(log_path, "a") as f:
                f.write(json.dumps(rec) + "\n")
            bar.set_postfix(loss=f"{float(terms.total.detach()):.4f}", psnr=f"{terms.psnr:.2f}", stage=state.stage)
        if cfg.iters:
            bar.update(1)
        else:
            bar.n = min(int(state.elapsed), int(budget))
            bar.refresh()
        if cfg.snapshots and snaps_done < cfg.snapshots:
            frac = state.step / cfg.iters if cfg.iters else state.elapsed / budget
            if frac >= (snaps_done + 1) / cfg.snapshots - 1e-9 or frac >= 1.0:
                snaps_done += 1
                save_snapshot(run_dir / "snapshots", fields, state.step, state.elapsed)
        if state.step % cfg.checkpoint_every == 0:
            reason = check_not_collapsed(fields, device)
            if reason:
                raise SrvolError(f"step {state.step}: {reason}")
            save_checkpoint(ckpt_dir, fields, opts, state, gen.get_state())
            last_good_step = state.step
    bar.close()
    reason = check_not_collapsed(fields, device)
    if reason:
        raise SrvolError(reason)
    save_checkpoint(ckpt_dir, fields, opts, state, gen.get_state())
    if cfg.snapshots and snaps_done < cfg.snapshots:
        save_snapshot(run_dir / "snapshots", fields, state.step, state.elapsed)
    write_model(run_dir, fields)
    return TrainSummary(iterations=state.step, train_seconds=state.elapsed,
                        final_psnr=last.psnr if last else float("nan"), rollbacks=state.rollbacks)
