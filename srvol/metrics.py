"""Image and geometry metrics (numpy in, float out). Keys of DESIGN.md section 5."""
from __future__ import annotations

import numpy as np

METRIC_KEYS = ("psnr_hr", "ssim_hr", "psnr_lr", "normal_mae_deg", "albedo_psnr", "relit_psnr",
               "relit_ssim", "chamfer", "train_seconds", "iterations")


def psnr(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None, peak: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of linear images (clipped to [0, peak]); over ``mask`` if given."""
    p = np.clip(np.asarray(pred, np.float64), 0, peak)
    g = np.clip(np.asarray(gt, np.float64), 0, peak)
    err = (p - g) ** 2
    if mask is not None:
        err = err[np.asarray(mask, bool)]
    mse = float(err.mean())
    return float("inf") if mse == 0 else 10.0 * np.log10(peak * peak / mse)


DARK_RATIO = 0.1
"""A foreground pixel is 'dark' when the render has less than this fraction of the GT's brightness."""


def dark_fraction(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """Fraction of lit foreground pixels (GT mean > 0.02) rendered at < DARK_RATIO of the GT.

    Catches the dark or empty outputs that NeRF-style methods are reported to produce under
    changing light: PSNR alone can look tolerable on a mostly black image.
    """
    g = np.asarray(gt, np.float64).mean(-1)
    p = np.asarray(pred, np.float64).mean(-1)
    lit = np.asarray(mask, bool) & (g > 0.02)
    if not lit.any():
        return 0.0
    return float((p[lit] < DARK_RATIO * g[lit]).mean())


def ssim(pred: np.ndarray, gt: np.ndarray, peak: float = 1.0) -> float:
    """Structural similarity (scikit-image, Gaussian window as Wang et al.) over the whole image."""
    from skimage.metrics import structural_similarity

    p = np.clip(np.asarray(pred, np.float64), 0, peak)
    g = np.clip(np.asarray(gt, np.float64), 0, peak)
    return float(structural_similarity(p, g, data_range=peak, channel_axis=-1 if p.ndim == 3 else None,
                                       gaussian_weights=True, sigma=1.5, use_sample_covariance=False))


def normal_mae_deg(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """Mean angle in degrees between normal maps (H, W, 3) over ``mask``; both re-normalised."""
    m = np.asarray(mask, bool)
    p = pred[m].astype(np.float64)
    g = gt[m].astype(np.float64)
    p /= np.linalg.norm(p, axis=-1, keepdims=True).clip(1e-12)
    g /= np.linalg.norm(g, axis=-1, keepdims=True).clip(1e-12)
    cos = np.clip((p * g).sum(-1), -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)).mean())


def albedo_psnr(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    """PSNR of albedo over ``mask`` after a per-channel least-squares scale of ``pred``.

    Albedo and light intensity are only known up to a common scale, so each
    channel c of pred is multiplied by ``s_c = <pred_c, gt_c> / <pred_c, pred_c>``.
    """
    m = np.asarray(mask, bool)
    p = pred[m].astype(np.float64)
    g = gt[m].astype(np.float64)
    scale = (p * g).sum(0) / np.maximum((p * p).sum(0), 1e-12)
    return psnr(p * scale, g)


def chamfer(points_a: np.ndarray, points_b: np.ndarray) -> float:
    """Symmetric Chamfer distance, mean of the two mean nearest-neighbour distances,
    in units of the bounding-box diagonal of ``points_b`` (the reference)."""
    from scipy.spatial import cKDTree

    a = np.asarray(points_a, np.float64)
    b = np.asarray(points_b, np.float64)
    d_ab = cKDTree(b).query(a)[0]
    d_ba = cKDTree(a).query(b)[0]
    diag = float(np.linalg.norm(b.max(0) - b.min(0)))
    return float(0.5 * (d_ab.mean() + d_ba.mean()) / diag)
