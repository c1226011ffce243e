"""The asset path against the neural path on the same analytic object, and asset folders on disk."""
from __future__ import annotations

import numpy as np
import torch

from srvol.export.asset import load_asset
from srvol.metrics import psnr
from srvol.relight.edits import parse_material, sample_texture
from srvol.relight.render import AssetScene, render_asset, render_fields
from srvol.relight.synthetic import latlong_asset
from srvol.types import Camera, PointLight

from relight_scenes import write_asset_folder


def side_camera(w: int = 64, h: int = 48) -> Camera:
    K = torch.tensor([[70.0, 0, w / 2], [0, 70.0, h / 2], [0, 0, 1]], dtype=torch.float64)
    return Camera.look_at([1.6, -1.6, 0.8], [0, 0, 0], [0, 0, 1], K, w, h)


def test_bilinear_lookup_reads_texel_centres_with_v_up():
    # 2 x 2 single-channel texture: rows top to bottom [1, 2], [3, 4]
    tex = torch.tensor([[[1.0], [2.0]], [[3.0], [4.0]]])
    uv = torch.tensor([[0.25, 0.75], [0.75, 0.75], [0.25, 0.25], [0.5, 0.5], [0.0, 1.0]])
    # texel centres, then the middle (mean of all four), then a corner clamped to the top-left texel
    torch.testing.assert_close(sample_texture(tex, uv)[:, 0], torch.tensor([1.0, 2.0, 3.0, 2.5, 1.0]))


def test_asset_of_the_sphere_renders_like_its_fields(sphere):
    sdf, material = sphere
    asset = latlong_asset(sdf, material, n_theta=96, n_phi=192, texture_size=(64, 32))
    cam = side_camera()
    light = PointLight.make([1.0, -1.5, 1.5], 10.0)
    neural = render_fields(sdf, material, cam, light, ss=2)
    mesh = render_asset(asset, cam, light, ss=2)
    assert psnr(mesh.rgb, neural.rgb) > 35.0
    assert np.abs(mesh.mask - neural.mask).mean() < 0.01


def test_edits_apply_to_the_asset_like_to_the_fields(sphere):
    sdf, material = sphere
    asset = latlong_asset(sdf, material, n_theta=96, n_phi=192, texture_size=(64, 32))
    cam = side_camera()
    light = PointLight.make([1.0, -1.5, 1.5], 10.0)
    edit = parse_material(["gold"])
    assert psnr(render_asset(asset, cam, light, edit).rgb, render_fields(sdf, material, cam, light, edit).rgb) > 30.0


def test_asset_read_from_its_folder_renders_as_in_memory(sphere, tmp_path):
    sdf, material = sphere
    asset = latlong_asset(sdf, material, n_theta=32, n_phi=64, texture_size=(32, 16))
    write_asset_folder(tmp_path / "asset", asset)
    cam = side_camera(32, 24)
    light = PointLight.make([1.0, -1.5, 1.5], 10.0)
    a = render_asset(asset, cam, light).rgb
    b = render_asset(AssetScene.build(load_asset(tmp_path / "asset")), cam, light).rgb
    np.testing.assert_allclose(a, b, atol=1e-6)
    assert a.max() > 0.1


def test_tangent_space_normal_map_tilts_the_shading_normal():
    """A ground quad with UVs u = (x + 1) / 2, v = (y + 1) / 2: tangent +x, bitangent +y, normal +z.
    A constant map (sin 30, 0, cos 30) turns the shading normal to (0.5, 0, 0.866) in the world."""
    from srvol.export.types import Asset, Mesh, TextureSet
    from srvol.relight.synthetic import constant_textures

    verts = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    mesh = Mesh(vertices=verts, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32), uv=(verts[:, :2] + 1) / 2,
                normals=np.tile(np.float32([0, 0, 1]), (4, 1)))
    flat = constant_textures((0.5, 0.5, 0.5), 0.04, 0.25)
    tilt = np.broadcast_to(np.float32([0.5, 0.0, np.sqrt(3) / 2]), (4, 4, 3)).copy()
    textures = TextureSet(albedo=flat.albedo, specular=flat.specular, alpha=flat.alpha, normal=tilt)
    K = torch.tensor([[20.0, 0, 8.5], [0, 20.0, 8.5], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.look_at([0.0, -0.01, 2.0], [0, 0, 0], [0, 1, 0], K, 17, 17)
    light = PointLight.make([0.0, 0.0, 2.0], 10.0)
    mapped = render_asset(Asset(mesh=mesh, textures=textures), cam, light, shadows=False)
    plain = render_asset(Asset(mesh=mesh, textures=flat), cam, light, shadows=False)
    np.testing.assert_allclose(mapped.normal[8, 8], [0.5, 0.0, np.sqrt(3) / 2], atol=1e-5)
    np.testing.assert_allclose(plain.normal[8, 8], [0.0, 0.0, 1.0], atol=1e-6)
    # Lambert part scales with n.l: cos 30 = 0.866 of the untilted diffuse (plus a changed highlight)
    assert mapped.rgb[8, 8, 0] < plain.rgb[8, 8, 0]
