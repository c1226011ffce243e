"""`srvol relight` end to end: outputs for each source kind, and user mistakes in one line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from srvol.cli import main
from srvol.data import camera_to_json
from srvol.images import read_exr, read_png
from srvol.relight.synthetic import latlong_asset
from srvol.relight.sources import default_camera

from relight_scenes import write_asset_folder


def run_cli(capsys, *argv: str) -> tuple[int, str]:
    rc = main(["relight", *argv])
    return rc, capsys.readouterr().err


@pytest.fixture
def asset_dir(sphere, tmp_path):
    sdf, material = sphere
    root = tmp_path / "asset"
    write_asset_folder(root, latlong_asset(sdf, material, n_theta=32, n_phi=64, texture_size=(32, 16)))
    return root


def test_asset_to_exr_is_linear_and_png_is_srgb(capsys, asset_dir, tmp_path):
    exr, png = tmp_path / "a.exr", tmp_path / "a.png"
    assert run_cli(capsys, str(asset_dir), "--light-pos", "1.5,-1,1.5", "--resolution", "40x30",
                   "--out", str(exr)) == (0, "")
    assert run_cli(capsys, str(asset_dir), "--light-pos", "1.5,-1,1.5", "--resolution", "40x30",
                   "--out", str(png))[0] == 0
    lin = read_exr(exr)
    assert lin.shape == (30, 40, 3) and lin.max() > 0.05
    np.testing.assert_allclose(read_png(png, srgb=True), np.clip(lin, 0, 1), atol=0.01)


def test_camera_file_renders_every_entry_into_a_folder(capsys, tmp_path):
    cams = {"a.png": camera_to_json(default_camera(24, 18)),
            "b.png": camera_to_json(default_camera(20, 16, azimuth_deg=30.0))}
    (tmp_path / "cams.json").write_text(json.dumps(cams))
    out = tmp_path / "out"
    rc, err = run_cli(capsys, "--builtin", "glossy", "--light-pos", "1,1,2", "--camera", str(tmp_path / "cams.json"),
                      "--material", "no-specular", "--out", str(out))
    assert (rc, err) == (0, "")
    assert read_exr(out / "a.exr").shape == (18, 24, 3) and read_exr(out / "b.exr").shape == (16, 20, 3)
    assert (out / "a.png").is_file()


def test_orbit_writes_a_sheet(capsys, tmp_path):
    out = tmp_path / "orbit.png"
    assert run_cli(capsys, "--builtin", "glossy", "--light-pos", "1.5,0,1.5", "--orbit", "3",
                   "--resolution", "24x18", "--out", str(out))[0] == 0
    assert read_png(out, srgb=False).shape[2] == 3


@pytest.mark.parametrize("argv, message", [
    (["--builtin", "glossy", "--light-pos", "0,0,0"], "inside the object"),
    (["--builtin", "glossy", "--light-pos", "1,1,1", "--material", "shiny"], "unknown material spec 'shiny'"),
    (["--builtin", "glossy", "--light-pos", "1,1"], "--light-pos 1,1"),
    (["--builtin", "glossy", "--light-pos", "1,1,2", "--intensity", "-3"], "must not be negative"),
    (["--builtin", "glossy", "--light-pos", "1,1,2", "--view", "000"], "no scene known"),
])
def test_mistakes_end_in_one_line(capsys, tmp_path, argv, message):
    out = tmp_path / "x.exr"
    rc, err = run_cli(capsys, *argv, "--out", str(out))
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("srvol: error: ") and message in err
    assert not out.exists()


def test_folder_that_is_neither_run_nor_asset(capsys, tmp_path):
    (tmp_path / "junk").mkdir()
    rc, err = run_cli(capsys, str(tmp_path / "junk"), "--light-pos", "1,1,2", "--out", str(tmp_path / "x.exr"))
    assert rc == 2 and "neither a training run" in err and err.count("\n") == 1


def test_light_inside_the_asset_mesh(capsys, asset_dir, tmp_path):
    rc, err = run_cli(capsys, str(asset_dir), "--light-pos", "0.1,0,0", "--out", str(tmp_path / "x.exr"))
    assert rc == 2 and "inside the object (inside the mesh)" in err
