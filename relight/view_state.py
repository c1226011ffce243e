"""What ``srvol view`` renders, as typed values: the viewer's camera, the light, the material controls.

The browser (viser) is a source of these values and nothing else: each tick the server reads its
widgets into one :class:`ViewState`; a state that differs from the last one rendered is rendered
again by the relighter (:func:`srvol.relight.render.render_scene`), the same call ``relight`` makes.
The state also writes itself back as the equivalent command lines (``relight`` for "save render",
``srvol export`` for "export with edits"), so what a user did in the browser can be scripted.

Frames: the scene frame of :mod:`srvol.types` (object in the unit sphere, +z up). viser's cameras
follow OpenCV axes too (+x right, +y down, +z forward); a pose's ``wxyz`` is the rotation
camera -> world (R in ``p_world = R p_camera + position``), ``fov_y`` the vertical field of view.
"""
from __future__ import annotations

import math
import shlex
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from srvol.camera_rig import CAMERA_DISTANCE
from srvol.relight.edits import PRESETS, MaterialEdit
from srvol.types import Camera, PointLight

PRESET_NAMES = ("as baked", *PRESETS, "no-specular")
"""The material dropdown: the asset or run as it is, then the presets of ``relight --material``."""

FULL_SIZE = (640, 480)
"""Render panel size (W x H) when the view is still, and always on the asset path."""
DRAG_SIZE = (160, 120)
"""Render panel size while the state is changing, on the neural path (a trained model on 2 cores
sphere-traces a 640x480 frame in seconds, a 160x120 one ~16x faster)."""


@dataclass(frozen=True)
class ViewerPose:
    """A viewer camera: position (3,) in the scene frame, wxyz (4,) rotation camera -> world
    (OpenCV axes), fov_y vertical field of view in radians, aspect width / height."""

    position: tuple[float, float, float]
    wxyz: tuple[float, float, float, float]
    fov_y: float
    aspect: float


@dataclass(frozen=True)
class MaterialControls:
    """The material panel: a preset (one of PRESET_NAMES) and three scales applied after it."""

    preset: str = "as baked"
    roughness_scale: float = 1.0
    specular_scale: float = 1.0
    albedo_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def edit(self) -> MaterialEdit:
        """The :class:`MaterialEdit` these controls stand for (what relight and export apply)."""
        return MaterialEdit(preset=PRESETS.get(self.preset), no_specular=self.preset == "no-specular",
                            roughness_scale=float(self.roughness_scale), specular_scale=float(self.specular_scale),
                            albedo_tint=tuple(float(c) for c in self.albedo_tint))


@dataclass(frozen=True)
class ViewState:
    """Everything a render panel image depends on (equal states give the same image)."""

    pose: ViewerPose
    light_position: tuple[float, float, float]
    intensity: float
    shadows: bool
    material: MaterialControls

    def light(self) -> PointLight:
        return PointLight.make(list(self.light_position), float(self.intensity))


# ----------------------------------------------------------------------------- cameras

def rotation_from_wxyz(wxyz) -> np.ndarray:
    """(3, 3) rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(c) for c in np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz))
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def wxyz_from_rotation(R: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, np.float64)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = (0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s)
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q) / np.linalg.norm(q)
    return tuple(float(c) for c in (q if q[0] >= 0 else -q))


def camera_from_pose(pose: ViewerPose, width: int, height: int) -> Camera:
    """The pinhole camera (square pixels, centred principal point) of a viewer pose at ``width x height``."""
    R = rotation_from_wxyz(pose.wxyz)  # camera -> world
    p = np.asarray(pose.position, np.float64)
    W2C = np.eye(4)
    W2C[:3, :3] = R.T
    W2C[:3, 3] = -R.T @ p
    f = 0.5 * height / math.tan(0.5 * pose.fov_y)
    K = torch.tensor([[f, 0.0, 0.5 * width], [0.0, f, 0.5 * height], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return Camera(K=K, W2C=torch.from_numpy(W2C), width=width, height=height)


def pose_from_camera(camera: Camera) -> ViewerPose:
    """A srvol camera as a viewer pose (its vertical field of view; the principal point is not kept)."""
    W2C = camera.W2C.double().cpu().numpy()
    R = W2C[:3, :3].T
    position = -R @ W2C[:3, 3]
    fy = float(camera.K[1, 1])
    return ViewerPose(position=tuple(float(c) for c in position), wxyz=wxyz_from_rotation(R),
                      fov_y=2.0 * math.atan(0.5 * camera.height / fy), aspect=camera.width / camera.height)


def orbit_position(azimuth_deg: float, elevation_deg: float, distance: float = CAMERA_DISTANCE) -> np.ndarray:
    """A point at ``distance`` from the origin, azimuth about +z from +x, elevation above the xy plane."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return distance * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def panel_size(aspect: float, width: int) -> tuple[int, int]:
    """The render panel's (W, H) for a viewer canvas of ``aspect``: W fixed, H from the aspect (clamped to
    W / 2 .. W, even)."""
    h = int(round(width / max(aspect, 1e-3)))
    h = min(max(h, width // 2), width)
    return width, h - h % 2


def render_size(kind: str, settled: bool, aspect: float) -> tuple[int, int]:
    """Render panel size: an asset at full size always; a run at DRAG_SIZE until the state settles."""
    base = FULL_SIZE if kind == "asset" or settled else DRAG_SIZE
    return panel_size(aspect, base[0])


# ----------------------------------------------------------------------------- equivalent commands

def _vec(values) -> str:
    return ",".join(f"{float(v):.4g}" for v in values)


def relight_command(source: Path, camera_file: Path, size: tuple[int, int], state: ViewState, out: Path) -> str:
    """The ``relight`` command line that renders what the panel shows (``camera_file``: the pose written
    as a cameras.json-style file)."""
    args = ["relight", str(source), "--camera", str(camera_file), "--resolution", f"{size[0]}x{size[1]}",
            "--light-pos", _vec(state.light_position), "--intensity", f"{state.intensity:.4g}"]
    spec = state.material.edit().spec()
    if spec:
        args += ["--material", spec]
    if not state.shadows:
        args.append("--no-shadows")
    return shlex.join(args + ["--out", str(out)])


def export_command(source: Path, edit: MaterialEdit, formats: tuple[str, ...], out: Path) -> str:
    """The ``srvol export`` command line that writes the edited asset."""
    args = ["srvol", "export", str(source), "--format", ",".join(formats)]
    spec = edit.spec()
    if spec:
        args += ["--material", spec]
    return shlex.join(args + ["--out", str(out)])
