"""Blender (bpy 5) imports of the USD and the GLB: material wiring, and a tiny Cycles render.

bpy runs in a subprocess (it crashes a process that loaded embree)."""
from __future__ import annotations

import importlib.util

import pytest

from srvol.export.asset import load_asset
from srvol.export.blender import BlenderView, run_blender_check, write_blend
from srvol.images import read_png

pytestmark = pytest.mark.blender

TINY = BlenderView(width=32, height=24, samples=4)


@pytest.fixture(scope="module")
def needs_bpy():
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("bpy (Blender as a Python module) is not installed")


@pytest.mark.parametrize("source", ["usd", "glb"])
def test_blender_material_wiring(sphere_asset, tmp_path, needs_bpy, source):
    root, _ = sphere_asset
    tex = load_asset(root).textures
    rep = run_blender_check(root, tmp_path / "r.png", TINY, source=source)
    (mat,) = rep["materials"]
    assert mat["base_color_image"], "no image linked into Base Color"
    # USD: the linear EXR must be Non-Color; glTF: the PNG is sRGB-encoded and must be tagged sRGB.
    assert mat["base_color_colorspace"] == ("Non-Color" if source == "usd" else "sRGB")
    assert mat["roughness_colorspace"] == "Non-Color"
    # Roughness values Blender reads are r = sqrt(alpha), not alpha (their means differ by ~0.2 here).
    assert mat["roughness_image_mean"] == pytest.approx(float(tex.roughness.mean()), abs=0.02)
    # Specular: the F0 Blender applies where the baked F0 is largest equals it (within 10 %); a bare USD
    # import would give 0.04 times it. The USD texture holds F0 itself, the glTF one F0 / f0_ref.
    f0_ref = max(float(tex.specular.max()), 0.04)
    texel = float(tex.specular.max()) if source == "usd" else 1.0
    assert mat["f0_per_unit_specular_texel"] * texel == pytest.approx(f0_ref, rel=0.1)
    img = read_png(tmp_path / "r.png", srgb=True)
    assert img.shape[:2] == (24, 32) and img.max() > 0.05  # the object is lit and visible


def test_write_blend(sphere_asset, tmp_path, needs_bpy):
    import shutil

    root, _ = sphere_asset
    work = tmp_path / "asset"
    shutil.copytree(root, work)
    write_blend(work, work / "model.blend", f0_ref=0.14)
    assert (work / "model.blend").stat().st_size > 10000
    assert sorted(p.name for p in work.iterdir() if p.name.startswith(".")) == []
    assert not (work / "model.blend1").exists()
