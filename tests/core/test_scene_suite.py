"""The scene suite: tuning and report sets, per-scene capture defaults, framing, tiny synthesis."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from srvol.data import load_scene
from srvol.synth.generate import aim_camera, gt_mesh, make_cameras, synthesize
from srvol.synth.scenes import DEFAULT_SCENE, REPORT_SCENES, SCENES, TUNING_SCENES
from srvol.types import Camera

SUITE = (*TUNING_SCENES, *REPORT_SCENES)


def test_tuning_and_report_sets_are_disjoint_and_cover_every_scene():
    assert DEFAULT_SCENE in TUNING_SCENES
    assert len(TUNING_SCENES) >= 4 and len(REPORT_SCENES) >= 4
    assert not set(TUNING_SCENES) & set(REPORT_SCENES)
    assert sorted(SUITE) == sorted(SCENES) and len(SCENES) >= 10


def test_scene_captures_span_the_sizes_psfs_and_views_users_bring():
    for names in (TUNING_SCENES, REPORT_SCENES):
        opts = [SCENES[n].synth for n in names]
        assert any(o.aim != (0.0, 0.0) for o in opts)  # each set has off-centre objects
        assert len({o.lr for o in opts}) >= 3 and len({o.psf_sigma for o in opts}) >= 3
    for o in (SCENES[n].synth for n in SUITE):
        assert (120, 90) <= o.lr <= (320, 240) and 0.25 <= o.psf_sigma <= 0.75 and 24 <= o.views <= 64


def test_an_aimed_camera_shows_its_target_at_the_aim_point():
    # 100 x 80 pixels, f = 50: aim (0.5, -0.25) puts the origin 25 px right of and 10 px above the centre
    K = torch.tensor([[50.0, 0, 50], [0, 50.0, 40], [0, 0, 1]], dtype=torch.float64)
    cam = aim_camera(Camera.look_at([3.0, 1.0, 0.5], [0, 0, 0], [0, 0, 1], K, 100, 80), (0.5, -0.25))
    uv = cam.project(torch.zeros(1, 3, dtype=torch.float64))[0]
    np.testing.assert_allclose(uv.numpy(), [75.0, 30.0], atol=1e-9)
    np.testing.assert_allclose(cam.center.numpy(), [3.0, 1.0, 0.5], atol=1e-12)  # turned, not moved


@pytest.mark.parametrize("name", SUITE)
def test_no_view_of_the_scene_defaults_clips_the_object(name):
    """Every training and test camera of the full-size capture sees all of the GT surface, 1 LR px in."""
    opts = replace(SCENES[name].synth, mesh_resolution=40)
    surface = SCENES[name].make_surface()
    points = torch.from_numpy(np.asarray(gt_mesh(surface, opts.mesh_resolution).vertices, dtype=np.float64))
    for cam in make_cameras(opts, opts.views, 0.0) + make_cameras(opts, opts.test_views, 0.37):
        uv = cam.project(points)
        assert uv.min() >= 1.0 and (uv[:, 0].max() <= cam.width - 1) and (uv[:, 1].max() <= cam.height - 1), name


@pytest.mark.parametrize("name", SUITE)
def test_every_scene_synthesises_at_a_tiny_size_into_a_valid_scene(name, tmp_path):
    opts = replace(SCENES[name].synth, lr=(32, 24), views=3, test_views=1, relit_views=1, ss=1, mesh_resolution=32)
    scene = load_scene(synthesize(name, tmp_path / name, opts, progress=False))  # the reader validates it
    assert scene.gt.parts() == ["hr(1)", "normal(1)", "albedo(1)", "relit(1)", "mesh"]
    for v in scene.views.values():
        border = np.concatenate([v.mask[0], v.mask[-1], v.mask[:, 0], v.mask[:, -1]])
        assert not border.any(), f"{name} view {v.name}: the object touches the image border"
        assert 0.02 < v.mask.mean() < 0.7, f"{name} view {v.name}: object covers {v.mask.mean():.0%}"
        assert np.isfinite(v.image).all() and v.image[v.mask].mean() > 0.005
