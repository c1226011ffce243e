"""Shadows on a hand-built scene: a ball above a ground plane, light straight above.

Every camera pixel that sees the plane is classified by the radial distance of its hit point
from the z axis: inside the analytic shadow disk it must be black, outside it lit.
"""
from __future__ import annotations

import numpy as np
import pytest
import torch

from srvol.relight.render import AssetScene, FieldScene, RelitImage, render_scene
from srvol.types import Camera

from relight_scenes import SphereOnPlane, oblique_camera

BAND = 0.005  # scene units either side of the analytic boundary left unjudged


def hit_points(camera: Camera, img: RelitImage) -> np.ndarray:
    rays = camera.to("cpu", torch.float32).rays_at(camera.to("cpu", torch.float32).pixel_centers())
    pts = rays.origins + torch.from_numpy(img.depth.reshape(-1))[:, None] * rays.directions
    return pts.numpy().reshape(img.depth.shape + (3,))


def assert_shadow_disk(scene_def: SphereOnPlane, camera: Camera, img: RelitImage) -> None:
    pts = hit_points(camera, img)
    on_plane = (img.mask > 0) & (np.abs(pts[..., 2] + scene_def.h) < 2e-3)
    radial = np.linalg.norm(pts[..., :2], axis=-1)
    lit = img.rgb.sum(-1) > 1e-6
    rs = scene_def.shadow_radius
    inside = on_plane & (radial < rs - BAND)
    outside = on_plane & (radial > rs + BAND) & (radial < 0.9)
    assert inside.sum() > 30 and outside.sum() > 300, "the camera must see both sides of the boundary"
    assert not lit[inside].any(), f"{lit[inside].sum()} plane pixels lit inside the shadow disk r={rs:.4f}"
    assert lit[outside].all(), f"{(~lit[outside]).sum()} plane pixels dark outside the shadow disk"


def test_shadow_radius_is_hand_computed():
    s = SphereOnPlane(R=0.3, c=0.2, h=0.3, L=1.5)
    # light 1.3 above the centre: tan(half-angle) = 0.3 / sqrt(1.3^2 - 0.3^2) = 0.23717; 1.8 below the light
    assert s.shadow_radius == pytest.approx(1.8 * 0.3 / np.sqrt(1.69 - 0.09), rel=1e-12)
    assert s.shadow_radius == pytest.approx(0.42691, abs=1e-5)


def test_neural_path_shadow_matches_the_analytic_disk(sphere_on_plane):
    cam = oblique_camera()
    img = render_scene(FieldScene(sphere_on_plane.sdf, SphereOnPlane.material), cam, sphere_on_plane.light())
    assert_shadow_disk(sphere_on_plane, cam, img)


def test_asset_path_shadow_matches_the_analytic_disk(sphere_on_plane):
    cam = oblique_camera()
    img = render_scene(AssetScene.build(sphere_on_plane.asset()), cam, sphere_on_plane.light())
    assert_shadow_disk(sphere_on_plane, cam, img)


def test_without_shadows_the_disk_is_lit(sphere_on_plane):
    cam = oblique_camera()
    img = render_scene(FieldScene(sphere_on_plane.sdf, SphereOnPlane.material), cam, sphere_on_plane.light(),
                       shadows=False)
    pts = hit_points(cam, img)
    on_plane = (img.mask > 0) & (np.abs(pts[..., 2] + sphere_on_plane.h) < 2e-3)
    inside = on_plane & (np.linalg.norm(pts[..., :2], axis=-1) < sphere_on_plane.shadow_radius - BAND)
    assert inside.sum() > 30 and (img.rgb[inside].sum(-1) > 1e-6).all()


def test_asset_contains_and_field_contains_agree_on_the_light(sphere_on_plane):
    fields = FieldScene(sphere_on_plane.sdf, SphereOnPlane.material)
    asset = AssetScene.build(sphere_on_plane.asset())
    for point, inside in [([0.0, 0.0, 0.2], True), ([0.0, 0.0, 1.5], False), ([0.5, 0.5, 0.0], False)]:
        p = torch.tensor(point)
        assert fields.contains(p) == inside
        assert asset.contains(p) == inside
