"""Material edits: parsing, what each writes into the material, and what no-specular does to an image."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from srvol.errors import SrvolError
from srvol.geometry import spherical_uv
from srvol.images import write_png
from srvol.relight.edits import GOLD, MaterialEdit, parse_material
from srvol.relight.render import FieldScene, render_scene
from srvol.types import SurfaceMaterial

from relight_scenes import SphereOnPlane, oblique_camera

POINTS = torch.tensor([[0.0, 0.0, 0.5], [0.5, 0.0, 0.0], [0.0, -0.5, 0.0]])


def base() -> SurfaceMaterial:
    return SurfaceMaterial.constant(3, albedo=(0.6, 0.5, 0.4), specular=0.04, alpha=0.2)


def test_roughness_writes_alpha_as_its_square():
    m = parse_material(["roughness=0.5"]).apply(base(), POINTS)
    torch.testing.assert_close(m.alpha, torch.full((3, 1), 0.25))
    torch.testing.assert_close(m.roughness, torch.full((3, 1), 0.5))
    torch.testing.assert_close(m.albedo, base().albedo)  # untouched
    torch.testing.assert_close(m.specular, base().specular)


def test_specular_and_albedo_set_f0_and_rho():
    m = parse_material(["albedo=0.8,0.2,0.1", "specular=0.3"]).apply(base(), POINTS)
    torch.testing.assert_close(m.albedo, torch.tensor([[0.8, 0.2, 0.1]] * 3))
    torch.testing.assert_close(m.specular, torch.full((3, 1), 0.3))
    torch.testing.assert_close(m.alpha, base().alpha)


def test_specs_combine_with_commas_and_grey_albedo_takes_one_number():
    edit = parse_material(["albedo=0.8,0.2,0.1,roughness=0.3,no-specular"])
    assert edit.albedo == (0.8, 0.2, 0.1) and edit.roughness == 0.3 and edit.no_specular
    assert parse_material(["albedo=0.5"]).albedo == (0.5, 0.5, 0.5)
    assert parse_material([]).is_identity


def test_gold_is_a_dark_gold_diffuse_under_a_strong_grey_f0():
    m = parse_material(["gold"]).apply(base(), POINTS)
    torch.testing.assert_close(m.albedo[0], torch.tensor([0.25, 0.1775, 0.0725]))
    torch.testing.assert_close(m.specular, torch.full((3, 1), 0.75))
    torch.testing.assert_close(m.alpha, torch.full((3, 1), 0.09))  # r = 0.3
    assert (m.albedo + m.specular <= 1.0).all(), "albedo + F0 stays below 1 in every channel"
    assert GOLD.albedo[0] > GOLD.albedo[1] > GOLD.albedo[2]  # the hue: red > green > blue
    # later specs override the preset
    m2 = parse_material(["gold,roughness=0.6"]).apply(base(), POINTS)
    torch.testing.assert_close(m2.alpha, torch.full((3, 1), 0.36))


@pytest.mark.parametrize("spec", ["shiny", "roughness=1.5", "albedo=1,2", "specular=x", "gold=1", "albedo=",
                                  "no-specular,specular=0.2", "albedo-texture=/nonexistent.png"])
def test_bad_specs_raise_one_line(spec):
    with pytest.raises(SrvolError) as e:
        parse_material([spec])
    assert "\n" not in str(e.value)


@pytest.fixture
def quad_png(tmp_path):
    """2 x 2 sRGB PNG: top row red, green; bottom row blue, white."""
    img = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], np.float32)
    path = tmp_path / "quad.png"
    write_png(path, img, srgb=True)
    return path


def test_albedo_texture_in_uv_space_has_its_top_row_at_v_1(quad_png):
    edit = parse_material([f"albedo-texture={quad_png}"])
    uv = torch.tensor([[0.1, 0.9], [0.9, 0.9], [0.1, 0.1], [0.9, 0.1]])
    m = edit.apply(SurfaceMaterial.constant(4), torch.zeros(4, 3), uv=uv)
    torch.testing.assert_close(m.albedo, torch.tensor([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]))


def test_albedo_texture_without_uvs_is_projected_spherically(quad_png):
    edit = parse_material([f"albedo-texture={quad_png}"])
    # near the north pole at azimuth ~ -174 deg: u ~ 0.016, v ~ 0.97 -> top-left (red);
    # near the south pole at azimuth ~ +96 deg: u ~ 0.77, v ~ 0.03 -> bottom-right (white)
    pts = torch.tensor([[-0.1, -0.01, 1.0], [-0.01, 0.1, -1.0]])
    uv = spherical_uv(pts)
    assert uv[0, 0] == pytest.approx(0.0159, abs=1e-3) and uv[0, 1] == pytest.approx(0.968, abs=1e-3)
    m = edit.apply(SurfaceMaterial.constant(2), pts)
    torch.testing.assert_close(m.albedo, torch.tensor([[1.0, 0, 0], [1, 1, 1]]))


def test_no_specular_leaves_the_shadowed_lambert_image(sphere_on_plane):
    """no-specular: the image equals rho/pi * I * max(0, n.l) / r^2 * visibility, computed here by hand
    from the render's own hit points and normals; shadows are where the original render is dark.

    F0 = 0 is all the BRDF can express: Schlick's grazing rise (1 - v.h)^5 of the microfacet lobe
    remains (srvol.brdf has no F90 term), so the check is that what is left of the specular energy
    is below 1 % of the original's, not exactly zero."""
    s = sphere_on_plane
    cam = oblique_camera(64, 48)
    scene = FieldScene(s.sdf, SphereOnPlane.material)
    light = s.light()
    full = render_scene(scene, cam, light)
    diffuse = render_scene(scene, cam, light, parse_material(["no-specular"]))
    c32 = cam.to("cpu", torch.float32)
    rays = c32.rays_at(c32.pixel_centers())
    pts = (rays.origins + torch.from_numpy(diffuse.depth.reshape(-1))[:, None] * rays.directions).numpy()
    n = diffuse.normal.reshape(-1, 3)
    to_l = light.position.numpy() - pts
    r2 = (to_l ** 2).sum(-1)
    cos = np.clip((n * to_l).sum(-1) / np.sqrt(r2), 0, None)
    hit = diffuse.mask.reshape(-1) > 0
    shadowed = hit & (full.rgb.reshape(-1, 3).sum(-1) == 0) & (cos > 0.05)
    assert shadowed.sum() > 20
    lambert = np.array([0.7, 0.6, 0.5]) / math.pi * 10.0 * (cos / r2)[:, None]
    lambert[~hit | shadowed] = 0
    ours = diffuse.rgb.reshape(-1, 3)
    np.testing.assert_array_equal(ours[shadowed], 0.0)  # shadows unchanged
    np.testing.assert_allclose(ours, lambert, rtol=5e-3, atol=1e-4)  # diffuse shading unchanged
    specular_before = (full.rgb.reshape(-1, 3) - lambert).sum()
    specular_after = (ours - lambert).sum()
    assert specular_before > 0.02 * full.rgb.sum(), "the original has a visible specular part"
    assert abs(specular_after) < 0.01 * specular_before


def test_no_edit_and_the_identity_edit_render_alike(sphere):
    from srvol.relight.render import render_fields
    from srvol.relight.sources import default_camera
    from srvol.types import PointLight

    sdf, material = sphere
    cam = default_camera(24, 18)
    light = PointLight.make([1.0, -1.0, 1.0], 10.0)
    a = render_fields(sdf, material, cam, light, None).rgb
    b = render_fields(sdf, material, cam, light, MaterialEdit()).rgb
    np.testing.assert_array_equal(a, b)
    assert a.max() > 0.05
