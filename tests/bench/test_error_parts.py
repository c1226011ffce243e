"""bench_error_parts: the squared error of a view split over silhouette band, highlights, rest and
background (a worked example with the error placed by hand)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from bench.bench_error_parts import normal_error_by_ring, split_error


def disc_scene():
    """A 64x64 grey disc of radius 20 with a bright 3x3 spot at its centre, on black."""
    yy, xx = np.mgrid[:64, :64]
    disc = (yy - 32) ** 2 + (xx - 32) ** 2 < 20 ** 2
    gt = np.zeros((64, 64, 3), np.float32)
    gt[disc] = 0.3
    gt[31:34, 31:34] = 0.9
    return gt, disc


def test_an_error_on_the_spot_is_the_highlights_share():
    gt, disc = disc_scene()
    pred = gt.copy()
    pred[31:34, 31:34] = 0.5  # the highlight rendered at half its height and nothing else wrong
    e = split_error(pred, gt, disc)
    assert e.parts["highlights"][0] == pytest.approx(1.0)
    assert e.parts["highlights"][2] == float("inf")  # perfect highlights: a perfect view
    assert e.parts["band"][0] == 0 and e.parts["rest"][0] == 0


def test_a_shrunken_silhouette_is_the_band_and_values_above_one_are_clipped():
    gt, disc = disc_scene()
    yy, xx = np.mgrid[:64, :64]
    pred = np.where(((yy - 32) ** 2 + (xx - 32) ** 2 < 19 ** 2)[..., None], gt, 0.0)
    pred[31:34, 31:34] = 5.0  # clipped to 1 as psnr_hr clips: 0.1 off, not 4.1
    e = split_error(pred, gt, disc)
    band, hi = e.parts["band"][0], e.parts["highlights"][0]
    assert band > 0.9 and 0 < hi < 0.1
    assert sum(share for share, _, _ in e.parts.values()) == pytest.approx(1.0)
    sse = ((np.clip(pred, 0, 1) - gt) ** 2).sum()
    assert e.psnr == pytest.approx(10 * np.log10(pred.size / sse))


def test_normals_tilted_on_the_rim_show_in_the_first_ring_only():
    """The disc's normals face the camera; the render tilts them 10 deg on its outer 2 pixels."""
    gt, disc = disc_scene()
    gt_n = np.where(disc[..., None], np.float32([0, 0, 1]), 0).astype(np.float32)
    rim = disc & ~ndimage.binary_erosion(disc, iterations=2)
    t = np.radians(10)
    pred_n = np.where(rim[..., None], np.float32([np.sin(t), 0, np.cos(t)]), gt_n)
    rows = normal_error_by_ring(pred_n, gt_n, disc, disc)
    (first, mae0, share0), *inner = rows
    assert first == (0, 2) and mae0 == pytest.approx(10, abs=1e-3)
    assert all(mae == pytest.approx(0, abs=1e-3) for _, mae, _ in inner)
    assert share0 == pytest.approx(rim.sum() / disc.sum(), abs=0.02)
    assert sum(share for _, _, share in rows) == pytest.approx(1.0)
