"""The camera's point-spread function: how an LR pixel integrates the HR image.

An LR pixel p sees ``integral k(p - q) C(q) dq`` with k a Gaussian of standard
deviation ``sigma`` (in LR pixels). This module holds

* the exact separable operator on a piecewise-constant HR image
  (:func:`blur_decimate`, used by synthesis and by the evaluation), and
* the sub-pixel ray offsets of the three training variants
  (:func:`pixel_offsets`): ``gaussian`` (SuperRVol, Monte Carlo from k, i.i.d. as
  the paper or in rotated antithetic groups),
  ``box`` (Vol-SR / NeRF-SR: a fixed d x d grid of HR pixel centres) and
  ``none`` (one ray through the pixel centre), and
* the shared lattice (:func:`lattice_weights`): a patch of LR pixels whose rays,
  on a randomly shifted regular lattice, serve every pixel of the patch with
  Gaussian weights -- an unbiased, low-variance estimate of the same integral
  at a few rays per LR pixel instead of 25.

Offsets are in LR pixels relative to the pixel centre.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import torch
from torch import Tensor


class SRMode(str, Enum):
    GAUSSIAN = "gaussian"
    BOX = "box"
    NONE = "none"


DEFAULT_SIGMA_LR_PX = 0.375
"""The PSF sigma of a scene that declares none (DESIGN.md section 4) and of ``srvol synth``."""


@dataclass(frozen=True)
class GaussianPSF:
    """The camera's Gaussian PSF: standard deviation ``sigma_lr_px`` in LR pixels, and the HR/LR
    ratio ``sr`` (an LR pixel spans sr x sr HR pixels). :attr:`sigma_hr_px` is the one LR -> HR
    conversion."""

    sigma_lr_px: float = DEFAULT_SIGMA_LR_PX
    sr: int = 4

    @property
    def sigma_hr_px(self) -> float:
        return self.sigma_lr_px * self.sr


def _phi(x: np.ndarray) -> np.ndarray:
    from scipy.special import ndtr

    return ndtr(x)


def decimation_matrix(n_lr: int, sr: int, sigma_lr_px: float) -> np.ndarray:
    """(n_lr, n_lr * sr) weights: LR sample i = sum_k A[i, k] HR[k], 1-D.

    HR pixel k covers [k, k + 1) in HR units; LR pixel i's centre sits at
    (i + 0.5) * sr. Each weight is the Gaussian's mass over the HR pixel, rows
    renormalised (the image border truncates the kernel).
    """
    sigma_hr = max(GaussianPSF(sigma_lr_px, sr).sigma_hr_px, 1e-3)
    k = np.arange(n_lr * sr, dtype=np.float64)
    u = (np.arange(n_lr, dtype=np.float64) + 0.5) * sr
    A = _phi((k[None, :] + 1 - u[:, None]) / sigma_hr) - _phi((k[None, :] - u[:, None]) / sigma_hr)
    A[A < 1e-12] = 0.0
    return A / A.sum(axis=1, keepdims=True)


def blur_decimate(hr: np.ndarray, sr: int, sigma_lr_px: float) -> np.ndarray:
    """HR image (H*sr, W*sr, C) -> LR image (H, W, C) under the Gaussian PSF."""
    from scipy.sparse import csr_matrix

    H, W = hr.shape[0] // sr, hr.shape[1] // sr
    # The weights are banded (the Gaussian's support, a few sigma): as sparse matrices a 12 MP
    # photo decimates in 0.36 s instead of 2.6 s on one thread (the same sums in float64).
    Ay = csr_matrix(decimation_matrix(H, sr, sigma_lr_px))
    Ax = csr_matrix(decimation_matrix(W, sr, sigma_lr_px))
    img = hr.astype(np.float64)
    flat = img.reshape(img.shape[0], img.shape[1], -1)  # (H*sr, W*sr, C)
    C = flat.shape[2]
    rows = (Ay @ flat.reshape(flat.shape[0], -1)).reshape(H, flat.shape[1], C)  # (H, W*sr, C)
    cols = Ax @ rows.transpose(1, 0, 2).reshape(flat.shape[1], -1)  # (W, H*C)
    out = cols.reshape(W, H, C).transpose(1, 0, 2)
    return np.ascontiguousarray(out if img.ndim == 3 else out[..., 0], dtype=np.float32)


def box_offsets(d: int) -> Tensor:
    """(d*d, 2) centres of a d x d grid of sub-pixels, in LR pixels from the centre."""
    c = (torch.arange(d, dtype=torch.float32) + 0.5) / d - 0.5
    y, x = torch.meshgrid(c, c, indexing="ij")
    return torch.stack([x.reshape(-1), y.reshape(-1)], dim=-1)


def antithetic_gaussian_offsets(n_pixels: int, n_samples: int, sigma_lr_px: float,
                                generator: torch.Generator | None = None) -> Tensor:
    """(n_pixels, n_samples, 2) Gaussian offsets in rotated antithetic groups of four.

    Each group is {g, -g, Jg, -Jg} for one draw g ~ N(0, sigma^2 I) and J the rotation by 90
    degrees. Every offset is still N(0, sigma^2 I) (the Gaussian is rotation-invariant), so the
    plain mean is an unbiased estimate of the PSF integral; but for an image that varies
    linearly across the pixel the group's error is exactly zero, and for a quadratic one it is
    (|g|^2 / 4) tr(H) instead of a random sum of gradient terms. Four rays then estimate the
    integral about as well as many i.i.d. ones wherever the HR image is smooth at the PSF's scale.
    """
    groups = -(-n_samples // 4)
    g = torch.randn(n_pixels, groups, 2, generator=generator) * sigma_lr_px
    j = torch.stack([-g[..., 1], g[..., 0]], dim=-1)
    return torch.stack([g, -g, j, -j], dim=2).reshape(n_pixels, groups * 4, 2)[:, :n_samples]


def pixel_offsets(mode: SRMode, n_pixels: int, n_samples: int, sigma_lr_px: float, sr: int,
                  generator: torch.Generator | None = None, antithetic: bool = False) -> Tensor:
    """(n_pixels, S, 2) sub-pixel offsets (LR pixels) of the rays that estimate each LR pixel.

    gaussian: S = n_samples draws from N(0, sigma^2 I) -- i.i.d. (the paper: 25) or, with
              ``antithetic``, in rotated antithetic groups (:func:`antithetic_gaussian_offsets`);
    box:      S = sr^2, the fixed grid of HR pixel centres (Vol-SR);
    none:     S = 1, the centre.
    The LR pixel value is the plain mean over the S rays.
    """
    if mode == SRMode.GAUSSIAN:
        if antithetic:
            return antithetic_gaussian_offsets(n_pixels, n_samples, sigma_lr_px, generator)
        return torch.randn(n_pixels, n_samples, 2, generator=generator) * sigma_lr_px
    if mode == SRMode.BOX:
        return box_offsets(sr).expand(n_pixels, -1, -1)
    return torch.zeros(n_pixels, 1, 2)


LATTICE_TRUNCATION = 2.5
"""The lattice covers the patch plus this many sigma on each side (the Gaussian's mass beyond
2.5 sigma per axis is 1.2 %; the weights are renormalised)."""


def lattice_size(patch: int, cell: float, sigma_lr_px: float) -> int:
    """Rays per side of the lattice that serves a patch x patch block of LR pixels."""
    span = (patch - 1) + 2 * LATTICE_TRUNCATION * sigma_lr_px
    return int(math.floor(span / cell)) + 1


def lattice_weights(patch: int, cell: float, sigma_lr_px: float, shift: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Pixel centres, ray positions and PSF weights of shared-lattice patches.

    shift (G, 2) in [0, 1): the lattice's random offset in units of ``cell``.
    Returns pixel centres (P, 2) and ray positions (G, R, 2), both in LR pixels from the
    patch's corner (pixel (a, b) has its centre at (a + 0.5, b + 0.5)), and weights
    (G, P, R): w ~ k(ray - centre), each row normalised to 1. Averaged over the shift the
    estimate sum_r w C(ray) is the PSF integral at the pixel (up to the renormalisation).
    """
    K = lattice_size(patch, cell, sigma_lr_px)
    dev = shift.device
    c = torch.arange(patch, dtype=torch.float32, device=dev) + 0.5
    py, px = torch.meshgrid(c, c, indexing="ij")
    pix = torch.stack([px.reshape(-1), py.reshape(-1)], -1)  # (P, 2)
    lo = 0.5 - LATTICE_TRUNCATION * sigma_lr_px
    k = torch.arange(K, dtype=torch.float32, device=dev) * cell
    ky, kx = torch.meshgrid(k, k, indexing="ij")
    base = torch.stack([kx.reshape(-1), ky.reshape(-1)], -1) + lo  # (R, 2)
    rays = base[None] + shift.to(torch.float32)[:, None, :] * cell  # (G, R, 2)
    d2 = ((rays[:, None, :, :] - pix[None, :, None, :]) ** 2).sum(-1)  # (G, P, R)
    # normalised Gaussian weights; softmax cannot underflow to 0/0 for a PSF much narrower than the cell
    return pix, rays, torch.softmax(-0.5 * d2 / max(sigma_lr_px, 1e-4) ** 2, dim=-1)


@dataclass(frozen=True)
class PsfSampler:
    """The sub-pixel rays that estimate LR pixels in training: the scene's PSF and the SR mode
    (gaussian: SuperRVol; box: Vol-SR; none: one ray per pixel). Made once from the scene,
    asked for per-pixel offsets or shared lattices."""

    mode: SRMode
    psf: GaussianPSF

    def offsets(self, n_pixels: int, n_samples: int, generator: torch.Generator | None = None,
                antithetic: bool = False) -> Tensor:
        """(n_pixels, S, 2) offsets in LR pixels from each pixel's centre (:func:`pixel_offsets`)."""
        return pixel_offsets(self.mode, n_pixels, n_samples, self.psf.sigma_lr_px, self.psf.sr,
                             generator=generator, antithetic=antithetic)

    def lattice_size(self, patch: int, cell: float) -> int:
        """Rays per side of the lattice that serves a patch x patch block (:func:`lattice_size`)."""
        return lattice_size(patch, cell, self.psf.sigma_lr_px)

    def lattice(self, patch: int, cell: float, shift: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Pixel centres, ray positions and Gaussian weights of shared lattices (:func:`lattice_weights`)."""
        return lattice_weights(patch, cell, self.psf.sigma_lr_px, shift)
