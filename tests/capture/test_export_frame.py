"""``srvol export --frame capture``: the interchange meshes in the capture's frame, the raw mesh in the scene's."""
from __future__ import annotations

import json

import numpy as np
import pytest

from srvol.capture.frame import Similarity
from srvol.types import SurfaceMaterial


def sphere_sdf(x):
    return x.norm(dim=-1) - 0.5


def grey(x):
    return SurfaceMaterial.constant(x.shape[0], albedo=(0.6, 0.5, 0.4), specular=0.04, alpha=0.2, dtype=x.dtype)


def test_export_writes_the_formats_in_the_given_frame(tmp_path):
    import trimesh
    from scipy.spatial import cKDTree

    from srvol.export.pipeline import ExportOptions, export_fields

    c, s = np.cos(0.7), np.sin(0.7)
    to_capture = Similarity(3.0, np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), np.array([10.0, -2.0, 0.5]))
    out = tmp_path / "asset"
    export_fields(sphere_sdf, grey, out, ExportOptions(formats=("obj",), resolution=48, faces=1500, texture_size=64,
                                                       to_frame=to_capture, frame_name="capture"))
    raw = np.load(out / "raw" / "mesh.npz")["vertices"]
    assert np.linalg.norm(raw, axis=1) == pytest.approx(0.5, abs=0.02)  # raw stays in the scene frame
    obj = trimesh.load(out / "model.obj", force="mesh", process=False)
    v = np.asarray(obj.vertices)
    assert np.linalg.norm(v - [10.0, -2.0, 0.5], axis=1) == pytest.approx(1.5, abs=0.06)  # radius 0.5 x 3
    assert cKDTree(to_capture.apply(raw)).query(v)[0].max() < 1e-4
    meta = json.loads((out / "asset.json").read_text())
    assert meta["stats"]["frame"]["name"] == "capture"
    assert Similarity.from_json(meta["stats"]["frame"]["scene_to_frame"]).scale == pytest.approx(3.0)


def test_frame_capture_needs_an_imported_scene(tmp_path, capsys):
    from srvol.cli import main

    assert main(["export", "--builtin", "bumpy", "--frame", "capture", "--out", str(tmp_path / "a")]) == 2
    assert capsys.readouterr().err.strip() == ("srvol: error: --frame capture needs a run trained on an imported "
                                               "scene (srvol import)")
