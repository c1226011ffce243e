"""Fixtures of the core tests: a tiny hand-made scene in the srvol format, written in a few ms."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from srvol.data import SceneInfo, View, write_scene_folder
from srvol.types import Camera

TINY_W, TINY_H = 8, 6
TINY_STEMS = ("000", "001", "002")


def tiny_camera(k: int, width: int = TINY_W, height: int = TINY_H) -> Camera:
    """Camera k of a ring at distance 3 around the origin, f = 10 px, principal point at the centre."""
    ang = 2 * math.pi * k / 3
    K = torch.tensor([[10.0, 0, width / 2], [0, 10.0, height / 2], [0, 0, 1]], dtype=torch.float64)
    return Camera.look_at([3 * math.cos(ang), 3 * math.sin(ang), 0.5], [0, 0, 0], [0, 0, 1], K, width, height)


def tiny_views() -> list[View]:
    rng = np.random.default_rng(0)
    views = []
    for k, stem in enumerate(TINY_STEMS):
        image = rng.random((TINY_H, TINY_W, 3)).astype(np.float32)
        mask = np.zeros((TINY_H, TINY_W), bool)
        mask[1:5, 2:6] = True
        views.append(View(name=stem, camera=tiny_camera(k), image=image, mask=mask))
    return views


TINY_INFO = SceneInfo(color_space="linear", light_intensity=(2.0, 2.0, 2.0), psf_sigma_lr_px=0.5, sr_factor=2,
                      train=("000", "001"), test=("002",))


def write_tiny_scene(out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    write_scene_folder(out, tiny_views(), TINY_INFO)
    return out


@pytest.fixture
def tiny_scene(tmp_path) -> Path:
    """A valid 3-view 8x6 scene (EXR images, PNG masks, scene.json) in a fresh folder."""
    return write_tiny_scene(tmp_path / "tiny")
