"""Each metric on an example small enough to compute by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest

from srvol.metrics import albedo_psnr, chamfer, dark_fraction, normal_mae_deg, psnr, ssim


def test_psnr_of_a_constant_offset():
    # every pixel off by 0.1: MSE = 0.01, PSNR = 10 log10(1 / 0.01) = 20 dB
    gt = np.full((4, 5, 3), 0.5)
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=1e-9)
    # off by 0.01 on half of the pixels: MSE = 0.5e-4, PSNR = 10 log10(2e4) = 43.0103 dB
    pred = gt.copy()
    pred[:2] += 0.01
    assert psnr(pred, gt) == pytest.approx(10 * math.log10(2e4), abs=1e-9)


def test_psnr_over_a_mask_and_of_identical_images():
    gt = np.zeros((2, 2, 3))
    pred = gt.copy()
    pred[0, 0] = 0.5  # only outside the mask
    mask = np.array([[False, True], [True, True]])
    assert psnr(pred, gt, mask) == float("inf")
    assert psnr(pred, gt) == pytest.approx(10 * math.log10(1 / (0.25 / 4)), abs=1e-9)


def test_ssim_of_identical_images_is_one_and_of_noise_is_lower():
    rng = np.random.default_rng(0)
    img = rng.random((32, 32, 3))
    assert ssim(img, img) == pytest.approx(1.0, abs=1e-12)
    noise = rng.standard_normal(img.shape)
    slight, strong = (ssim(np.clip(img + a * noise, 0, 1), img) for a in (0.02, 0.2))
    assert 0.9 < slight < 1.0
    assert strong < slight


def test_normal_mae_of_known_rotations():
    # left half exact, right half rotated by 90 deg: mean 45 deg; the unmasked pixel (180 deg off) is ignored
    gt = np.zeros((1, 5, 3))
    gt[..., 2] = 1.0
    pred = gt.copy()
    pred[0, 2:4] = [1.0, 0.0, 0.0]
    pred[0, 4] = [0.0, 0.0, -1.0]
    mask = np.array([[True, True, True, True, False]])
    assert normal_mae_deg(pred, gt, mask) == pytest.approx(45.0, abs=1e-9)
    # lengths do not matter: both maps are re-normalised; 60 deg tilt everywhere
    tilted = np.broadcast_to([math.sin(math.radians(60)), 0.0, math.cos(math.radians(60))], gt.shape) * 3.0
    assert normal_mae_deg(tilted, gt, np.ones((1, 5), bool)) == pytest.approx(60.0, abs=1e-9)


def test_albedo_psnr_is_invariant_to_per_channel_scale():
    rng = np.random.default_rng(1)
    gt = rng.uniform(0.1, 0.9, (8, 8, 3))
    mask = np.ones((8, 8), bool)
    assert albedo_psnr(gt * np.array([0.5, 2.0, 1.3]), gt, mask) > 200.0  # exact up to rounding
    # a constant offset is not a scale: the least-squares scale of pred = gt + 0.1 leaves an error
    assert albedo_psnr(gt + 0.1, gt, mask) < 40.0


def test_albedo_psnr_scale_is_least_squares_per_channel():
    # pred = [2, 4] against gt = [0.5, 0.5] in one channel: s = <p, g>/<p, p> = 3/20,
    # s p = [0.3, 0.6], residuals 0.2 and -0.1: MSE = 0.025, PSNR = 10 log10(40) = 16.02 dB
    gt = np.full((1, 2, 1), 0.5)
    pred = np.array([[[2.0], [4.0]]])
    assert albedo_psnr(pred, gt, np.ones((1, 2), bool)) == pytest.approx(10 * math.log10(40), abs=1e-9)


def test_chamfer_of_a_shifted_point_set_in_units_of_the_bbox_diagonal():
    # the 8 corners of a unit cube (diagonal sqrt 3) against the same corners shifted by 0.1 along x:
    # every nearest neighbour is 0.1 away both ways -> 0.1 / sqrt(3)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    assert chamfer(corners + [0.1, 0, 0], corners) == pytest.approx(0.1 / math.sqrt(3), abs=1e-12)
    assert chamfer(corners, corners) == 0.0


def test_chamfer_is_the_mean_of_both_directions():
    # a = {0}, b = {0, 1} on a line (diagonal 1): a->b mean 0, b->a mean 0.5 -> chamfer 0.25
    a = np.zeros((1, 3))
    b = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    assert chamfer(a, b) == pytest.approx(0.25, abs=1e-12)


def test_dark_fraction_counts_lit_pixels_rendered_black():
    gt = np.full((4, 4, 3), 0.5)
    pred = gt.copy()
    pred[:2] = 0.01  # half the image at 2 % of the truth
    mask = np.ones((4, 4), bool)
    assert dark_fraction(pred, gt, mask) == 0.5
    assert dark_fraction(gt, gt, mask) == 0.0
    gt[:] = 0.0  # nothing lit: nothing can be dark
    assert dark_fraction(pred, gt, mask) == 0.0
