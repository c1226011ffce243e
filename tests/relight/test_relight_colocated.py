"""The light at the camera: the relighting renderer reproduces the training situation.

Worked example: a sphere of radius 0.5 seen head-on from 2.5 away, flash at the camera. At
the centre pixel n = v = l, so h = n, D = 1 / (pi alpha^2), G = 1, F = F0, and the radiance is
(rho / pi + F0 / (4 pi alpha^2)) * I / r^2 with r = 2.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from srvol.metrics import psnr
from srvol.relight.render import render_fields
from srvol.synth.render import render as gt_render
from srvol.synth.surfaces import AnalyticSurface
from srvol.types import Camera, PointLight



def head_on_camera(size: int = 33) -> Camera:
    K = torch.tensor([[60.0, 0, size / 2], [0, 60.0, size / 2], [0, 0, 1]], dtype=torch.float64)
    return Camera.look_at([0.0, -2.5, 0.0], [0, 0, 0], [0, 0, 1], K, size, size)


def test_centre_pixel_matches_the_hand_computed_colocated_radiance(sphere):
    """The ``sphere`` fixture: radius 0.5, rho (0.6, 0.5, 0.4), F0 0.04, alpha 0.2."""
    sdf, material = sphere
    cam = head_on_camera()
    img = render_fields(sdf, material, cam, PointLight.at_camera(cam, 10.0), shadows=True)
    alpha, f0 = 0.2, 0.04
    rho = np.array([0.6, 0.5, 0.4])
    expected = (rho / math.pi + f0 / (4 * math.pi * alpha ** 2)) * 10.0 / 2.0 ** 2
    np.testing.assert_allclose(expected, [0.67641, 0.59683, 0.51725], atol=1e-5)  # the numbers by hand
    np.testing.assert_allclose(img.rgb[16, 16], expected, rtol=1e-4)
    assert img.depth[16, 16] == pytest.approx(2.0, abs=1e-4)
    np.testing.assert_allclose(img.normal[16, 16], [0.0, -1.0, 0.0], atol=1e-4)


def test_colocated_render_equals_the_ground_truth_renderer(sphere):
    sdf, material = sphere
    cam = head_on_camera(48)
    light = PointLight.at_camera(cam, 10.0)
    ours = render_fields(sdf, material, cam, light, shadows=True, ss=2)
    gt = gt_render(AnalyticSurface(sdf=sdf, material=material), cam, light, ss=2, shadows=False, maps=False)
    # silhouettes agree up to single sub-pixel rays passing within ~1e-3 of the surface
    assert np.abs(ours.mask - gt.coverage).max() <= 0.25
    assert (ours.mask != gt.coverage).mean() < 0.005
    assert psnr(ours.rgb, gt.rgb) > 60.0


def test_moved_light_equals_the_ground_truth_renderer_with_shadows(sphere):
    sdf, material = sphere
    cam = head_on_camera(48)
    light = PointLight.make([1.2, -1.0, 1.0], 8.0)
    ours = render_fields(sdf, material, cam, light, shadows=True, ss=2)
    gt = gt_render(AnalyticSurface(sdf=sdf, material=material), cam, light, ss=2, shadows=True, maps=False)
    assert psnr(ours.rgb, gt.rgb) > 50.0
    # the image half holding the sphere point nearest the light (its projection) is the bright one
    lit_point = 0.5 * light.position.double() / light.position.double().norm()
    column = float(cam.project(lit_point[None])[0, 0])
    lit, dark = (ours.rgb[:, :24], ours.rgb[:, 24:]) if column < 24 else (ours.rgb[:, 24:], ours.rgb[:, :24])
    assert lit.sum() > 2.0 * dark.sum()
