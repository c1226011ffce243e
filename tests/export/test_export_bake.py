"""Baking: texel centres reproduce a field known in closed form; gutters are filled."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from export_testfields import RADIUS, colour_material, sphere_sdf
from srvol.export.bake import BakeOptions, auto_texture_size, bake, dilate, rasterize_uv
from srvol.export.extract import ExtractOptions, extract_mesh
from srvol.export.simplify import decimate
from srvol.export.types import Mesh
from srvol.export.uv import unwrap
from srvol.geometry import sdf_normals

SIZE = 128


def _baked_sphere():
    full = extract_mesh(sphere_sdf, ExtractOptions(resolution=48)).mesh
    uvm = unwrap(decimate(full, 800), SIZE).mesh
    normals = sdf_normals(sphere_sdf, torch.from_numpy(np.ascontiguousarray(uvm.vertices, np.float32))).numpy()
    mesh = Mesh(uvm.vertices, uvm.faces, uvm.uv, normals)
    return mesh, bake(sphere_sdf, colour_material, mesh, BakeOptions(texture_size=SIZE, gutter=6, normal_map=True))


def test_rasterize_one_triangle_hand_counted():
    # Lower-left half of a 4x4 texture: uv (0,0), (1,0), (0,1). In texel units (y down) the triangle is
    # (0,4), (4,4), (0,0); texel centre (i+.5, j+.5) is inside when i + 0.5 <= j + 0.5, i.e. i <= j: 10 texels.
    uv = np.array([[0, 0], [1, 0], [0, 1]], dtype=np.float32)
    r = rasterize_uv(uv, np.array([[0, 1, 2]]), 4)
    assert sorted(zip(r.rows.tolist(), r.cols.tolist())) == [(j, i) for j in range(4) for i in range(j + 1)]
    np.testing.assert_allclose(r.bary.sum(1), 1.0, atol=1e-12)


def test_bake_reproduces_field_at_texel_centres():
    mesh, res = _baked_sphere()
    tex = res.textures
    assert res.unfilled_fraction == 0.0
    ras = rasterize_uv(mesh.uv, mesh.faces, SIZE)
    rng = np.random.default_rng(1)
    pick = rng.choice(len(ras.rows), 300, replace=False)
    p = (ras.bary[pick, :, None] * mesh.vertices[mesh.faces[ras.face[pick]]].astype(np.float64)).sum(1)
    on_surface = p / np.linalg.norm(p, axis=1, keepdims=True) * RADIUS  # the exact projection on a sphere
    want = colour_material(torch.from_numpy(on_surface).float())
    rows, cols = ras.rows[pick], ras.cols[pick]
    np.testing.assert_allclose(tex.albedo[rows, cols], want.albedo.numpy(), atol=2e-4)
    np.testing.assert_allclose(tex.specular[rows, cols], want.specular.numpy(), atol=2e-4)
    np.testing.assert_allclose(tex.alpha[rows, cols], want.alpha.numpy(), atol=2e-4)
    np.testing.assert_allclose(tex.roughness[rows, cols], np.sqrt(want.alpha.numpy()), atol=2e-4)
    # On an exact sphere the field's normal is the smooth mesh normal: the normal map is ~(0, 0, 1).
    assert np.median(tex.normal[rows, cols, 2]) > 0.999


def test_gutters_dilated_at_least_four_texels():
    _, res = _baked_sphere()
    tex = res.textures
    cov = tex.coverage
    # Texels within 4 texels (8-neighbour steps) of a chart take a chart's value, not black or the fill mean.
    ring = cov.copy()
    for _ in range(4):
        ring = ring | dilate(np.zeros((*cov.shape, 1), np.float32), ring, 1)[1]
    gutter = ring & ~cov
    assert gutter.sum() > 0
    assert (tex.albedo[gutter] > 0.05).all()  # the ramp's minimum on the sphere is 0.1
    assert np.isfinite(tex.albedo).all()


def test_dilate_copies_nearest_filled_texel():
    img = np.zeros((1, 4, 1), np.float32)
    img[0, 0, 0] = 2.0
    filled = np.array([[True, False, False, False]])
    out, mask = dilate(img, filled, 2)
    assert out[0, :3, 0].tolist() == [2.0, 2.0, 2.0] and mask.tolist() == [[True, True, True, False]]
    # Two charts: each gutter texel takes the nearer chart's value.
    img = np.array([[[1.0], [0.0], [0.0], [0.0], [0.0], [5.0]]], np.float32)
    out, _ = dilate(img, np.array([[True, False, False, False, False, True]]), 4)
    assert out[0, :, 0].tolist() == [1.0, 1.0, 1.0, 5.0, 5.0, 5.0]


def test_auto_texture_size_from_hr_texel_density():
    # 1 m^2 at 1 mm HR pixels: 1e6 texels / 0.6 packing -> side 1291 -> 2048.
    assert auto_texture_size(1.0, 0.001) == 2048
    assert auto_texture_size(1.0, 0.01) == 256  # clamped to the minimum


def test_a_black_material_is_refused_not_silently_exported():
    """A collapsed run bakes albedo = F0 = 0 everywhere: export stops with one line naming the way out."""
    from srvol.errors import SrvolError
    from srvol.export.pipeline import check_not_dark
    from srvol.export.types import TextureSet

    cov = np.ones((8, 8), bool)
    black = TextureSet(albedo=np.zeros((8, 8, 3), np.float32), specular=np.zeros((8, 8, 1), np.float32),
                       alpha=np.full((8, 8, 1), 0.25, np.float32), coverage=cov)
    with pytest.raises(SrvolError, match="--allow-dark"):
        check_not_dark(black)
    coal = TextureSet(albedo=np.full((8, 8, 3), 0.01, np.float32), specular=np.full((8, 8, 1), 0.04, np.float32),
                      alpha=black.alpha, coverage=cov)
    check_not_dark(coal)  # very dark but real (the stability study's dark scene): exported
