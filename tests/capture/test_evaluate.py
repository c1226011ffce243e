"""``srvol eval --gt``: an exact sphere seen in a scene frame that differs from the GT's by a known
similarity scores as exact once aligned (renders by the GT ray caster, no training)."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
import torch

from srvol.capture.evaluate import channel_gain, evaluate_capture
from srvol.capture.frame import Similarity
from srvol.data import GroundTruth, Scene, SceneInfo, View, camera_to_json
from srvol.images import write_exr
from srvol.synth.render import render
from srvol.synth.surfaces import AnalyticSurface
from srvol.types import Camera, PointLight, SurfaceMaterial

RADIUS = 0.5


def grey(x):
    return SurfaceMaterial.constant(x.shape[0], albedo=(0.6, 0.5, 0.4), specular=0.04, alpha=0.2, dtype=x.dtype)


def sphere_at(center: np.ndarray, radius: float) -> AnalyticSurface:
    c = torch.as_tensor(center, dtype=torch.float64)
    return AnalyticSurface(sdf=lambda x: (x - c.to(x)).norm(dim=-1) - radius, material=grey, bound=0.99)


def ring_camera(k: int, n: int, w: int = 48, h: int = 36) -> Camera:
    ang = 2 * math.pi * k / n
    K = torch.tensor([[50.0, 0, w / 2], [0, 50.0, h / 2], [0, 0, 1]], dtype=torch.float64)
    return Camera.look_at([2.5 * math.cos(ang), 2.5 * math.sin(ang), 0.6], [0, 0, 0], [0, 0, 1], K, w, h)


@dataclass(frozen=True)
class Fields:
    surface: AnalyticSurface

    def sdf(self, x):
        return self.surface.sdf(x.double()).to(x.dtype)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """GT folder (GT frame: the sphere at the origin) and a scene whose frame is S(GT frame)."""
    import trimesh

    root = tmp_path_factory.mktemp("capture_eval")
    gt = root / "gt"
    gt.mkdir()
    q, r = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))
    R = q * np.sign(np.diag(r))
    R = R if np.linalg.det(R) > 0 else -R
    S = Similarity(0.7, R, np.array([0.1, -0.05, 0.08]))  # GT -> scene
    photos = {f"IMG_{k:04d}": ring_camera(k, 8) for k in range(8)}
    (gt / "photo_cameras.json").write_text(json.dumps({f"{n}.jpg": camera_to_json(c) for n, c in photos.items()}))
    surface = AnalyticSurface(sdf=lambda x: x.norm(dim=-1) - RADIUS, material=grey, bound=0.99)
    test = ring_camera(1, 3)
    gt_render = render(surface, test, PointLight.at_camera(test, (10.0,) * 3), ss=2)
    write_exr(gt / "hr" / "test_00.exr", gt_render.rgb)
    write_exr(gt / "normal" / "test_00.exr", gt_render.normal)
    write_exr(gt / "albedo" / "test_00.exr", gt_render.albedo)
    (gt / "hr_cameras.json").write_text(json.dumps({"test_00": camera_to_json(test)}))
    light = PointLight.make([0.5, 2.0, 1.5], 8.0)
    write_exr(gt / "relit" / "test_00_l0.exr", render(surface, test, light, ss=2, shadows=True, maps=False).rgb)
    (gt / "relit.json").write_text(json.dumps([{"name": "test_00_l0", "camera": "test_00",
                                                "light_pos": light.position.tolist(),
                                                "intensity": light.intensity.tolist()}]))
    (gt / "capture.json").write_text(json.dumps({"light_intensity": 10.0}))
    trimesh.creation.icosphere(subdivisions=5, radius=RADIUS).export(gt / "mesh.ply")
    views = {n: View(n, S.camera(c), np.zeros((36, 48, 3), np.float32), None) for n, c in photos.items()}
    scene = Scene(root=root / "scene", info=SceneInfo(), views=views, train=list(views), test=[],
                  gt=GroundTruth(root / "scene" / "gt"))
    return gt, scene, sphere_at(S.apply(np.zeros((1, 3)))[0], RADIUS * S.scale)


def test_an_exact_model_in_another_frame_scores_as_exact(case):
    gt, scene, moved = case

    def view(cam, light):
        r = render(moved, cam, light, ss=2)
        return type("V", (), {"rgb": r.rgb, "opacity": r.coverage, "normal": r.normal, "albedo": r.albedo})

    def relit(cam, light):
        return render(moved, cam, light, ss=2, shadows=True, maps=False).rgb

    flash = (3.0, 3.0, 3.0)  # any: the gain absorbs intensity and exposure
    m = evaluate_capture(scene, gt, view, flash, relit=relit, fields=Fields(moved))
    assert m["registered"] == 1.0
    assert m["rotation_median_deg"] < 1e-5
    assert m["gain"] == pytest.approx([10.0 * 0.7 ** 2 / 3] * 3, rel=1e-3)
    assert m["psnr_hr"] > 50 and m["normal_mae_deg"] < 0.5 and m["albedo_psnr"] > 50
    assert m["relit_psnr"] > 50
    assert m["chamfer"] < 0.005


def test_a_misaligned_model_scores_badly(case):
    """The same sphere where the frame says it is not: the scores must drop (the test can fail)."""
    gt, scene, moved = case
    off = sphere_at(np.array([0.25, 0.0, 0.0]), RADIUS * 0.7)

    def view(cam, light):
        r = render(off, cam, light, ss=1)
        return type("V", (), {"rgb": r.rgb, "opacity": r.coverage, "normal": r.normal, "albedo": r.albedo})

    m = evaluate_capture(scene, gt, view, (3.0,) * 3, fields=Fields(off))
    assert m["psnr_hr"] < 30 and m["chamfer"] > 0.05


def test_channel_gain_is_least_squares():
    pred = [np.ones((2, 2, 3)) * [1.0, 2.0, 4.0]]
    gt = [np.ones((2, 2, 3)) * [2.0, 2.0, 2.0]]
    assert np.allclose(channel_gain(pred, gt), [2.0, 1.0, 0.5])
