"""The working (LR) resolution of an imported scene: a whole factor f below the photos, reached by a
Gaussian blur of known sigma and decimation (:func:`srvol.psf.blur_decimate`, the exact operator the
synthetic scenes are made with), so that the scene's PSF is exact for the decimation.

The photo's own optics blur too; srvol takes it as :data:`PHOTO_SIGMA_PX` photo pixels (the default
PSF of a scene), so the scene's sigma in LR pixels is sqrt(DECIMATION_SIGMA^2 + (PHOTO_SIGMA_PX / f)^2)
(= PHOTO_SIGMA_PX when f = 1: no decimation, no added blur).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from srvol.errors import SrvolError
from srvol.psf import DEFAULT_SIGMA_LR_PX, blur_decimate

DEFAULT_LR_SIDE = 400
"""The default working resolution's longest side is at most this: the factor is the smallest whole
number that brings the photo's longest side to it (a 4032x3024 photo -> f = 11 -> 366x274)."""

DECIMATION_SIGMA = 0.5
"""sigma (LR pixels) of the Gaussian blurred into the photo before decimating by f > 1."""

PHOTO_SIGMA_PX = DEFAULT_SIGMA_LR_PX
"""The photo's own PSF sigma, in photo pixels (an assumption: a sharp phone photo)."""


@dataclass(frozen=True)
class WorkingResolution:
    """factor: whole decimation factor; size: (w, h) LR size; crop: (W, H) of the photo part used
    (the right and bottom remainders of W, H mod f are dropped, so pixel edges stay aligned)."""

    factor: int
    size: tuple[int, int]
    crop: tuple[int, int]

    @property
    def psf_sigma_lr_px(self) -> float:
        if self.factor == 1:
            return PHOTO_SIGMA_PX
        return math.hypot(DECIMATION_SIGMA, PHOTO_SIGMA_PX / self.factor)


def choose_resolution(photo: tuple[int, int], lr: tuple[int, int] | None) -> WorkingResolution:
    """The working resolution for photos of size ``photo``: ``lr`` (W, H) if given, which must be the
    photo divided by a whole factor (rounded down), else the default (:data:`DEFAULT_LR_SIDE`)."""
    W, H = photo
    if lr is None:
        f = max(1, math.ceil(max(W, H) / DEFAULT_LR_SIDE))
    else:
        f = max(1, round(W / lr[0]))
        if (W // f, H // f) != tuple(lr):
            options = ", ".join(f"{W // k}x{H // k}" for k in range(1, 9) if W // k >= 16)
            raise SrvolError(f"--lr {lr[0]}x{lr[1]}: the photos ({W}x{H}) divide by whole factors only: {options}")
    return WorkingResolution(factor=f, size=(W // f, H // f), crop=(W // f * f, H // f * f))


def to_working(linear: np.ndarray, res: WorkingResolution) -> np.ndarray:
    """(H, W, 3) linear photo -> (h, w, 3) LR image: cropped, blurred by DECIMATION_SIGMA LR px, decimated."""
    W, H = res.crop
    img = linear[:H, :W]
    if res.factor == 1:
        return np.ascontiguousarray(img, dtype=np.float32)
    return blur_decimate(img, res.factor, DECIMATION_SIGMA)


def scale_intrinsics(K: np.ndarray, factor: int) -> np.ndarray:
    """(3, 3) K of the photo -> K of the LR image (pixel edges onto pixel edges)."""
    out = np.asarray(K, np.float64).copy()
    out[:2] /= factor
    return out
