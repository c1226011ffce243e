"""Similarities, the working resolution and mask helpers: worked examples."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from srvol.capture.frame import Similarity, fit_similarity, rotation_angle_deg, rotation_between
from srvol.capture.masks import clean_mask
from srvol.capture.resolution import choose_resolution, to_working
from srvol.errors import SrvolError
from srvol.types import Camera


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_fit_similarity_recovers_a_known_one():
    rng = np.random.default_rng(1)
    sim = Similarity(2.5, random_rotation(rng), np.array([0.3, -1.0, 4.0]))
    src = rng.normal(size=(20, 3))
    got = fit_similarity(src, sim.apply(src))
    assert got.scale == pytest.approx(2.5)
    assert rotation_angle_deg(got.rotation, sim.rotation) < 1e-6
    assert np.allclose(got.translation, sim.translation)
    assert np.allclose(sim.inverse().apply(sim.apply(src)), src)


def test_a_camera_moved_by_a_similarity_sees_the_same_image():
    rng = np.random.default_rng(2)
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]], dtype=torch.float64)
    cam = Camera.look_at([3.0, 1.0, 0.5], [0, 0, 0], [0, 0, 1], K, 64, 48)
    sim = Similarity(0.37, random_rotation(rng), np.array([1.0, 2.0, -0.5]))
    pts = rng.normal(scale=0.5, size=(10, 3))
    moved = sim.camera(cam)
    assert torch.allclose(cam.project(torch.from_numpy(pts)), moved.project(torch.from_numpy(sim.apply(pts))))
    assert np.allclose(moved.center.numpy(), sim.apply(cam.center.numpy()[None])[0])


def test_rotation_between_takes_a_onto_b():
    for a, b in (([0, 0, 1.0], [0, 0, 1.0]), ([1.0, 0, 0], [0, 0, 1.0]), ([0, 0, 1.0], [0, 0, -1.0])):
        R = rotation_between(np.array(a), np.array(b))
        assert np.allclose(R @ a, b) and np.isclose(np.linalg.det(R), 1)


def test_working_resolution_defaults_and_whole_factors():
    assert choose_resolution((320, 240), None).factor == 1
    r = choose_resolution((4032, 3024), None)
    assert (r.factor, r.size, r.crop) == (11, (366, 274), (4026, 3014))
    assert r.psf_sigma_lr_px == pytest.approx(math.hypot(0.5, 0.375 / 11))
    assert choose_resolution((640, 480), (320, 240)).factor == 2
    with pytest.raises(SrvolError, match="whole factors"):
        choose_resolution((640, 480), (300, 200))


def test_decimation_keeps_a_flat_image_flat_and_the_mean():
    r = choose_resolution((64, 48), (16, 12))
    img = np.full((48, 64, 3), 0.25, np.float32)
    assert np.allclose(to_working(img, r), 0.25)


def test_clean_mask_fills_holes_and_drops_specks():
    m = np.zeros((50, 50), bool)
    m[10:40, 10:40] = True
    m[20:25, 20:25] = False  # a hole
    m[2, 45] = True  # a speck
    out = clean_mask(m)
    assert out[22, 22] and not out[2, 45] and out.sum() == 900
