"""`srvol view`'s material controls and buttons: edits as relight applies them, "export with edits"
(perceptual-roughness rule, validators), "save render" and the command lines they print."""
from __future__ import annotations

import json
import shlex
import subprocess

import numpy as np
import pytest
import torch

from srvol.cli import main as srvol_main
from srvol.export.asset import load_asset
from srvol.images import read_exr
from srvol.relight.edits import MaterialEdit, edit_textures, parse_material
from srvol.relight.sources import default_camera
from srvol.relight.view import ViewOptions, Viewer
from srvol.relight.view_state import MaterialControls, camera_from_pose, pose_from_camera
from srvol.types import ALPHA_MIN, SurfaceMaterial

from view_fixtures import export_sphere, free_port



@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    return export_sphere(tmp_path_factory.mktemp("view_edits") / "asset")


def test_roughness_scale_acts_on_perceptual_roughness():
    # alpha 0.36 is r = 0.6; half the roughness is r = 0.3, alpha 0.09 -- not alpha 0.18
    m = SurfaceMaterial.constant(2, albedo=(0.5, 0.4, 0.3), specular=0.2, alpha=0.36)
    out = parse_material(["roughness-scale=0.5"]).apply(m, torch.zeros(2, 3))
    torch.testing.assert_close(out.alpha, torch.full((2, 1), 0.09))
    # r is capped at 1 (alpha 1), and alpha keeps its floor
    assert float(parse_material(["roughness-scale=4"]).apply(m, torch.zeros(2, 3)).alpha[0]) == 1.0
    assert float(parse_material(["roughness-scale=0"]).apply(m, torch.zeros(2, 3)).alpha[0]) == pytest.approx(ALPHA_MIN)
    tinted = parse_material(["specular-scale=2,albedo-tint=1,0.5,0"]).apply(m, torch.zeros(2, 3))
    torch.testing.assert_close(tinted.specular, torch.full((2, 1), 0.4))
    torch.testing.assert_close(tinted.albedo[0], torch.tensor([0.5, 0.2, 0.0]))


def test_controls_write_a_spec_that_parses_back():
    controls = MaterialControls(preset="gold", roughness_scale=0.5, specular_scale=1.5, albedo_tint=(1.0, 0.8, 0.6))
    edit = controls.edit()
    assert edit.spec() == "gold,roughness-scale=0.5,specular-scale=1.5,albedo-tint=1,0.8,0.6"
    assert parse_material([edit.spec()]) == edit
    assert MaterialControls().edit().is_identity and MaterialControls().edit().spec() == ""
    assert MaterialControls(preset="no-specular").edit() == MaterialEdit(no_specular=True)


def test_viewer_pose_and_camera_round_trip():
    cam = default_camera(64, 48)
    back = camera_from_pose(pose_from_camera(cam), 64, 48)
    torch.testing.assert_close(back.W2C, cam.W2C.double(), atol=1e-9, rtol=0)
    torch.testing.assert_close(back.K.double(), cam.K.double(), atol=1e-9, rtol=0)


def test_edit_textures_is_the_edit_applied_texel_by_texel(asset):
    tex = load_asset(asset).textures
    out = edit_textures(tex, parse_material(["roughness-scale=0.5,albedo-tint=1,1,0.5"]))
    np.testing.assert_allclose(out.alpha, np.maximum(0.25 * tex.alpha, ALPHA_MIN), rtol=1e-5)
    np.testing.assert_allclose(out.albedo[..., 2], 0.5 * tex.albedo[..., 2], rtol=1e-6)
    np.testing.assert_array_equal(out.specular, tex.specular)


def test_export_with_edits_halves_perceptual_roughness_and_passes_the_validators(asset, tmp_path, capsys, gltf_validator):
    from srvol.export.usd import validate

    viewer = Viewer(asset, ViewOptions(port=free_port(), out=tmp_path / "out"))
    try:
        viewer.roughness.value = 0.5  # the "roughness scale" slider
        viewer._report(viewer.export_with_edits)  # what the button runs
    finally:
        viewer.stop()
    printed = capsys.readouterr().out
    edited = tmp_path / "out" / "asset_edited_000"
    assert f"wrote {edited}" in printed
    # the command it prints writes the same asset
    command = next(line for line in printed.splitlines() if line.startswith("srvol export"))
    assert "--material roughness-scale=0.5" in command
    args = shlex.split(command)[1:]
    args[args.index("--out") + 1] = str(tmp_path / "by_command")
    assert srvol_main(args) == 0

    original, new = load_asset(asset).textures, load_asset(edited).textures
    # r' = 0.5 r, so alpha' = (0.5 sqrt(alpha))^2 = alpha / 4 (above the floor here: alpha >= 0.09)
    np.testing.assert_allclose(new.alpha, original.alpha / 4, rtol=1e-5)
    np.testing.assert_allclose(read_exr(edited / "raw" / "roughness.exr"),
                               0.5 * read_exr(asset / "raw" / "roughness.exr"), rtol=1e-5)
    np.testing.assert_array_equal(new.albedo, original.albedo)
    np.testing.assert_array_equal(new.specular, original.specular)
    np.testing.assert_array_equal(read_exr(tmp_path / "by_command" / "raw" / "alpha.exr"), new.alpha)
    assert not any(p.name.startswith(".") for p in (tmp_path / "out").iterdir())  # atomic: no temporary left

    assert validate(edited / "model.usda") == []
    issues = json.loads(subprocess.run(["node", str(gltf_validator), str(edited / "model.glb")],
                                       capture_output=True, text=True, check=True).stdout)
    assert issues["numErrors"] == 0, issues["messages"]


def test_save_render_prints_the_relight_command_that_renders_the_same_image(asset, tmp_path, capsys):
    viewer = Viewer(asset, ViewOptions(port=free_port(), out=tmp_path / "out"))
    try:
        viewer.light_handle.position = (1.0, -2.0, 1.5)
        viewer.preset.value = "gold"
        viewer.shadows.value = False
        viewer._report(viewer.save_render)
    finally:
        viewer.stop()
    printed = capsys.readouterr().out
    saved = tmp_path / "out" / "render_000.exr"
    assert saved.is_file() and saved.with_suffix(".png").is_file()
    command = next(line for line in printed.splitlines() if line.startswith("relight "))
    assert "--material gold" in command and "--no-shadows" in command and "--light-pos 1,-2,1.5" in command
    args = shlex.split(command)
    args[args.index("--out") + 1] = str(tmp_path / "again.exr")
    assert srvol_main(args) == 0
    np.testing.assert_array_equal(read_exr(tmp_path / "again.exr"), read_exr(saved))


def test_export_of_fields_applies_the_edit_to_the_baked_maps(asset, tmp_path):
    """A run's "export with edits" (and `srvol export RUN --material`): the edit reaches the baked maps."""
    from functools import partial

    from srvol.export.pipeline import ExportOptions, export_fields

    from view_fixtures import ramp_material, sphere_sdf

    out = tmp_path / "edited"
    export_fields(sphere_sdf, ramp_material, out, ExportOptions(formats=("usd",), resolution=64, faces=1500,
                                                                texture_size=128),
                  texture_edit=partial(edit_textures, edit=parse_material(["roughness-scale=0.5"])))
    np.testing.assert_allclose(load_asset(out).textures.alpha, load_asset(asset).textures.alpha / 4, rtol=1e-5)


def test_export_of_an_asset_refuses_bad_specs_and_its_own_folder_in_one_line(asset, tmp_path, capsys):
    assert srvol_main(["export", str(asset), "--material", "shiny", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("srvol: error: unknown material spec 'shiny'")
    assert srvol_main(["export", str(asset), "--out", str(asset), "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "would replace the asset it is made from" in err[0]
    assert (asset / "asset.json").is_file() and not (tmp_path / "x").exists()
