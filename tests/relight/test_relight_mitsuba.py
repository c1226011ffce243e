"""srvol's asset renderer against Mitsuba 3 on the same asset (diffuse + GGX, point light, shadows)."""
from __future__ import annotations

import pytest
import torch

from srvol.relight.synthetic import latlong_asset
from srvol.types import Camera, PointLight

from relight_scenes import SphereOnPlane

mi = pytest.importorskip("mitsuba", reason="the independent check needs Mitsuba 3 (pip install mitsuba)")


def test_mitsuba_renders_the_sphere_asset_like_srvol(sphere):
    from srvol.relight.mitsuba_check import check_asset

    sdf, material = sphere
    asset = latlong_asset(sdf, material, n_theta=64, n_phi=128, texture_size=(64, 32))
    K = torch.tensor([[60.0, 0, 24], [0, 60.0, 18], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.look_at([1.6, -1.6, 0.8], [0, 0, 0], [0, 0, 1], K, 48, 36)
    result = check_asset(asset, cam, PointLight.make([0.5, -2.0, 1.5], 10.0), spp=16, ss=4)
    assert result.psnr >= 35.0
    assert result.mitsuba_rgb.max() > 0.1


def test_mitsuba_casts_the_same_shadow():
    from srvol.relight.mitsuba_check import check_asset

    s = SphereOnPlane()
    K = torch.tensor([[40.0, 0, 24], [0, 40.0, 18], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.look_at([0.0, -1.9, 1.6], [0.0, 0.0, -0.3], [0, 0, 1], K, 48, 36)
    light = PointLight.make([0.3, -0.6, 1.5], 10.0)  # ~60 deg from the view: Schlick's rise stays small
    result = check_asset(s.asset(), cam, light, spp=16, ss=4)
    assert result.psnr >= 35.0
