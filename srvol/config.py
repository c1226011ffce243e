"""What defines a training run, and the rules that derive it from a scene.

* :class:`TrainConfig` -- the schema of a run (saved in config.json as plain JSON);
* the presets: :func:`paper_config` (the paper's recipe, a GPU run), :func:`fast_config`
  (CPU-first) and :func:`auto_config` (``fast`` with capacity derived from the scene, every
  choice printed with its reason);
* what a stage uses (:func:`sampler_of_stage`, :func:`psf_sampler_of_stage`,
  :func:`rays_per_step`) and the words ``srvol train`` prints for it (``describe_*``);
* :class:`RunConfig`, the whole config.json (the run's TrainConfig and what it remembers of
  its scene), written and read by one pair of functions: :func:`write_run_config` and
  :func:`read_run_config`. Readers of a run (eval, report, export, relight) import this module, never the training loop.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from srvol.capture.frame import read_normalization
from srvol.capture.terms import CaptureTermsConfig
from srvol.data import Scene
from srvol.errors import SrvolError
from srvol.fields import FieldConfig
from srvol.psf import GaussianPSF, SRMode, lattice_size
from srvol.render import SamplerConfig

CONFIG_VERSION = 1


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
    lambda_smooth: float = 0.0  # stage 1: weight of mean |n(x) - n(x + e)|^2 on the surface (losses.py); 0 = off
    batch_smooth: int = 256
    beta_anneal: float = 0.0
    """Stage 1: VolSDF's beta is bounded above by a cap that falls geometrically from its start (0.1)
    to BETA_CAP_END over this share of the run (time or iterations), then stays there; 0 = no cap
    (the paper: beta free). Keeps a blurred density from being a way out when the shape is far from
    the initial sphere."""
    silhouette_rays: float = 0.0
    """Share of the out-of-mask rays drawn from each view's mask bounding box (+2 px), where the mask
    carves gaps between legs or under a seat; the rest from anywhere outside the mask."""
    capture: CaptureTermsConfig | None = None  # real-capture terms (srvol.capture.terms); None: DESIGN.md sec. 3
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
        d["capture"] = self.capture.to_json() if self.capture is not None else None
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
        d["capture"] = CaptureTermsConfig.from_json(d["capture"]) if d.get("capture") else None
        known = TrainConfig.__dataclass_fields__
        return TrainConfig(**{k: v for k, v in d.items() if k in known})


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
"""auto's share of the time budget for stage 2 (BRDF refinement on frozen geometry)."""

THIN_PARTS_RECIPE = ("--beta-anneal", "0.3", "--refine-samples", "8", "--silhouette-rays", "0.5")
# the flags that turned the stool from a fog into a stool (README); not auto's default: bumpy stalled with them


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
    detail_px = recoverable_cell_hr_px(scene.info.psf.sigma_hr_px)
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
    stage2 = STAGE2_SAMPLER
    reasons.append(f"stage 2 (geometry frozen): {STAGE2_SAMPLER.n_coarse} locating + "
                   f"{STAGE2_SAMPLER.gradient_samples} gradient samples per ray (stage 1: {stage1.n_coarse} + "
                   f"{stage1.gradient_samples}): the surface no longer moves and beta is small, so a few samples "
                   "around the crossing carry its weight; 2.1x the stage-2 steps in the same time, +0.21 dB in 90 s "
                   "vs +0.10 (stage2_table.md)")
    reasons.append(f"stage 2 takes {AUTO_STAGE2_FRACTION:.0%} of the budget (paper: 10%): its steps are cheap and it "
                   "keeps gaining (default scene, 600 s, 8 held-out views: 38.79 dB HR PSNR at 30% vs 38.22 at 15%; "
                   "train_table.md)")
    cfg = TrainConfig(preset="auto", fields=fields, sampler=stage1, stage2_sampler=stage2,
                      stage2_fraction=AUTO_STAGE2_FRACTION, sr=sr, psf_samples=ns,
                      psf_sampler="antithetic" if mode == SRMode.GAUSSIAN else "mc",
                      stage2_psf_sampler="lattice" if mode == SRMode.GAUSSIAN else "", patch=4, lattice_cell=cell,
                      batch_in=batch_in, batch_out=max(64, batch_in // 2), batch_stage2=batch_stage2,
                      time_budget=time_budget)
    reasons.append(f"{n_in} in-mask training pixels; {batch_in} per step x {ns} rays "
                   f"(stage 2: {rays_per_step(cfg, 2)} rays per step)")
    if read_normalization(scene.root) is not None:  # imported by srvol import
        cfg = replace(cfg, capture=AUTO_CAPTURE_TERMS)
        reasons.append(f"real-capture terms on ({AUTO_CAPTURE_TERMS.describe()}): an imported scene; ambient, pose "
                       "off: each cost 0.3-0.4 dB, 2.5-2.9 deg normals on the bunny capture (capture_terms_table.md)")
    reasons.append(f"time budget {time_budget:.0f} s for both stages")
    return replace(cfg, reasons=tuple(reasons))



def psf_sampler_of_stage(cfg: TrainConfig, stage: int) -> str:
    """The PSF sampler in use in ``stage`` (1 or 2)."""
    return cfg.stage2_psf_sampler if stage == 2 and cfg.stage2_psf_sampler else cfg.psf_sampler


def sampler_of_stage(cfg: TrainConfig, stage: int) -> SamplerConfig:
    """The samples per ray in ``stage`` (1 or 2)."""
    return cfg.stage2_sampler if stage == 2 and cfg.stage2_sampler is not None else cfg.sampler


def describe_ray_samples(cfg: TrainConfig) -> str:
    """Samples per ray, in words (printed by train)."""
    def words(s: SamplerConfig) -> str:
        locating = f"{s.n_coarse} + {s.n_refine} refining" if s.n_refine else f"{s.n_coarse}"
        return f"{locating} locating + {s.gradient_samples} gradient samples per ray"

    text = words(cfg.sampler)
    if cfg.stage2_sampler is not None and cfg.stage2_sampler != cfg.sampler and cfg.stage2_fraction > 0:
        text += f" (stage 2: {words(cfg.stage2_sampler)})"
    return text


def describe_psf_rays(cfg: TrainConfig, psf: GaussianPSF) -> str:
    """How each LR pixel is estimated, in words (printed by train, shown by report and the benchmark)."""
    gaussian = cfg.sr == SRMode.GAUSSIAN.value

    def words(sampler: str) -> str:
        if gaussian and sampler == "lattice":
            k, p = lattice_size(cfg.patch, cfg.lattice_cell, psf.sigma_lr_px), cfg.patch
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


# ----------------------------------------------------------------------------- config.json

@dataclass(frozen=True)
class SceneRecord:
    """What a run remembers of the scene it was trained on (config.json "scene").

    path: the scene folder (None if unknown); psf: its Gaussian PSF and sr factor;
    hr_pixel_size: scene units covered by one HR pixel at the object's distance (median over
    training views; sizes marching cubes, faces and textures); light_intensity: the declared
    co-located intensity, None when training learned it.
    """

    path: Path | None
    psf: GaussianPSF
    hr_pixel_size: float
    light_intensity: tuple[float, float, float] | None

    @staticmethod
    def of_scene(scene: Scene, path: Path) -> "SceneRecord":
        return SceneRecord(path=Path(path).resolve(), psf=scene.info.psf, hr_pixel_size=hr_pixel_size(scene),
                           light_intensity=scene.info.light_intensity)

    def to_json(self) -> dict:
        return {"path": str(self.path) if self.path else None, "sr_factor": self.psf.sr,
                "psf_sigma_lr_px": self.psf.sigma_lr_px, "hr_pixel_size": self.hr_pixel_size,
                "light_intensity": list(self.light_intensity) if self.light_intensity else None}

    @staticmethod
    def from_json(d: dict) -> "SceneRecord":
        light = d.get("light_intensity")
        return SceneRecord(path=Path(d["path"]) if d.get("path") else None,
                           psf=GaussianPSF(float(d["psf_sigma_lr_px"]), int(d["sr_factor"])),
                           hr_pixel_size=float(d["hr_pixel_size"]),
                           light_intensity=tuple(float(v) for v in light) if light else None)


@dataclass(frozen=True)
class RunConfig:
    """RUN/config.json: ``{"version": CONFIG_VERSION, "train": TrainConfig, "scene": SceneRecord}``."""

    train: TrainConfig
    scene: SceneRecord


CONFIG_NAME = "config.json"


def write_run_config(run_dir: Path, config: RunConfig) -> None:
    """Atomically write RUN/config.json."""
    from srvol.atomic import atomic_write_text

    data = {"version": CONFIG_VERSION, "train": config.train.to_json(), "scene": config.scene.to_json()}
    atomic_write_text(Path(run_dir) / CONFIG_NAME, json.dumps(data, indent=1))


def read_run_config(run_dir: Path) -> RunConfig:
    """RUN/config.json as a :class:`RunConfig`; one clear error line for a missing, malformed or
    foreign file."""
    path = Path(run_dir) / CONFIG_NAME
    if not path.is_file():
        raise SrvolError(f"{run_dir}: not a training run (no {CONFIG_NAME})")
    try:
        raw = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SrvolError(f"{path}: malformed JSON ({getattr(e, 'msg', e)})") from None
    if not isinstance(raw, dict) or raw.get("version") != CONFIG_VERSION:
        version = raw.get("version") if isinstance(raw, dict) else None
        raise SrvolError(f"{path}: unsupported config version {version!r} (expected {CONFIG_VERSION})")
    try:
        return RunConfig(train=TrainConfig.from_json(raw["train"]), scene=SceneRecord.from_json(raw["scene"]))
    except KeyError as e:
        raise SrvolError(f"{path}: malformed config (missing {e})") from None
    except (TypeError, ValueError, AttributeError) as e:
        raise SrvolError(f"{path}: malformed config ({e})") from None
