"""Scoring against a scene's relit ground truth, and --view on a scene's test cameras."""
from __future__ import annotations

from srvol.cli import main
from srvol.data import load_scene
from srvol.images import read_exr, read_png
from srvol.relight.compare import NamedScene, compare_relit, write_comparison_sheet
from srvol.relight.sources import builtin_scene


def test_exact_fields_match_the_relit_ground_truth(default_scene, tmp_path):
    comp = compare_relit(default_scene, [NamedScene("fields", builtin_scene("bumpy"))], ss=1)
    assert len(comp.scores) == 1
    psnr, ssim = comp.mean("fields")
    assert psnr > 40.0 and ssim > 0.99
    sheet = tmp_path / "sheet.png"
    write_comparison_sheet(sheet, comp, "bumpy")
    img = read_png(sheet, srgb=False)
    assert img.shape[1] > 3 * 160  # GT | fields | |err| side by side at HR width 160


def test_view_renders_the_scenes_hr_camera(capsys, default_scene, tmp_path):
    scene = load_scene(default_scene, load_images=False)
    stem = scene.test[0]
    out = tmp_path / "view.exr"
    rc = main(["relight", "--builtin", "bumpy", "--scene", str(default_scene), "--view", stem,
               "--light-pos", "1.5,-1,1.5", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    hr = scene.hr_camera(stem)
    assert read_exr(out).shape == (hr.height, hr.width, 3) == (120, 160, 3)
    rc = main(["relight", "--builtin", "bumpy", "--scene", str(default_scene), "--view", "nope",
               "--light-pos", "1.5,-1,1.5", "--out", str(tmp_path / "x.exr")])
    assert rc == 2 and "--view nope: no such view" in capsys.readouterr().err
