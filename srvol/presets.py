"""The presets, and the rules that derive a run from its scene.

* :func:`paper_config` -- the paper's recipe (a GPU run);
* :func:`fast_config` -- CPU-first;
* :func:`auto_config` -- ``fast`` with capacity, samples and schedules derived from the scene;
  every choice is printed with its reason, and the reasons quote figures measured on the
  scene suite's tuning set (``srvol synth --list``), never its report set.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from srvol.capture.frame import read_normalization
from srvol.capture.terms import CaptureTermsConfig
from srvol.config import TrainConfig, hr_pixel_size, rays_per_step
from srvol.data import Scene
from srvol.error_map import STAGE2_IMPORTANCE
from srvol.fields import FieldConfig
from srvol.psf import SRMode
from srvol.render import SamplerConfig


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


AUTO_CAPTURE_TERMS = CaptureTermsConfig(exposure=True, vignetting=True, ambient=False, pose=False)

AUTO_STAGE2_FRACTION = 0.3
"""auto's share of the time budget for stage 2 (the BRDF refined through the PSF, beta fixed)."""

BETA_ANNEAL = 0.3
"""auto: share of the run over which beta's cap falls from 0.1 to the HR pixel footprint."""

GEOMETRY_LR_TAIL = 0.1
"""auto: the further factor the SDF's learning rates fall by over the second half of stage 1."""

STAGE2_GEOMETRY_LR = 3.0
"""auto: stage 2's SDF learning rate, times the one stage 1 ended with (0 = frozen, the paper)."""

THIN_SHARE = 0.03
"""auto: masks with at least this share of their pixels in parts narrower than the locating
samples' spacing turn on the thin-parts sampling (refining samples, silhouette rays). On the
tuning set: stool 9.0%, airplane 1.3%, the rest 0.0%; 3% is the gap's geometric middle."""

THIN_REFINE_SAMPLES = 8
THIN_SILHOUETTE_RAYS = 0.5
THIN_PARTS_RECIPE = ("--refine-samples", str(THIN_REFINE_SAMPLES), "--silhouette-rays", str(THIN_SILHOUETTE_RAYS))
"""What auto adds for a scene with thin parts, as the flags that add it to any run."""


def thin_share(masks: list[np.ndarray], width_lr_px: float) -> float:
    """Mean share of the masks' pixels that a morphological opening with a disc about
    ``width_lr_px`` across (radius ceil(width / 2)) removes: the parts of the silhouette narrower than
    that (legs, rails, handles). 0 for no masks."""
    from skimage.morphology import binary_opening, disk

    radius = max(1, math.ceil(width_lr_px / 2))
    shares = []
    for mask in masks:
        m = np.asarray(mask) > 0.5
        shares.append(float((m & ~binary_opening(m, disk(radius))).sum()) / max(1, int(m.sum())))
    return float(np.mean(shares)) if shares else 0.0


SOLIDITY_BSPLINE = 0.75
"""auto: masks whose mean solidity (area / convex hull area) is below this get the quadratic B-spline
SDF: a shape far from the sphere training starts from (wings, legs, open frames), which the
smoothstep grids' terraces ripple as the surface travels across cells. Tuning set: stool 0.57,
airplane 0.60, torus 0.92, glossy 0.99, bumpy/dark/shiny 0.99; 0.75 sits in the gap."""


def silhouette_solidity(masks: list[np.ndarray]) -> float:
    """Mean over views of the mask's area over its convex hull's area: 1 for a convex silhouette
    (a ball), low where the silhouette is spread thin (wings, legs, rings). 1 for no masks."""
    from skimage.morphology import convex_hull_image

    shares = []
    for mask in masks:
        m = np.asarray(mask) > 0.5
        if m.any():
            shares.append(float(m.sum()) / float(convex_hull_image(m).sum()))
    return float(np.mean(shares)) if shares else 1.0


def fast_config(sr: str = "gaussian", psf_samples: int = 4) -> TrainConfig:
    return TrainConfig(preset="fast", fields=FieldConfig(kind="grid"), sampler=SamplerConfig(),
                       stage2_sampler=STAGE2_SAMPLER, sr=sr, psf_samples=psf_samples)


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


SDF_CELL_HR_PX = 12
"""auto: the finest SDF grid's cell in HR pixels (finest level 2 / (12 x footprint), a multiple of 4 in
16..64). A finer surface fits the training views better and renders held-out views worse: it bends under
each training view's highlights as grain, which breaks up the glossy highlights of a new view (tuning
scene shiny, 600 s: 6 HR px with twice the heads 30.40 dB against 32.62; with stage 1 on pixel-centre rays,
free of PSF noise, 8 HR px fitted the log's probe pixels at 35.1 dB against 29.2 at the end and scored
31.88 dB against 32.70 on the held-out views; bumpy 39.06 against 39.20; suite_tuning.md)."""

MAT_CELL_DETAILS = 1.0
"""auto: the finest material cell spans up to this many recoverable details (:func:`recoverable_cell_hr_px`,
a half-period each): half the shortest period the PSF passes, the detail SR recovers. The finest level
is the smallest power of two (in 32..1024) whose cell 2 / level is no wider than that. Two details per
cell (a level half as fine, in a 2^14 table) left SR nothing to recover into: noSR beat it on five of
seven suite scenes (suite_tuning.md)."""

AUTO_HEAD_WIDTH = 32
AUTO_TABLE_LOG2 = 17
"""auto: hidden width of the SDF and material heads, and the material hash table (2^17 entries x 2 per
level: the finest levels of a one-detail material grid fit with few collisions)."""


def _pow2_at_least(x: float, lo: float, hi: float) -> int:
    """The power of two at or above ``x``, clamped to [lo, hi] (the bounds need not be powers of two)."""
    return int(round(max(lo, min(2 ** math.ceil(math.log2(x)), hi))))


def _multiple_of_4(x: float, lo: float, hi: float) -> int:
    """``x`` rounded to a multiple of 4, clamped to [lo, hi] and never under 8."""
    return max(8, int(round(max(lo, min(x, hi)) / 4)) * 4)


class AutoBatches(NamedTuple):
    """auto's pixels per step (the TrainConfig fields of the same names)."""

    batch_in: int
    batch_out: int
    batch_stage2: int


LATTICE_CELL_PER_SIGMA = 4.0 / 3.0
"""Stage 2's lattice spacing in PSF sigmas (the default scene's 0.5 LR px at sigma 0.375), never under
half an LR pixel. A fixed 0.5 LR px lattice packs ~14x14 rays round a 4x4 block where sigma is 0.7, and
a 700-ray step then sees ~64 LR pixels. Tuning scenes, stage 1 identical (--iters): airplane (sigma 0.5)
41.87 dB at 0.67 vs 41.57 at 0.5; stool (0.6) 42.39 at 0.8 vs 42.40."""


def lattice_cell_for(sigma_lr_px: float) -> float:
    """auto's stage-2 lattice spacing (LR pixels) for a PSF of ``sigma_lr_px``."""
    return max(0.5, round(LATTICE_CELL_PER_SIGMA * sigma_lr_px, 3))


def auto_batches(psf_samples: int, centre_rays: bool = False) -> AutoBatches:
    """auto's pixels per step at ``psf_samples`` rays per pixel: ~512 in-mask rays per stage-1 step
    (one step stays ~0.1-0.2 s on 2 cores), out-of-mask pixels half as many as the step's in-mask
    pixels, and the paper's 700 rays per stage-2 step; never under 64 pixels. ``centre_rays``: stage 1
    traces one ray at each pixel's centre, ``psf_samples`` times the pixels (auto's SR), so the
    out-of-mask pixels are half of those (before, half of ``batch_in``: SR's stage 1 saw half of
    noSR's out-of-mask pixels). Tuning set, 600 s, runs of each against runs of the other: airplane
    43.84 dB over three (42.76-44.87) against 43.12 (42.72-43.45), shiny 32.25 over two against 32.87
    over three, bumpy level: inside the runs' spread either way, so SR takes noSR's share and the two
    differ in stage 2 alone."""
    ns = max(1, psf_samples)
    batch_in = int(max(64, min(512, 512 // ns)))
    pixels = batch_in * ns if centre_rays else batch_in  # in-mask pixels of a stage-1 step
    return AutoBatches(batch_in, max(64, pixels // 2), int(max(64, TrainConfig.batch_stage2 // ns)))


def stage1_rays_in_words(ns: int, centre: bool, batch_in: int) -> str:
    """A stage-1 step's in-mask rays: ``ns`` rays per pixel's worth, as ``ns`` x ``batch_in`` centre rays
    (``centre``) or ``ns`` PSF rays on each of ``batch_in`` pixels."""
    return (f"{batch_in * ns} in-mask pixels per stage-1 step, one centre ray each" if centre
            else f"{batch_in} in-mask pixels per step x {ns} rays")


def stage1_rays_reason(asked: str, ns: int, centre: bool, batch_in: int, batch_out: int) -> str:
    """The reason line for ``asked`` stage-1 rays (--psf-samples / --psf-sampler on a Gaussian PSF) and
    the out-of-mask pixels."""
    return f"{asked} (asked): {stage1_rays_in_words(ns, centre, batch_in)}, {batch_out} out-of-mask"


def auto_config(scene: Scene, sr: str, time_budget: float, capacity: float = 1.0) -> TrainConfig:
    """Capacity derived from the scene: resolution from the HR pixel footprint, the stage-2
    lattice spacing from the PSF width, the beta cap from the footprint, thin-parts sampling from
    the masks; pixel-centre rays in stage 1 and the PSF lattices in stage 2 (:func:`auto_batches`:
    pixels per step).
    Reasons are printed and saved.

    ``capacity`` scales the derived model (grid resolutions, hash table, head widths) for
    the capacity study: 0.5 = half, 2 = double; 1 is what the scene needs.
    """
    hr = hr_pixel_size(scene)
    reasons = [f"HR pixel footprint {hr:.4f} scene units (object distance / focal / sr)"]
    # Material detail: the finest hash level's cell spans the shortest period the LR images still carry.
    detail_px = recoverable_cell_hr_px(scene.info.psf.sigma_hr_px)
    mat_max = _pow2_at_least(2.0 / (MAT_CELL_DETAILS * detail_px * hr), 32 * capacity, 1024 * capacity)
    # Geometry: finest SDF level ~ SDF_CELL_HR_PX HR pixels per cell; three levels, each x2.
    fine = _multiple_of_4(2.0 / (SDF_CELL_HR_PX * hr) * capacity, 16 * capacity, 64 * capacity)
    table_log2 = max(10, AUTO_TABLE_LOG2 + int(round(3 * math.log2(capacity))))
    hidden = max(8, int(round(AUTO_HEAD_WIDTH * capacity)))
    reasons.append(f"geometry sized for what {hr:.4f}-unit pixels can supervise in minutes: SDF cell "
                   f"~{SDF_CELL_HR_PX} HR pixels, {AUTO_HEAD_WIDTH}-wide heads -- on the tuning set (600 s) twice "
                   "this (SDF cell 6 HR px, 64-wide heads) fitted grain into the surface: shiny 30.40 dB HR PSNR, "
                   "5.1 deg vs 32.62, 3.8 deg; bumpy 37.09 vs 36.78; stool 40.21 vs 39.60; an 8 HR px cell fitted "
                   "shiny's training pixels (the log's probe) at 35.1 dB against 29.2 and scored 31.88 dB against "
                   "32.70 on the held-out views, bumpy 39.06 against 39.20 (suite_tuning.md)")
    if capacity != 1.0:
        reasons.append(f"capacity x{capacity:g} of what the scene needs (study setting)")
    reasons.append(f"material hash grid finest level {mat_max}, 2^{table_log2} entries per level (cell "
                   f"{2 / mat_max:.4f}: one recoverable detail, {detail_px:.1f} HR pixels of {hr:.4f} at this PSF) -- "
                   f"half as fine in a 2^{table_log2 - 3} table left SR nothing to recover into (suite_tuning.md)")
    levels = (max(4, fine // 4), max(4, fine // 2), fine)
    reasons.append(f"SDF grids {levels} (finest cell {2 / fine:.4f} ~ {2 / fine / hr:.0f} HR pixels)")
    mode = SRMode(sr)
    sigma = scene.info.psf_sigma_lr_px
    cell = lattice_cell_for(sigma)
    if mode == SRMode.GAUSSIAN:
        # Stage 1 fits the geometry from pixel-centre rays: a PSF estimate's noise (even an antithetic
        # pair's) costs the surface more than the blur it models buys there; the PSF's detail is
        # recovered in stage 2, where the settled geometry lets low-noise shared lattices carry it.
        # ns = 2 keeps the rays per step of the 2-ray estimate (auto_batches), for --psf-samples too.
        ns = 2
        reasons.append(f"stage 1 (geometry): one ray at each LR pixel's centre, {ns}x the pixels of a {ns}-ray PSF "
                       f"estimate at the same rays per step (sigma {sigma} LR px) -- the geometry learns from more, "
                       "varied pixels and no PSF noise; the PSF enters in stage 2, which recovers the detail "
                       "(tuning set, 600 s, with the finer material grid above: shiny 32.85 dB, bumpy 39.06, "
                       "stool 41.17 vs 32.01, 37.76, 40.46 with an antithetic PSF pair per pixel and half the "
                       "material detail; suite_tuning.md; --psf-samples N asks for N PSF rays per pixel in stage 1 "
                       "instead)")
        reasons.append("stage 2 (BRDF through the PSF): shared ray lattices with Gaussian weights -- low-noise PSF "
                       "estimates for the BRDF (90 more seconds of stage 2 on a finished 600 s run, 32 + 12 samples "
                       "per ray: +0.10 dB HR PSNR vs -1.44 dB with antithetic pairs, -1.95 dB with 2 i.i.d. rays -- "
                       "the L1 of a noisy estimate pulls towards images flat within each pixel -- and -0.05 dB for "
                       "noSR; stage2_table.md)")
        reasons.append(f"stage 2 lattice spacing {cell:g} LR px: 4/3 of sigma {sigma:g}, at least half a pixel -- a "
                       "0.5 px lattice wastes rays round each block where the PSF is wide (tuning scenes, same "
                       "stage 1: airplane, sigma 0.5, 41.87 dB at 0.67 vs 41.57 at 0.5; stool, 0.6, 42.39 vs 42.40)")
    elif mode == SRMode.BOX:
        ns = scene.info.sr_factor ** 2
        reasons.append(f"box PSF: {ns} rays per LR pixel (sr {scene.info.sr_factor})")
    else:
        ns = 1
    n_in = int(sum(v.mask.sum() if v.mask is not None else v.image.shape[0] * v.image.shape[1]
                   for v in scene.train_views()))
    batches = auto_batches(ns, centre_rays=mode == SRMode.GAUSSIAN)
    fields = FieldConfig(kind="grid", sdf_levels=levels, mat_max_res=mat_max, mat_table_log2=table_log2,
                         sdf_hidden=hidden, mat_hidden=hidden)
    stage1 = SamplerConfig()
    stage2 = STAGE2_SAMPLER
    reasons.append(f"stage 2 (surface settled, beta fixed): {STAGE2_SAMPLER.n_coarse} locating + "
                   f"{STAGE2_SAMPLER.gradient_samples} gradient samples per ray (stage 1: {stage1.n_coarse} + "
                   f"{stage1.gradient_samples}): the surface moves little (at most at the rate stage 1 ended with) and beta is small, so a few samples "
                   "around the crossing carry its weight; 2.1x the stage-2 steps in the same time, +0.21 dB in 90 s "
                   "vs +0.10 (stage2_table.md). Checked when stage 2 begins: where they render the probe pixels "
                   "more than 0.25 dB below stage 1's samples (tuning scenes with thin parts: stool 0.91 dB, "
                   "airplane 0.36), stage 2 takes stage 1's locating samples and 6 + 1 gradient ones")
    reasons.append(f"stage 2 takes {AUTO_STAGE2_FRACTION:.0%} of the budget (paper: 10%): its steps are cheap and it "
                   "keeps gaining (default scene, 600 s, 8 held-out views: 38.79 dB HR PSNR at 30% vs 38.22 at 15%; "
                   "train_table.md)")
    cfg = TrainConfig(preset="auto", fields=fields, sampler=stage1, stage2_sampler=stage2,
                      stage2_fraction=AUTO_STAGE2_FRACTION, sr=sr, psf_samples=ns,
                      psf_sampler="centre" if mode == SRMode.GAUSSIAN else "mc",
                      stage2_psf_sampler="lattice" if mode == SRMode.GAUSSIAN else "", patch=4, lattice_cell=cell,
                      **batches._asdict(),
                      time_budget=time_budget)
    per_step = stage1_rays_in_words(ns, cfg.psf_sampler == "centre", batches.batch_in)
    reasons.append(f"{n_in} in-mask training pixels; {per_step} (stage 2: {rays_per_step(cfg, 2)} rays per step); "
                   f"{cfg.batch_out} out-of-mask pixels per stage-1 step, half its in-mask pixels, as noSR "
                   "(tuning set, 600 s, against half as many: airplane 43.84 vs 43.12 dB over three runs each, shiny "
                   "32.25 vs 32.87, bumpy level -- inside the runs' spread; suite_tuning.md)")
    if read_normalization(scene.root) is not None:  # imported by srvol import
        cfg = replace(cfg, capture=AUTO_CAPTURE_TERMS)
        reasons.append(f"real-capture terms on ({AUTO_CAPTURE_TERMS.describe()}): an imported scene; ambient, pose "
                       "off: each cost 0.3-0.4 dB, 2.5-2.9 deg normals on the bunny capture (capture_terms_table.md)")
    # Beta: left free it *rose* on thin or hard shapes (stool: 0.24 by mid-run, a fog; rings 0.03);
    # a cap falling to the scene's HR pixel footprint keeps the density as sharp as the images.
    cfg = replace(cfg, beta_anneal=BETA_ANNEAL, beta_cap_end=round(hr, 5))
    reasons.append(f"VolSDF beta capped by a bound falling from 0.1 to {hr:.4f} (the HR pixel footprint) over the "
                   f"first {BETA_ANNEAL:.0%} of the run: left free it rose to 0.24 on the tuning scene stool (a fog); on "
                   "bumpy, where it falls by itself, the cap changes nothing (37.13 vs 37.12 dB, 3.7 deg, 600 s)")
    cfg = replace(cfg, geometry_lr_tail=GEOMETRY_LR_TAIL)
    reasons.append(f"the SDF's learning rates fall a further x{GEOMETRY_LR_TAIL:g} over the second half of stage 1 "
                   "(at its end 0.02 of their start, not 0.2): Adam moves every parameter by about its learning rate "
                   "whatever a step's few hundred rays say, and the surface kept moving by that to the end (tuning "
                   "scenes, 600 s, side by side with auto: stool 44.14 dB, 4.15 deg vs 43.17, 4.48; airplane 43.71, "
                   "3.42 vs 43.17, 4.64; suite_tuning.md)")
    cfg = replace(cfg, stage2_geometry_lr=STAGE2_GEOMETRY_LR)
    reasons.append(f"stage 2 refines the SDF with the BRDF, at x{STAGE2_GEOMETRY_LR:g} the rate stage 1 ended with "
                   "(--stage2-geometry-lr 0 = frozen, the paper's): a glossy lobe needs the surface under it to a "
                   "fraction of a degree, and frozen, the BRDF widens its lobes to fit the surface it has. Tuning set, "
                   "600 s, x1 against frozen: HR PSNR +0.44 dB on the mean (dark +1.26, shiny +1.03, stool +0.95, "
                   "glossy +0.17, torus +0.17, bumpy -0.04, airplane -0.49, within its 1.4 dB spread), normals -0.23 "
                   "deg, a stage-2 step 1.3-1.4x as long; x3 against x1, side by side: stool +0.93 dB, shiny +0.49, "
                   "glossy +0.23, bumpy +0.02, torus -0.02, dark -0.24 (mean +0.24), normals better or level on all "
                   "six (-0.13 deg on the mean; suite_tuning.md)")
    reasons.append("photometric L1 on linear values (--photometric-clip 1 takes photo pixels at or past white as "
                   "saturated, as a sensor and the HR metric clip them): tuning scenes, 600 s, against auto side by "
                   "side: shiny +1.33 dB, glossy -0.74, airplane -1.47 (against an earlier run; its spread is ~1.4 "
                   "dB), and the four scenes with no pixel past white unchanged: -0.13 dB on the mean (suite_tuning.md)")
    cfg = replace(cfg, stage2_importance=STAGE2_IMPORTANCE)
    reasons.append(f"stage 2 draws {STAGE2_IMPORTANCE:.0%} of its patches by an error map of the training views, each "
                   "pixel weighted so the loss means the same (--stage2-importance 0 = uniform): a few flash "
                   "highlights hold most of stage 2's error (glossy: 1 % of the patches, 89 %), and a uniform draw "
                   "meets them now and then -- the logged 25-step PSNR swung by 14.5 dB on glossy, 2.4 with the map; "
                   "HR PSNR within a run's spread on the tuning set (glossy 34.52 vs 34.17 dB, stool 44.05 vs 44.14, "
                   "bumpy 39.01 vs 39.05; suite_tuning.md)")
    reasons.append("no stereo points (--free-space 1 keeps their lines of sight free, --anchors 1 pulls the surface to "
                   "them as well): the free space alone gained +0.21 dB, -0.14 deg on the tuning set's mean (airplane "
                   "+1.22, glossy +0.52; shiny -0.48, torus -0.14), inside the runs' spread, and the stereo and the "
                   "term cost 30-110 s and up to a fifth of a step: every report scene lost with it (rings -3.57 dB at "
                   "half its steps); the pull opens glossy's bowl (normals 1.5-2.1 deg) but costs its HR PSNR 0.5-3.5 "
                   "dB (suite_tuning.md)")
    spacing_px = 2 * stage1.bound / stage1.n_coarse / (hr * scene.info.sr_factor)
    masks = [v.mask for v in scene.train_views() if v.mask is not None]
    thin = thin_share(masks, spacing_px)
    if thin >= THIN_SHARE:
        cfg = replace(cfg, silhouette_rays=THIN_SILHOUETTE_RAYS, sampler=replace(stage1, n_refine=THIN_REFINE_SAMPLES),
                      stage2_sampler=replace(stage2, n_refine=THIN_REFINE_SAMPLES))
        reasons.append(f"thin parts: {thin:.1%} of the mask pixels lie in parts narrower than the locating samples' "
                       f"spacing ({spacing_px:.1f} LR px; >= {THIN_SHARE:.0%}): {THIN_REFINE_SAMPLES} refining "
                       "samples where a ray may pass through a part the samples step over, half the out-of-mask rays "
                       "near the silhouette "
                       "(tuning scene stool, 600 s: 38.25 dB, 10.4 deg with them)")
    else:
        reasons.append(f"no thin parts: {thin:.1%} of the mask pixels lie in parts narrower than the locating samples' "
                       f"spacing ({spacing_px:.1f} LR px; < {THIN_SHARE:.0%}), so no refining samples (on bumpy they "
                       "cost 0.7 dB at 600 s)")
    solidity = silhouette_solidity(masks)
    if solidity < SOLIDITY_BSPLINE:
        cfg = replace(cfg, fields=replace(cfg.fields, sdf_interpolation="bspline"))
        reasons.append(f"silhouettes far from convex (mean solidity {solidity:.2f} < {SOLIDITY_BSPLINE}): quadratic "
                       "B-spline SDF grids -- smoothstep's terraces ripple a surface that travels far from the initial "
                       "sphere (tuning scenes airplane, 600 s: 41.89 dB, 5.1 deg vs 39.02, 7.2; stool 42.42, 5.6 vs 40.15, 7.0), "
                       "on near-convex shapes they cost (glossy -1.23 dB, torus -0.67, shiny -0.64; suite_tuning.md)")
    else:
        reasons.append(f"near-convex silhouettes (mean solidity {solidity:.2f} >= {SOLIDITY_BSPLINE}): smoothstep SDF "
                       "grids, about half the B-spline's cost per training query")
    reasons.append(f"time budget {time_budget:.0f} s for both stages")
    return replace(cfg, reasons=tuple(reasons))
