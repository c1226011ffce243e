"""Real-capture terms of the image formation (issue 16, part 2), ready for training to hook in.

What a phone adds to the co-located model of DESIGN.md section 3, each a small parameter:

* a per-photo **exposure gain** (auto-exposure), exp(log_gain[view]); one reference photo is fixed at 1
  (the light's intensity carries the common scale);
* the **flash offset** from the lens, in the camera frame (x right, y down, z forward): the light of a
  photo sits at centre + R^T offset; learned, or given;
* **vignetting**: 1 + k1 r^2 + k2 r^4 per camera (photos of one image size), r the distance from the
  image centre over the half-diagonal;
* a weak **ambient** term: ambient * albedo (RGB), added to the flash's radiance.

A pixel then reads  gain[view] * vignette(r) * (L_flash(x; light at centre + R^T offset) + ambient * albedo(x)),
exactly how ``srvol synth --capture`` makes its photos before noise, clipping and sRGB
(:mod:`srvol.synth.capture`; ``tests/capture/test_terms.py`` checks the two agree).

Not yet hooked into training (srvol/losses.py, srvol/pixels.py and srvol/train.py); the hooks it needs:
the pixel batch carries each pixel's view and LR coordinates, the photometric loss compares
:meth:`CaptureTerms.apply` of the rendered radiance (plus the rendered albedo for the ambient term)
instead of the radiance, the co-located light of a ray becomes :meth:`CaptureTerms.flash_position`,
and the optimiser gets the terms' parameters. Per-photo pose refinement is not here.
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
    flash_offset: tuple[float, float, float] | None = None
    learn_flash_offset: bool = True
    reference_view: int = 0


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
        self.ambient = nn.Parameter(torch.zeros(3), requires_grad=config.ambient)
        offset = torch.tensor(config.flash_offset if config.flash_offset is not None else (0.0, 0.0, 0.0))
        self.flash_offset = nn.Parameter(offset.float(), requires_grad=config.flash_offset is None
                                         and config.learn_flash_offset)

    def gain(self, view: Tensor) -> Tensor:
        """(P,) exposure gain of each pixel's photo (the reference photo's is 1)."""
        return torch.exp(self.log_gain * self.gain_free)[view]

    def vignette(self, view: Tensor, r2: Tensor) -> Tensor:
        """(P,) 1 + k1 r^2 + k2 r^4 with the (k1, k2) of each pixel's camera."""
        k = self.vignetting[self.camera_of_view[view]]
        return 1 + k[:, 0] * r2 + k[:, 1] * r2 * r2

    def flash_position(self, centers: Tensor, rotations: Tensor) -> Tensor:
        """(P, 3) flash positions of photos with camera centres (P, 3) and world-to-camera rotations (P, 3, 3)."""
        return centers + torch.einsum("pji,j->pi", rotations, self.flash_offset.to(centers))

    def apply(self, radiance: Tensor, albedo: Tensor, view: Tensor, r2: Tensor) -> Tensor:
        """(P, 3) what the photos record of (P, 3) flash radiance at surfaces of (P, 3) albedo."""
        return (self.gain(view) * self.vignette(view, r2))[:, None] * (radiance + self.ambient * albedo)
