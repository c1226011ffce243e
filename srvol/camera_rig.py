"""The built-in scenes' camera rig: cameras on a sphere about the object, looking at the origin.

``srvol synth`` places its views with :func:`rig_camera`; ``srvol relight``'s default camera is
one more camera of the same rig, so that a built-in scene renders as framed in its data set.
The flash of those scenes has radiant intensity :data:`RIG_LIGHT_INTENSITY`; callers build
their :class:`~srvol.types.PointLight` from it and pass the light on.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from srvol.types import Camera

CAMERA_DISTANCE = 2.6
"""Distance of the rig's cameras from the origin (scene units)."""

RIG_LIGHT_INTENSITY = 10.0
"""Radiant intensity (W/sr, grey) of the light the built-in scenes are rendered with."""

OBJECT_RADIUS = 0.82
"""Radius about the origin that the frame holds (the built-in objects reach up to 0.8)."""


def rig_intrinsics(width: int, height: int) -> Tensor:
    """(3, 3) float64 intrinsics: square pixels, centred principal point, and a focal length that
    fits the sphere of :data:`OBJECT_RADIUS` into 95 % of the image height seen from the rig."""
    f = 0.95 * (height / 2) / math.tan(math.asin(OBJECT_RADIUS / CAMERA_DISTANCE))
    return torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64)


def rig_camera(direction, width: int, height: int, distance: float = CAMERA_DISTANCE) -> Camera:
    """The rig's camera at ``distance * direction`` (a unit (3,) array or tensor) looking at the
    origin, +z up in the image. The intrinsics do not depend on ``distance``: a closer camera
    shows the object larger (a scene's zoom)."""
    eye = distance * torch.as_tensor(direction)
    return Camera.look_at(eye, [0, 0, 0], [0, 0, 1], rig_intrinsics(width, height), width, height)
