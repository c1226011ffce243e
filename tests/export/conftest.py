"""Export fixtures: a sphere with a position-dependent material, exported once per session."""
from __future__ import annotations

import pytest
from export_testfields import colour_material, sphere_sdf

@pytest.fixture(scope="session")
def sphere_asset(tmp_path_factory):
    """An asset folder of the sphere in every format but .blend (64^3, 1500 faces, 128^2 textures)."""
    from srvol.export.pipeline import ExportOptions, export_fields

    out = tmp_path_factory.mktemp("export") / "sphere_asset"
    report = export_fields(sphere_sdf, colour_material, out,
                           ExportOptions(formats=("usd", "usdc", "usdz", "gltf", "glb", "obj"), resolution=64,
                                         faces=1500, texture_size=128, normal_map=True))
    return out, report
