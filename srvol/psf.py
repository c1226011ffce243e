"""The camera's point-spread function: how an LR pixel integrates the HR image.

An LR pixel p sees ``integral k(p - q) C(q) dq`` with k a Gaussian of standard
deviation ``sigma`` (in LR pixels). This module holds

* the exact separable operator on a piecewise-constant HR image
  (:func:`blur_decimate`, used by synthesis and by the evaluation), and
* the sub-pixel ray offsets of the three training variants
  (:func:`pixel_offsets`): ``gaussian`` (SuperRVol, Monte Carlo from k),
  ``box`` (Vol-SR / NeRF-SR: a fixed d x d grid of HR pixel centres) and
  ``none`` (one ray through the pixel centre).

Offsets are in LR pixels relative to the pixel centre.
"""
from __future__ import annotations

import math
from enum import Enum

import numpy as np
import torch
from torch import Tensor


class SRMode(str, Enum):
    GAUSSIAN = "gaussian"
    BOX = "box"
    NONE = "none"


def _phi(x: np.ndarray) -> np.ndarray:
    from scipy.special import ndtr

    return ndtr(x)


def decimation_matrix(n_lr: int, sr: int, sigma_lr_px: float) -> np.ndarray:
    """(n_lr, n_lr * sr) weights: LR sample i = sum_k A[i, k] HR[k], 1-D.

    HR pixel k covers [k, k + 1) in HR units; LR pixel i's centre sits at
    (i + 0.5) * sr. Each weight is the Gaussian's mass over the HR pixel, rows
    renormalised (the image border truncates the kernel).
    """
    sigma_hr = max(sigma_lr_px * sr, 1e-3)
    k = np.arange(n_lr * sr, dtype=np.float64)
    u = (np.arange(n_lr, dtype=np.float64) + 0.5) * sr
    A = _phi((k[None, :] + 1 - u[:, None]) / sigma_hr) - _phi((k[None, :] - u[:, None]) / sigma_hr)
    A[A < 1e-12] = 0.0
    return A / A.sum(axis=1, keepdims=True)


def blur_decimate(hr: np.ndarray, sr: int, sigma_lr_px: float) -> np.ndarray:
    """HR image (H*sr, W*sr, C) -> LR image (H, W, C) under the Gaussian PSF."""
    H, W = hr.shape[0] // sr, hr.shape[1] // sr
    Ay = decimation_matrix(H, sr, sigma_lr_px)
    Ax = decimation_matrix(W, sr, sigma_lr_px)
    img = hr.astype(np.float64)
    if img.ndim == 2:
        return (Ay @ img @ Ax.T).astype(np.float32)
    return np.einsum("ik,klc,jl->ijc", Ay, img, Ax, optimize=True).astype(np.float32)


def box_offsets(d: int) -> Tensor:
    """(d*d, 2) centres of a d x d grid of sub-pixels, in LR pixels from the centre."""
    c = (torch.arange(d, dtype=torch.float32) + 0.5) / d - 0.5
    y, x = torch.meshgrid(c, c, indexing="ij")
    return torch.stack([x.reshape(-1), y.reshape(-1)], dim=-1)


def pixel_offsets(mode: SRMode, n_pixels: int, n_samples: int, sigma_lr_px: float, sr: int,
                  generator: torch.Generator | None = None) -> Tensor:
    """(n_pixels, S, 2) sub-pixel offsets (LR pixels) of the rays that estimate each LR pixel.

    gaussian: S = n_samples draws from N(0, sigma^2 I) (the paper: 25);
    box:      S = sr^2, the fixed grid of HR pixel centres (Vol-SR);
    none:     S = 1, the centre.
    The LR pixel value is the plain mean over the S rays.
    """
    if mode == SRMode.GAUSSIAN:
        return torch.randn(n_pixels, n_samples, 2, generator=generator) * sigma_lr_px
    if mode == SRMode.BOX:
        return box_offsets(sr).expand(n_pixels, -1, -1)
    return torch.zeros(n_pixels, 1, 2)


def gaussian_weights_on_grid(offsets_lr: Tensor, cell_lr: float, sigma_lr_px: float) -> Tensor:
    """Mass of the Gaussian PSF over square cells of side ``cell_lr`` centred at ``offsets_lr`` (..., 2).

    The weight a sub-pixel sample gets when rays on a regular grid are shared by
    neighbouring LR pixels (the fast preset's patch renderer).
    """
    s = max(sigma_lr_px, 1e-4) * math.sqrt(2.0)
    lo = (offsets_lr - 0.5 * cell_lr) / s
    hi = (offsets_lr + 0.5 * cell_lr) / s
    m = 0.5 * (torch.erf(hi) - torch.erf(lo))
    return m[..., 0] * m[..., 1]
