"""The real-capture terms in training, as worked examples on the small imported capture:
``auto`` turns them on for an imported scene only, every term's parameter gets a gradient from the
photometric loss, the flash offset moves the light that shades the rays, the terms survive a resume,
and ``--capture-terms`` / ``--flash-offset`` say in one line what is wrong with them."""
from __future__ import annotations

import argparse
import json
from dataclasses import replace

import pytest
import torch

from srvol.capture.frame import read_normalization
from srvol.capture.terms import CaptureTerms, CaptureTermsConfig
from srvol.config import TrainConfig
from srvol.presets import AUTO_CAPTURE_TERMS, auto_config
from srvol.data import load_scene
from srvol.errors import SrvolError
from srvol.fields import SceneFields
from srvol.losses import compute_loss
from srvol.pixels import PixelBank
from srvol.psf import PsfSampler, SRMode
from srvol.train import CAPTURE_TERMS_NAME, train
from srvol.train_cli import add_parser, build_config


def _small(cfg: TrainConfig, iters: int) -> TrainConfig:
    return replace(cfg, iters=iters, time_budget=0.0, checkpoint_every=4, log_every=2, batch_in=64, batch_out=32,
                   batch_eikonal=64, batch_stage2=96)


def test_auto_turns_the_terms_on_for_an_imported_scene_only(small_import, default_scene):
    imported = auto_config(load_scene(small_import[0]), "gaussian", 60.0)
    assert imported.capture == AUTO_CAPTURE_TERMS and imported.capture.learn_flash_offset
    assert any("real-capture terms on" in r for r in imported.reasons)
    assert auto_config(load_scene(default_scene), "gaussian", 60.0).capture is None
    assert TrainConfig.from_json(json.loads(json.dumps(imported.to_json()))).capture == imported.capture


def test_every_term_gets_a_gradient_and_the_reference_photo_keeps_gain_one(small_import):
    scene = load_scene(small_import[0])
    cfg = _small(auto_config(scene, "gaussian", 60.0), 1)
    bank = PixelBank(scene, torch.device("cpu"))
    fields = SceneFields(cfg.fields, learn_intensity=True)
    terms = CaptureTerms(len(scene.train), bank.camera_of_view, CaptureTermsConfig())  # all of them
    psf = PsfSampler(SRMode(cfg.sr), scene.info.psf)
    loss = compute_loss(fields, bank, cfg, psf, 1, torch.Generator().manual_seed(0), fields.intensity,
                        capture=terms)
    loss.total.backward()
    for name in ("log_gain", "vignetting", "ambient_raw", "flash_offset", "pose_rotation", "pose_shift"):
        grad = getattr(terms, name).grad
        assert grad is not None and grad.abs().sum() > 0, name
    g = terms.gain(torch.arange(len(scene.train)))
    assert g[0] == 1.0  # the reference photo: exp(log_gain * 0)
    assert terms.pose_rotation.grad[0].abs().sum() == 0  # and its pose holds the frame


def test_the_flash_offset_moves_the_light_of_each_ray(small_import):
    scene = load_scene(small_import[0])
    cfg = _small(auto_config(scene, "gaussian", 60.0), 1)
    bank = PixelBank(scene, torch.device("cpu"))
    torch.manual_seed(0)
    fields = SceneFields(cfg.fields, learn_intensity=True)
    psf = PsfSampler(SRMode(cfg.sr), scene.info.psf)

    def stage2_loss(offset):
        """Stage 2's photometric loss on the same pixels and ray jitter, the flash at ``offset`` (None: no terms)."""
        terms = None if offset is None else CaptureTerms(
            len(scene.train), bank.camera_of_view,
            CaptureTermsConfig(exposure=False, vignetting=False, ambient=False, pose=False, flash_offset=offset))
        torch.manual_seed(1)  # the samples' jitter
        return float(compute_loss(fields, bank, cfg, psf, 2, torch.Generator().manual_seed(0), fields.intensity,
                                  capture=terms).photometric)

    assert stage2_loss((0.0, 0.0, 0.0)) == pytest.approx(stage2_loss(None), abs=1e-6)  # no offset: co-located
    assert stage2_loss((0.3, 0.0, 0.0)) != stage2_loss(None)  # the loss sees the light move
    # each ray's flash sits 0.3 to its camera's right: the camera's x axis in the world
    from srvol.losses import flash_lit

    batch = bank.sample(64, True, psf, 2, torch.Generator().manual_seed(0))
    terms = CaptureTerms(len(scene.train), bank.camera_of_view,
                         CaptureTermsConfig(exposure=False, vignetting=False, ambient=False, pose=False,
                                            flash_offset=(0.3, 0.0, 0.0)))
    rays, light = flash_lit(bank, batch.rays, batch.ray_view, batch.n_rays, fields.intensity, terms)
    right = bank.R_T[batch.ray_view][:, :, 0]  # camera-to-world rotation's first column
    assert torch.allclose(light.position - rays.origins, 0.3 * right, atol=1e-5)


def test_the_terms_are_saved_and_survive_a_resume(small_import, tmp_path):
    scene = load_scene(small_import[0])
    cfg = _small(auto_config(scene, "gaussian", 60.0), 6)
    run = tmp_path / "run"
    train(scene, replace(cfg, iters=4), run, progress=False, say=lambda *_: None)
    first = json.loads((run / CAPTURE_TERMS_NAME).read_text())
    assert set(first["exposure_gain"]) == set(scene.train) and first["exposure_gain"][scene.train[0]] == 1.0
    assert first["ambient_rgb"][0] >= 0
    said = []
    train(scene, cfg, run, resume=True, progress=False, say=said.append)
    assert any("resuming at step 4" in s for s in said)
    second = json.loads((run / CAPTURE_TERMS_NAME).read_text())
    assert second["flash_offset_camera_frame"] != first["flash_offset_camera_frame"]  # kept learning from there


def test_capture_flags(small_import):
    scene_dir = small_import[0]
    scene = load_scene(scene_dir)
    ap = argparse.ArgumentParser()
    add_parser(ap.add_subparsers())

    def cfg_of(*extra):
        return build_config(scene, ap.parse_args(["train", str(scene_dir), "--out", "unused", *extra]))

    assert cfg_of("--capture-terms", "none").capture is None
    only = cfg_of("--capture-terms", "exposure,ambient").capture
    assert (only.exposure, only.vignetting, only.ambient, only.pose, only.learn_flash_offset) == (
        True, False, True, False, False)
    given = cfg_of("--flash-offset", "0.02,0,0").capture
    scale = read_normalization(scene_dir).scale
    assert given.flash_offset == pytest.approx((0.02 * scale, 0.0, 0.0)) and not given.learn_flash_offset
    for bad, says in ((["--capture-terms", "exposure,gamma"], "--capture-terms"),
                      (["--flash-offset", "1,2"], "--flash-offset"),
                      (["--capture-terms", "exposure", "--flash-offset", "0,0,0.1"], "flash term")):
        with pytest.raises(SrvolError, match=says):
            cfg_of(*bad)
