"""Real-capture terms of the image formation: what a phone adds to the co-located model of
DESIGN.md section 3, each a small parameter:

* a per-photo **exposure gain** (auto-exposure), exp(log_gain[view]); one reference photo is fixed at 1
  (the light's intensity carries the common scale);
* the **flash offset** from the lens, in the camera frame (x right, y down, z forward): the light of a
  photo sits at centre + R^T offset; learned, or given;
* **vignetting**: 1 + k1 r^2 + k2 r^4 per camera (photos of one image size), r the distance from the
  image centre over the half-diagonal;
* a weak **ambient** term: ambient * albedo (RGB), added to the flash's radiance;
* a per-photo **pose refinement**: a small rotation about the camera centre (axis-angle) and a shift
  of the centre, in the scene frame, learned at a small rate; the reference photo is fixed (it holds
  the frame), and each ray of a photo moves with it (its flash with the shift).

A pixel then reads  gain[view] * vignette(r) * (L_flash(x; light at centre + R^T offset) + ambient * albedo(x)),
exactly how ``srvol synth --capture`` makes its photos before noise, clipping and sRGB
(:mod:`srvol.synth.capture`; ``tests/capture/test_terms.py`` checks the two agree).

Training (``srvol/losses.py``) renders each ray under its photo's flash, compares
:meth:`CaptureTerms.apply` of the rendered radiance and albedo with the photo, and optimises the
terms with the fields in both stages; ``auto`` turns them on for imported scenes (scene.json has a
``normalization``). The learned values are saved in RUN/capture_terms.json.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass(frozen=True)
class CaptureTermsConfig:
    """Which terms are on. flash_offset: given (x, y, z) in scene units, or None = learned (from 0)."""

    exposure: bool = True
    vignetting: bool = True
    ambient: bool = True
    pose: bool = True
    flash_offset: tuple[float, float, float] | None = None
    learn_flash_offset: bool = True
    reference_view: int = 0

    def to_json(self) -> dict:
        return {"exposure": self.exposure, "vignetting": self.vignetting, "ambient": self.ambient, "pose": self.pose,
                "flash_offset": list(self.flash_offset) if self.flash_offset is not None else None,
                "learn_flash_offset": self.learn_flash_offset, "reference_view": self.reference_view}

    @staticmethod
    def from_json(d: dict) -> "CaptureTermsConfig":
        off = d.get("flash_offset")
        return CaptureTermsConfig(exposure=bool(d.get("exposure", True)), vignetting=bool(d.get("vignetting", True)),
                                  ambient=bool(d.get("ambient", True)), pose=bool(d.get("pose", False)),
                                  flash_offset=tuple(float(v) for v in off) if off is not None else None,
                                  learn_flash_offset=bool(d.get("learn_flash_offset", True)),
                                  reference_view=int(d.get("reference_view", 0)))

    def names(self) -> set[str]:
        """The terms that are on, as ``--capture-terms`` names them (the inverse of :func:`terms_config`)."""
        return {n for n, on in (("exposure", self.exposure), ("vignetting", self.vignetting), ("ambient", self.ambient),
                                ("pose", self.pose), ("flash", self.flash_offset is not None or self.learn_flash_offset))
                if on}

    def describe(self) -> str:
        """The terms that are on, in words (``srvol train`` prints it)."""
        on = [name for name, flag in (("exposure gain per photo", self.exposure), ("vignetting per camera",
              self.vignetting), ("ambient", self.ambient), ("pose refinement per photo", self.pose)) if flag]
        if self.flash_offset is not None:
            on.append("flash offset given ({:.4g}, {:.4g}, {:.4g})".format(*self.flash_offset))
        elif self.learn_flash_offset:
            on.append("flash offset learned")
        return ", ".join(on) if on else "none"


AMBIENT_RAW_START = -6.9
"""softplus(-6.9) = 0.001: the ambient term starts near zero (weak, as the flash dominates)."""

TERM_NAMES = ("exposure", "flash", "vignetting", "ambient", "pose")
"""The terms ``--capture-terms`` names."""


def terms_config(names: set[str], flash_offset: tuple[float, float, float] | None = None) -> CaptureTermsConfig:
    """The config with the terms ``names`` (a subset of :data:`TERM_NAMES`) on; the flash offset is
    given when ``flash_offset`` is (and "flash" is on), learned otherwise."""
    flash = "flash" in names
    return CaptureTermsConfig(exposure="exposure" in names, vignetting="vignetting" in names,
                              ambient="ambient" in names, pose="pose" in names, flash_offset=flash_offset if flash else None,
                              learn_flash_offset=flash and flash_offset is None)


def radial2(uv: Tensor, width: int, height: int) -> Tensor:
    """(P,) squared distance of pixel coordinates ``uv`` (P, 2) from the image centre, over the
    squared half-diagonal (1 at the corners)."""
    du = uv[:, 0] - width / 2
    dv = uv[:, 1] - height / 2
    return (du * du + dv * dv) / ((width / 2) ** 2 + (height / 2) ** 2)


class CaptureTerms(nn.Module):
    """The terms of ``n_views`` photos taken by ``camera_of_view.max() + 1`` cameras."""

    def __init__(self, n_views: int, camera_of_view: Tensor, config: CaptureTermsConfig = CaptureTermsConfig()):
        super().__init__()
        self.config = config
        self.register_buffer("camera_of_view", camera_of_view.long())
        n_cameras = int(camera_of_view.max()) + 1 if len(camera_of_view) else 0
        self.log_gain = nn.Parameter(torch.zeros(n_views), requires_grad=config.exposure)
        free = torch.ones(n_views)
        if n_views:
            free[config.reference_view] = 0.0
        self.register_buffer("gain_free", free)
        self.vignetting = nn.Parameter(torch.zeros(n_cameras, 2), requires_grad=config.vignetting)
        # softplus-parametrised: ambient light is never negative (learned freely it went to -0.05
        # within 30 steps on the bunny capture, while the geometry was still a sphere)
        self.ambient_raw = nn.Parameter(torch.full((3,), AMBIENT_RAW_START), requires_grad=config.ambient)
        self.pose_rotation = nn.Parameter(torch.zeros(n_views, 3), requires_grad=config.pose)
        self.pose_shift = nn.Parameter(torch.zeros(n_views, 3), requires_grad=config.pose)
        offset = torch.tensor(config.flash_offset if config.flash_offset is not None else (0.0, 0.0, 0.0))
        self.flash_offset = nn.Parameter(offset.float(), requires_grad=config.flash_offset is None
                                         and config.learn_flash_offset)

    @property
    def ambient(self) -> Tensor:
        """(3,) ambient radiance per unit albedo, >= 0 (0 when the term is off)."""
        if not self.config.ambient:
            return torch.zeros_like(self.ambient_raw)
        return nn.functional.softplus(self.ambient_raw)

    @torch.no_grad()
    def set_ambient(self, rgb) -> None:
        """Set the ambient term to ``rgb`` (3,) > 0 (tests, known captures)."""
        a = torch.as_tensor(rgb, dtype=self.ambient_raw.dtype)
        self.ambient_raw.copy_(a + torch.log(-torch.expm1(-a)))  # softplus^-1

    def gain(self, view: Tensor) -> Tensor:
        """(P,) exposure gain of each pixel's photo (the reference photo's is 1)."""
        return torch.exp(self.log_gain * self.gain_free)[view]

    def vignette(self, view: Tensor, r2: Tensor) -> Tensor:
        """(P,) 1 + k1 r^2 + k2 r^4 with the (k1, k2) of each pixel's camera."""
        k = self.vignetting[self.camera_of_view[view]]
        return 1 + k[:, 0] * r2 + k[:, 1] * r2 * r2

    def pose_parameters(self) -> list[nn.Parameter]:
        """The pose refinement's parameters (their own, small learning rate)."""
        return [self.pose_rotation, self.pose_shift] if self.config.pose else []

    def refine_rays(self, origins: Tensor, directions: Tensor, view: Tensor) -> tuple[Tensor, Tensor]:
        """Rays (P, 3) of photos ``view`` (P,) under the refined poses: directions turned about the
        camera centre by the photo's rotation, origins shifted by its shift (the reference photo's are 0)."""
        if not self.config.pose:
            return origins, directions
        free = self.gain_free[view][:, None]
        R = axis_angle_matrix(self.pose_rotation[view] * free)
        return origins + self.pose_shift[view] * free, torch.einsum("pij,pj->pi", R, directions)

    def flash_position(self, centers: Tensor, rotations: Tensor) -> Tensor:
        """(P, 3) flash positions of photos with camera centres (P, 3) and world-to-camera rotations (P, 3, 3)."""
        return centers + torch.einsum("pji,j->pi", rotations, self.flash_offset.to(centers))

    def values(self, view_names: list[str]) -> dict:
        """The learned values, for RUN/capture_terms.json."""
        gains = self.gain(torch.arange(len(view_names), device=self.log_gain.device)).detach().cpu()
        turn = torch.rad2deg((self.pose_rotation * self.gain_free[:, None]).detach().norm(dim=-1)).cpu()
        shift = (self.pose_shift * self.gain_free[:, None]).detach().norm(dim=-1).cpu()
        return {"pose_rotation_deg": {n: round(float(v), 4) for n, v in zip(view_names, turn)},
                "pose_shift": {n: round(float(v), 6) for n, v in zip(view_names, shift)},
                "exposure_gain": {n: round(float(g), 5) for n, g in zip(view_names, gains)},
                "flash_offset_camera_frame": [round(float(v), 6) for v in self.flash_offset.detach().cpu()],
                "vignetting_k1_k2_per_camera": [[round(float(v), 5) for v in row]
                                                for row in self.vignetting.detach().cpu()],
                "ambient_rgb": [round(float(v), 6) for v in self.ambient.detach().cpu()],
                "config": self.config.to_json()}

    def apply(self, radiance: Tensor, albedo: Tensor, view: Tensor, r2: Tensor) -> Tensor:
        """(P, 3) what the photos record of (P, 3) flash radiance at surfaces of (P, 3) albedo."""
        return (self.gain(view) * self.vignette(view, r2))[:, None] * (radiance + self.ambient * albedo)


def axis_angle_matrix(w: Tensor) -> Tensor:
    """(P, 3, 3) rotations of axis-angle vectors ``w`` (P, 3) (Rodrigues), differentiable at 0."""
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]  # (P, 1, 1)
    K = torch.zeros(len(w), 3, 3, dtype=w.dtype, device=w.device)
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    K = K - K.transpose(1, 2)
    theta = theta2.clamp_min(1e-12).sqrt()
    small = theta2 < 1e-8  # Taylor terms: sin t / t ~ 1 - t^2/6, (1 - cos t) / t^2 ~ 1/2 - t^2/24
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / theta2.clamp_min(1e-12))
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(K)
    return eye + a * K + b * (K @ K)
