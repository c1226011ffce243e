"""The demo's preview lights sit on the camera's side of the object: each one lights what the camera sees."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from srvol.demo import LIGHT_DISTANCE, lights_facing
from srvol.types import Camera


@pytest.mark.parametrize("camera", [(2.6, 0.0, 0.0), (-1.3, 2.25, 0.9), (0.0, -2.0, -1.2)])
def test_every_preview_light_is_on_the_camera_side(camera):
    d = np.asarray(camera) / np.linalg.norm(camera)
    lights = lights_facing(camera)
    assert [name for name, _ in lights] == ["key", "fill", "top"]
    for name, pos in lights:
        p = np.asarray(pos)
        assert np.linalg.norm(p) == pytest.approx(LIGHT_DISTANCE)
        assert p @ d / LIGHT_DISTANCE > 0.3, name  # within ~70 degrees of the camera's direction


def test_key_light_is_right_and_above_for_a_camera_on_the_x_axis():
    # camera on +x looking at the origin (towards -x), +z up: its image right is +y (Camera.look_at's x
    # axis); the key light is 35 deg to the right and 25 deg up
    _, key = lights_facing((2.6, 0.0, 0.0))[0]
    expected = LIGHT_DISTANCE * np.array([np.cos(np.radians(25)) * np.cos(np.radians(35)),
                                          np.cos(np.radians(25)) * np.sin(np.radians(35)), np.sin(np.radians(25))])
    cam = Camera.look_at([2.6, 0.0, 0.0], [0, 0, 0], [0, 0, 1], torch.eye(3), 8, 8)
    assert cam.W2C[0, :3].tolist() == pytest.approx([0.0, 1.0, 0.0])  # image x (right) is world +y
    np.testing.assert_allclose(key, expected, atol=1e-12)
