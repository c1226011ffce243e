"""What defines a training run.

* :class:`TrainConfig` -- the schema of a run (saved in config.json as plain JSON); the presets
  that fill it, and the rules that derive it from a scene, are in :mod:`srvol.presets`;
* what a stage uses (:func:`sampler_of_stage`, :func:`psf_sampler_of_stage`,
  :func:`rays_per_step`) and the words ``srvol train`` prints for it (``describe_*``);
* :class:`RunConfig`, the whole config.json (the run's TrainConfig and what it remembers of
  its scene), written and read by one pair of functions: :func:`write_run_config` and
  :func:`read_run_config`. Readers of a run (eval, report, export, relight) import this module, never the training loop.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

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
    rays per pixel in rotated antithetic groups {g, -g, Jg, -Jg}), "lattice" (shared, randomly
    shifted lattice of rays over patch x patch LR pixels) or "centre" (one ray at each pixel's centre,
    psf_samples times the pixels: noSR's estimate, for stage 1 -- the PSF then enters in stage 2)."""
    psf_warmup: float = 0.0
    """gaussian per-pixel samplers (mc, antithetic) only: for this fraction of training (time or iterations) each LR pixel
    gets one ray at a Gaussian-distributed sub-pixel offset and a step takes psf_samples times as
    many pixels (same rays per step); then psf_samples rays per pixel. The first phase settles the
    geometry from many pixels; the second resolves the PSF integral. 0 = the paper's schedule."""
    stage2_psf_sampler: str = ""
    """gaussian only: the sampler of stage 2 (BRDF through the PSF), "" = psf_sampler. A lattice suits
    stage 2: its deterministic Gaussian weights give the BRDF low-noise gradients, and the
    argument against it in stage 1 (4x4-pixel patches show the geometry fewer, less varied
    pixels per step) no longer applies."""
    stage2_sampler: SamplerConfig | None = None
    """Samples per ray in stage 2 (beta fixed, the SDF frozen or learning slowly), None = ``sampler``.
    With the surface settled and beta small, a few samples around the first crossing carry the
    whole VolSDF weight, and the locating pass only has to bracket a surface that moves little."""
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
    stage2_importance: float = 0.0
    """Stage 2: this share of the in-mask pixels (patch centres) is drawn in proportion to an error
    map of the training views, the rest uniformly, each pixel weighted by uniform over drawn
    probability (:mod:`srvol.error_map`); 0 = a uniform draw (the paper)."""
    geometry_lr_tail: float = 1.0
    """Stage 1: over its second half the SDF's learning rates fall by this further factor
    (geometrically, on top of the run's decay), so the surface settles rather than moving with each
    step's few hundred rays to the end (:func:`srvol.train.geometry_tail`); 1 = off (the paper)."""
    stage2_geometry_lr: float = 0.0
    """Stage 2: the SDF goes on learning at this multiple of the rate it ended stage 1 with, under stage
    1's terms but the mask's (stage 2 draws in-mask pixels only; beta stays frozen); 0 = the geometry
    is frozen (the paper)."""
    photometric_clip: float = 0.0
    """A photo pixel at or past this white level is saturated, as on a sensor and in the HR metric:
    the photometric L1 charges an estimate there only what it falls short of it (both stages;
    :func:`srvol.losses.photometric_l1`); 0 = linear values (the paper, and auto: suite_tuning.md)."""
    lambda_eikonal: float = 0.1
    lambda_mask: float = 0.1
    lambda_smooth: float = 0.0  # stage 1: weight of mean |n(x) - n(x + e)|^2 on the surface (losses.py); 0 = off
    batch_smooth: int = 256
    lambda_anchor: float = 0.0
    """Stage 1: weight of the pull term over surface points found by stereo between the training
    views (:mod:`srvol.anchors`): the SDF held to them (beyond their error); with the free-space term
    it opens concavities the photometric loss leaves closed; 0 = off (the paper, and auto:
    suite_tuning.md)."""
    lambda_free_space: float = 0.0
    """Stage 1: weight of the free-space term over the same stereo points: the SDF positive on each
    point's line of sight from its view, up to a margin before it (:func:`srvol.anchors.anchor_terms`);
    it never pulls the surface to a point. 0 = off (the paper, and auto: suite_tuning.md)."""
    batch_anchor: int = 256
    anchor_fade: float = 0.5
    """The anchor terms' weights fall linearly from ``lambda_anchor`` and ``lambda_free_space`` to 0
    over this share of the run: the points are about an LR pixel off; they open the concavities early
    and the photometric loss refines the surface after them."""
    beta_anneal: float = 0.0
    """Stage 1: VolSDF's beta is bounded above by a cap that falls geometrically from its start (0.1)
    to ``beta_cap_end`` over this share of the run (time or iterations), then stays there; 0 = no cap
    (the paper: beta free). Keeps a blurred density from being a way out when the shape is far from
    the initial sphere."""
    beta_cap_end: float = 0.002
    """Where the beta cap of ``beta_anneal`` ends (scene units)."""
    coarse_to_fine: float = 0.0
    """Stage 1: the grids' finer levels fade in one after another over this share of the run (time or
    iterations), the material's coarse levels and the SDF's coarsest grid on from the start
    (:meth:`SceneFields.set_coarse_to_fine`); 0 = every level from the start."""
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
    compile: bool = False
    """Run the fields' queries through ``torch.compile`` (:mod:`srvol.compiled`): the same maths in
    fewer, fused kernels; eager where compiling fails."""
    reasons: tuple[str, ...] = ()

    def trains_geometry(self, stage: int) -> bool:
        """Whether the SDF learns in ``stage``: always in stage 1, in stage 2 with stage2_geometry_lr."""
        return stage == 1 or self.stage2_geometry_lr > 0

    def uses_stereo(self) -> bool:
        """Whether either stereo term (the pull, the free space: :mod:`srvol.anchors`) is on."""
        return self.lambda_anchor > 0 or self.lambda_free_space > 0

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
        # a run written before the free space had its own weight: lambda_anchor carried both terms
        d.setdefault("lambda_free_space", d.get("lambda_anchor", 0.0))
        known = TrainConfig.__dataclass_fields__
        return TrainConfig(**{k: v for k, v in d.items() if k in known})


def hr_pixel_size(scene: Scene) -> float:
    """Scene units covered by one HR pixel at the object's distance (median over training views)."""
    sizes = []
    for v in scene.train_views():
        dist = float(v.camera.center.norm())
        sizes.append(dist / float(v.camera.K[0, 0]) / scene.info.sr_factor)
    return float(np.median(sizes))



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
        if gaussian and sampler == "centre":
            return f"one ray at each LR pixel's centre ({cfg.psf_samples}x the pixels)"
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
