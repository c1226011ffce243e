"""The synthetic ground truth: format, image formation by the declared PSF, GT maps, cameras, lights."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.ndimage import binary_dilation, binary_erosion

from srvol.data import load_scene
from srvol.metrics import psnr
from srvol.psf import blur_decimate
from srvol.synth.render import render
from srvol.synth.surfaces import AnalyticSurface
from srvol.types import Camera, PointLight, SurfaceMaterial


def sphere_sdf(x: torch.Tensor) -> torch.Tensor:
    return x.norm(dim=-1) - 0.5


def grey_material(x: torch.Tensor) -> SurfaceMaterial:
    return SurfaceMaterial.constant(x.shape[0], albedo=(0.6, 0.5, 0.4), specular=0.04, alpha=0.2, dtype=x.dtype)


@pytest.fixture(scope="module")
def scene(default_scene):
    return load_scene(default_scene)


def test_default_scene_loads_with_its_declared_split(scene):
    assert len(scene.train) == 12 and len(scene.test) == 2
    assert scene.has_masks
    assert scene.info.sr_factor == 4 and scene.info.psf_sigma_lr_px == 0.375
    assert scene.info.light_intensity is not None
    v = scene.views[scene.train[0]]
    assert v.image.shape == (30, 40, 3)
    assert 0.05 < v.mask.mean() < 0.9  # the object is there and does not fill the frame


def test_lr_test_views_are_the_hr_gt_blurred_and_decimated(scene):
    for stem in scene.test:
        hr = scene.gt.image("hr", stem)
        assert hr.shape == (120, 160, 3)
        lr = blur_decimate(hr, scene.info.sr_factor, scene.info.psf_sigma_lr_px)
        peak = float(hr.max())
        assert psnr(lr / peak, scene.views[stem].image / peak) >= 40.0
        # the PSF matters: a plain box average of the same HR image is measurably further away
        box = hr.reshape(30, 4, 40, 4, 3).mean(axis=(1, 3))
        assert psnr(box / peak, scene.views[stem].image / peak) < psnr(lr / peak, scene.views[stem].image / peak)


def test_gt_normals_unit_inside_the_object_and_zero_outside(scene):
    sr = scene.info.sr_factor
    for stem in scene.test:
        normal = scene.gt.image("normal", stem)
        albedo = scene.gt.image("albedo", stem)
        length = np.linalg.norm(normal, axis=-1)
        inside = length > 0
        np.testing.assert_allclose(length[inside], 1.0, atol=1e-4)
        assert np.all(albedo[~inside] == 0) and np.all(albedo[inside].max(-1) > 0)
        mask = scene.views[stem].mask
        deep_in = np.kron(binary_erosion(mask), np.ones((sr, sr), bool)).astype(bool)
        far_out = np.kron(~binary_dilation(mask), np.ones((sr, sr), bool)).astype(bool)
        assert deep_in.any() and far_out.any()
        assert inside[deep_in].all()
        assert not inside[far_out].any()


def test_gt_renderer_matches_the_hand_computed_centre_pixel_of_a_sphere():
    # Sphere r = 0.5 at the origin, camera and light at (0, 0, 2), 9 x 9 pixels with the principal point
    # at the centre of pixel (4, 4). Its ray hits the sphere at (0, 0, 0.5) head-on: n = l = v, distance
    # 1.5, cos = 1. With the grey material (rho = (0.6, 0.5, 0.4), F0 = 0.04, alpha = 0.2):
    #   f = rho / pi + D(1) G1(1)^2 F0 / 4 = rho / pi + F0 / (4 pi alpha^2) = rho / pi + 1 / (4 pi)
    # and with I = 2.25 = 1.5^2 the radiance I f / r^2 is f itself.
    K = torch.tensor([[20.0, 0, 4.5], [0, 20.0, 4.5], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.look_at([0, 0, 2.0], [0, 0, 0], [0, 1, 0], K, 9, 9)
    light = PointLight.at_camera(cam, [2.25] * 3)
    out = render(AnalyticSurface(sdf=sphere_sdf, material=grey_material), cam, light, ss=1)
    want = np.array([0.6, 0.5, 0.4]) / math.pi + 1 / (4 * math.pi)
    np.testing.assert_allclose(out.rgb[4, 4], want, rtol=1e-5)
    np.testing.assert_allclose(out.normal[4, 4], [0, 0, 1], atol=1e-6)
    assert out.coverage[4, 4] == 1.0 and out.coverage[0, 0] == 0.0  # corner ray: 0.2 rad off axis, misses
    assert np.all(out.rgb[0, 0] == 0)


def test_cameras_look_at_the_origin(scene):
    for v in scene.views.values():
        cam = v.camera
        axis = cam.W2C[2, :3]  # the optical axis (camera +z) in world coordinates
        to_origin = -cam.center / cam.center.norm()
        assert torch.dot(axis, to_origin).item() == pytest.approx(1.0, abs=1e-9)
        assert cam.K[0, 2].item() == cam.width / 2 and cam.K[1, 2].item() == cam.height / 2
        assert 2.0 < cam.center.norm().item() < 4.0


def test_relit_lights_are_away_from_the_camera(scene):
    specs = scene.gt.relit()
    assert len(specs) >= 1
    for spec in specs:
        cam = scene.views[spec.camera].camera
        assert spec.camera in scene.test
        assert (spec.light.position.double() - cam.center).norm().item() > 0.5
        img = scene.gt.image("relit", spec.name)
        assert img.shape == (120, 160, 3) and img.max() > 0


def test_look_at_puts_world_up_at_the_image_top():
    K = torch.tensor([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.look_at([3.0, 0, 0], [0, 0, 0], [0, 0, 1], K, 100, 100)
    top = cam.project(torch.tensor([[0, 0, 0.5]], dtype=torch.float64))[0]
    assert top[1].item() < 50  # above the centre: v grows downwards
    # looking from +x towards the origin with z up, +y is on the right
    right = cam.project(torch.tensor([[0, 0.5, 0]], dtype=torch.float64))[0]
    assert right[0].item() > 50


def test_gt_mesh_lies_on_the_surface_and_faces_outward(scene):
    trimesh = pytest.importorskip("trimesh", reason="the GT mesh is read with trimesh")
    from srvol.synth.scenes import bumpy_sdf

    mesh = trimesh.load(scene.gt.mesh_path, force="mesh", process=False)
    assert mesh.volume > 0  # positive signed volume: outward winding
    # the volume of the bumpy sphere is close to that of its radius-0.7 sphere
    assert mesh.volume == pytest.approx(4 / 3 * math.pi * 0.7 ** 3, rel=0.05)
    d = bumpy_sdf(torch.from_numpy(np.asarray(mesh.vertices[::50], dtype=np.float64)))
    assert d.abs().max().item() < 2e-3  # marching cubes at a 0.008 grid spacing
