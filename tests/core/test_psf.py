"""The PSF operator and the sub-pixel ray offsets of the three training variants."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from srvol.psf import SRMode, blur_decimate, decimation_matrix, pixel_offsets


@pytest.mark.parametrize("sigma", [0.0, 0.375, 0.8])
def test_decimation_rows_sum_to_one(sigma):
    A = decimation_matrix(10, 4, sigma)
    assert A.shape == (10, 40)
    np.testing.assert_allclose(A.sum(axis=1), 1.0, atol=1e-12)
    assert (A >= 0).all()


def test_decimation_row_is_symmetric_about_the_lr_centre():
    # LR pixel 5 at x4 has its centre at HR coordinate 22: HR pixels 21 and 22 straddle it
    A = decimation_matrix(12, 4, 0.375)
    row = A[5]
    centre = 22
    for m in range(8):
        assert row[centre - 1 - m] == pytest.approx(row[centre + m], abs=1e-14)


@pytest.mark.parametrize("sigma,sr", [(0.375, 4), (0.5, 2), (1.0, 3)])
def test_kernel_variance_is_sigma_squared_plus_box(sigma, sr):
    # Weights are the Gaussian's mass over unit HR bins; as point masses at bin centres their variance
    # is sigma_hr^2 + 1/12 (Sheppard's correction), sigma_hr = sigma * sr.
    A = decimation_matrix(16, sr, sigma)
    i = 8
    x = np.arange(16 * sr) + 0.5
    mean = (A[i] * x).sum()
    assert mean == pytest.approx((i + 0.5) * sr, abs=1e-9)
    var = (A[i] * (x - mean) ** 2).sum()
    assert var == pytest.approx((sigma * sr) ** 2 + 1 / 12, rel=1e-3)


def test_sigma_zero_is_the_box_of_the_two_central_hr_pixels():
    # sigma -> 0: all mass at the LR centre, which is the edge between two HR pixels (half each)
    A = decimation_matrix(3, 4, 0.0)
    np.testing.assert_allclose(A[1, 5:7], [0.5, 0.5], atol=1e-9)


def test_blur_decimate_of_a_constant_is_constant():
    hr = np.full((24, 32, 3), 0.3, np.float32)
    lr = blur_decimate(hr, 4, 0.375)
    assert lr.shape == (6, 8, 3)
    np.testing.assert_allclose(lr, 0.3, atol=1e-6)


def test_blur_decimate_of_a_step_is_between_its_levels():
    hr = np.zeros((16, 16), np.float32)
    hr[:, 8:] = 1.0
    lr = blur_decimate(hr, 4, 0.375)
    assert lr.shape == (4, 4)
    assert np.all(np.diff(lr, axis=1) >= 0)
    # the outer pixels' centres sit 6 HR px = 4 sigma_hr from the step: Gaussian tail 1 - Phi(4) ~ 3e-5
    np.testing.assert_allclose(lr[:, 0], 0.0, atol=1e-4)
    np.testing.assert_allclose(lr[:, 3], 1.0, atol=1e-4)
    # the two pixels either side of the step are mirror images: a + b = 1
    np.testing.assert_allclose(lr[:, 1] + lr[:, 2], 1.0, atol=1e-6)


@pytest.mark.parametrize("shape, sr, sigma", [((36, 48, 3), 4, 0.375), ((33, 44), 11, 0.5), ((8, 8, 1), 1, 0.3)])
def test_blur_decimate_is_the_decimation_matrices_applied_on_both_sides(shape, sr, sigma):
    hr = np.random.default_rng(0).random(shape).astype(np.float32)
    Ay = decimation_matrix(shape[0] // sr, sr, sigma)
    Ax = decimation_matrix(shape[1] // sr, sr, sigma)
    img = hr.astype(np.float64).reshape(shape[0], shape[1], -1)
    want = np.einsum("ik,klc,jl->ijc", Ay, img, Ax).reshape(shape[0] // sr, shape[1] // sr, *shape[2:])
    got = blur_decimate(hr, sr, sigma)
    assert got.shape == want.shape and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)


def test_gaussian_offsets_have_zero_mean_and_std_sigma():
    n, sigma = 40_000, 0.375
    off = pixel_offsets(SRMode.GAUSSIAN, n_pixels=1000, n_samples=n // 1000, sigma_lr_px=sigma, sr=4,
                        generator=torch.Generator().manual_seed(0)).double()
    assert off.shape == (1000, 40, 2)
    flat = off.reshape(-1, 2)
    # standard errors: mean sigma / sqrt(n) = 0.0019, std sigma / sqrt(2n) = 0.0013; allow 5 of them
    assert flat.mean(0).abs().max().item() < 5 * sigma / math.sqrt(n)
    assert (flat.std(0) - sigma).abs().max().item() < 5 * sigma / math.sqrt(2 * n)


def test_box_offsets_are_the_hr_pixel_centres():
    off = pixel_offsets(SRMode.BOX, n_pixels=3, n_samples=25, sigma_lr_px=0.375, sr=4)
    assert off.shape == (3, 16, 2)
    c = [-0.375, -0.125, 0.125, 0.375]  # centres of 4 HR pixels across one LR pixel, from its centre
    want = torch.tensor([[x, y] for y in c for x in c])
    torch.testing.assert_close(off[0], want)
    torch.testing.assert_close(off[2], want)


def test_none_is_one_ray_through_the_centre():
    off = pixel_offsets(SRMode.NONE, n_pixels=5, n_samples=25, sigma_lr_px=0.375, sr=4)
    assert off.shape == (5, 1, 2)
    assert torch.all(off == 0)


def test_lattice_estimate_of_a_fine_grating_is_the_psf_integral():
    """A grating finer than the LR Nyquist limit (period 1.5 LR px, as the default scene's grooves):
    the PSF integral at pixel p is sin(2 pi f p) * exp(-2 pi^2 sigma^2 f^2). Averaged over the lattice's
    random shift the shared-lattice estimate equals it, and one shift is far closer than Monte Carlo
    with the same number of rays per pixel."""
    from srvol.psf import lattice_weights

    sigma, f, patch, cell = 0.375, 1 / 1.5, 4, 0.5
    g = torch.Generator().manual_seed(0)
    shift = torch.rand(4000, 2, generator=g)
    pix, rays, w = lattice_weights(patch, cell, sigma, shift)
    assert torch.allclose(w.sum(-1), torch.ones(()), atol=1e-5)
    grating = lambda xy: torch.sin(2 * math.pi * f * xy[..., 0])
    est = torch.einsum("gpr,gr->gp", w, grating(rays))
    exact = grating(pix) * math.exp(-2 * math.pi ** 2 * sigma ** 2 * f ** 2)
    assert (est.mean(0) - exact).abs().max() < 0.01
    rays_per_pixel = rays.shape[1] / patch ** 2
    mc = grating(pix[None, :, None, :] + torch.randn(4000, patch ** 2, round(rays_per_pixel), 2, generator=g) * sigma)
    err_lattice = (est - exact).pow(2).mean().sqrt()
    err_mc = (mc.mean(-1) - exact).pow(2).mean().sqrt()
    assert err_lattice < 0.1 * err_mc  # measured: 0.008 vs 0.27 at 6.25 rays per pixel


def test_antithetic_offsets_are_gaussian_draws_in_rotated_groups_of_four():
    """Each offset is still N(0, sigma^2 I); each group {g, -g, Jg, -Jg} sums to zero, so a pixel's
    estimate of an image that varies linearly across it is exact."""
    sigma = 0.375
    off = pixel_offsets(SRMode.GAUSSIAN, n_pixels=10_000, n_samples=4, sigma_lr_px=sigma, sr=4,
                        generator=torch.Generator().manual_seed(0), antithetic=True).double()
    assert off.shape == (10_000, 4, 2)
    g = off[:, 0]
    torch.testing.assert_close(off[:, 1], -g)
    torch.testing.assert_close(off[:, 2], torch.stack([-g[:, 1], g[:, 0]], -1))
    torch.testing.assert_close(off.sum(1), torch.zeros(10_000, 2, dtype=torch.float64))
    n = 10_000  # independent draws: one per group
    assert g.mean(0).abs().max().item() < 5 * sigma / math.sqrt(n)
    assert (off.reshape(-1, 2).std(0) - sigma).abs().max().item() < 5 * sigma / math.sqrt(2 * n)
    odd = pixel_offsets(SRMode.GAUSSIAN, n_pixels=3, n_samples=6, sigma_lr_px=sigma, sr=4, antithetic=True)
    assert odd.shape == (3, 6, 2)  # counts that are not a multiple of 4 keep the leading members
    pair = pixel_offsets(SRMode.GAUSSIAN, n_pixels=5, n_samples=2, sigma_lr_px=sigma, sr=4, antithetic=True)
    torch.testing.assert_close(pair[:, 1], -pair[:, 0])  # auto's default scene: the pair {g, -g}


@pytest.mark.parametrize("period, max_ratio", [(4.0, 0.7), (1.5, 1.05)])
def test_antithetic_estimate_is_unbiased_with_less_noise_than_iid(period, max_ratio):
    """A grating of period 4 LR px and 1.5 LR px (the default scene's grooves): with 4 rays per
    pixel, the antithetic groups average to the PSF integral; their RMS error is 0.55x i.i.d.
    Monte Carlo's at period 4 and about the same (0.97x) at 1.5 px, where the phase moves too far
    within one sigma for the first-order cancellation to matter."""
    sigma, f, n = 0.375, 1 / period, 20_000
    g = torch.Generator().manual_seed(1)
    p = torch.rand(n, 2, generator=g) * period
    exact = torch.sin(2 * math.pi * f * p[:, 0]) * math.exp(-2 * math.pi ** 2 * sigma ** 2 * f ** 2)

    def estimate(antithetic: bool) -> torch.Tensor:
        off = pixel_offsets(SRMode.GAUSSIAN, n, 4, sigma, 4, generator=g, antithetic=antithetic)
        return torch.sin(2 * math.pi * f * (p[:, None, 0] + off[..., 0])).mean(1)

    anti, iid = estimate(True), estimate(False)
    assert (anti - exact).mean().abs() < 0.005
    rms = lambda e: (e - exact).pow(2).mean().sqrt()  # noqa: E731
    assert rms(anti) < max_ratio * rms(iid)
