"""`srvol report`: one self-contained HTML page, checked as text and as a headless-Chromium screenshot."""
from __future__ import annotations

import json
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from srvol.errors import SrvolError
from srvol.images import read_png, write_png
from srvol.report import build_report
from srvol.config import RunConfig, SceneRecord, write_run_config
from srvol.presets import fast_config
from srvol.psf import GaussianPSF

CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)


def _fake_run(root: Path) -> Path:
    """A run folder as training and eval leave it (config, summary, metrics, an eval sheet)."""
    run = root / "run"
    run.mkdir()
    train = replace(fast_config("gaussian"), reasons=("HR pixel footprint 0.0051",))
    write_run_config(run, RunConfig(train=train, scene=SceneRecord(path=None, psf=GaussianPSF(0.375, 4),
                                                                    hr_pixel_size=0.005, light_intensity=None)))
    (run / "train_summary.json").write_text(json.dumps({"iterations": 4732, "train_seconds": 597.0}))
    (run / "metrics.json").write_text(json.dumps({"psnr_hr": 38.39, "normal_mae_deg": 3.10}))
    yy, xx = np.mgrid[0:120, 0:160] / 120.0
    sheet = np.stack([xx, yy, 0.5 * np.ones_like(xx)], -1).astype(np.float32)  # a colour ramp
    write_png(run / "eval_sheet.png", sheet, srgb=True)
    return run


def test_report_inlines_images_metrics_and_commands(tmp_path):
    run = _fake_run(tmp_path)
    page = build_report(run, [], ["srvol train scene --out run"])
    assert page.startswith("<!doctype html>") and page.rstrip().endswith("</html>")
    assert "data:image/png;base64," in page  # self-contained: no file references
    assert "src=\"/" not in page and "src='/" not in page
    assert "38.3900" in page and "HR pixel footprint 0.0051" in page
    assert "4 rays per LR pixel" in page  # the PSF rays in the words `srvol train` prints
    assert "srvol train scene --out run" in page


def test_report_of_a_folder_that_is_not_a_run_is_one_error(tmp_path):
    with pytest.raises(SrvolError, match="not a training run"):
        build_report(tmp_path, [], [])
    (tmp_path / "config.json").write_text("{broken")
    with pytest.raises(SrvolError, match="malformed JSON"):
        build_report(tmp_path, [], [])


@pytest.mark.skipif(CHROMIUM is None, reason="SKIPPED LOUDLY: no chromium on this machine "
                                             "(.ci/run installs Debian's chromium; install it to run this test)")
def test_report_renders_in_headless_chromium(tmp_path):
    """Open the report in headless Chromium and check the screenshot is not blank: the page
    draws text and the inlined colour image, so many distinct colours and non-white pixels."""
    run = _fake_run(tmp_path)
    html = tmp_path / "report.html"
    html.write_text(build_report(run, [], ["srvol train scene --out run"]))
    shot = tmp_path / "shot.png"
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'profile'}", "--hide-scrollbars", "--window-size=1000,900",
           f"--screenshot={shot}", html.as_uri()]
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    img = read_png(shot, srgb=False)[..., :3]
    assert img.shape[0] >= 800 and img.shape[1] >= 900
    not_background = np.abs(img - img[2, 2]).max(-1) > 0.1
    assert not_background.mean() > 0.05  # text + the image: a blank page is ~0
    colours = np.unique((img[not_background] * 15).round(), axis=0)
    assert len(colours) > 50  # the colour ramp came through, not just black text


def _fake_asset(root: Path) -> Path:
    asset = root / "asset"
    (asset / "raw").mkdir(parents=True)
    (asset / "asset.json").write_text(json.dumps({"format": "srvol-asset/1", "files": {"usd": "model.usda",
                                                                                      "glb": "model.glb"},
                                                  "stats": {"faces": 30000}}))
    return asset


def test_report_leads_with_the_asset_then_words_then_diagnostics(tmp_path):
    run = _fake_run(tmp_path)
    asset = _fake_asset(tmp_path)
    previews = tmp_path / "relit"
    previews.mkdir()
    write_png(previews / "light0_key.png", np.full((8, 8, 3), 0.5, np.float32))
    page = build_report(run, [], [], asset=asset, previews=previews, scene=tmp_path / "scene")
    order = [page.index(s) for s in ("Your asset under moved lights", "light0_key", "Files written",
                                     "How good, how long", "Held-out views against the ground truth",
                                     "Diagnostics", "metrics.json")]
    assert order == sorted(order)
    assert f"srvol view {asset} --scene {tmp_path / 'scene'}" in page  # the live viewer, linked
    assert "model.glb" in page and "File &gt; Import &gt; glTF 2.0" in page
    # the headline in words a person reads: 597 s of training, 38.39 dB is "very good", 3.1 deg "very accurate"
    assert "Training took 9 min 57 s (4732 steps)." in page
    assert "38.4 dB PSNR: very good" in page
    assert "off by 3.1 degrees on average (very accurate)" in page


def test_headline_words_follow_the_bands():
    from srvol.report import headline

    assert headline({"psnr_hr": 41.0}, {})[0].endswith("excellent: side by side, differences are hard to find.")
    assert "poor" in headline({"relit_psnr": 22.0}, {})[0]
    assert "(rough in places)" in headline({"normal_mae_deg": 12.0}, {})[0]
    assert headline({"dark_fraction": 0.9}, {})[-1].startswith("Warning: most renders are far darker")
    assert headline({}, {}) == []
