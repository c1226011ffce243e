"""What ``relight`` renders: a trained run, an exported asset, or an exact built-in scene.

A :class:`Source` bundles the :class:`~srvol.relight.render.RelightScene` with what the command
line needs around it: the intensity of the light the source was seen under (``--intensity``
replaces it) and the scene folder whose cameras ``--view NAME`` refers to.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch

from srvol.camera_rig import RIG_LIGHT_INTENSITY, rig_camera
from srvol.errors import SrvolError
from srvol.field_adapters import material_in_float64, sdf_in_float64
from srvol.relight.render import AssetScene, FieldScene, RelightScene, TraceOptions
from srvol.types import Camera


@dataclass(frozen=True)
class Source:
    """kind: "run" | "asset" | "builtin"; label: for sheets and messages;
    intensity: RGB radiant intensity of the light the source was seen under (a run: its flash, given or
    learned; a built-in scene or an asset: the rig's flash, RIG_LIGHT_INTENSITY), what the CLI's light gets
    unless ``--intensity`` says otherwise; scene_dir: the scene for ``--view`` (None if unknown)."""

    kind: str
    label: str
    scene: RelightScene
    intensity: tuple[float, float, float]
    scene_dir: Path | None


BUILTIN_FIELDS = ("bumpy", "glossy")


def builtin_scene(name: str) -> FieldScene:
    """The exact analytic SDF and material of a built-in scene, with a step scale of 1 / Lipschitz."""
    from srvol.synth import scenes

    if name == "bumpy":
        return FieldScene(sdf_in_float64(scenes.bumpy_sdf), material_in_float64(scenes.bumpy_material),
                          TraceOptions(step_scale=1 / 1.6))
    if name == "glossy":
        return FieldScene(sdf_in_float64(scenes.glossy_sdf), material_in_float64(scenes.glossy_material),
                          TraceOptions(step_scale=0.95))
    raise SrvolError(f"--builtin {name}: no exact SDF for this scene (choose from {', '.join(BUILTIN_FIELDS)})")


def is_run_dir(path: Path) -> bool:
    return (Path(path) / "config.json").is_file()


def load_source(path: Path | None, builtin: str | None) -> Source:
    """Open SOURCE (a run folder or an asset folder) or the ``--builtin`` scene; one-line errors."""
    from srvol.export.asset import is_asset_dir, load_asset

    if builtin is not None:
        if path is not None:
            raise SrvolError("give either SOURCE or --builtin NAME, not both")
        return Source("builtin", f"builtin:{builtin}", builtin_scene(builtin), (RIG_LIGHT_INTENSITY,) * 3, None)
    if path is None:
        raise SrvolError("relight needs SOURCE (a training run or an exported asset folder) or --builtin NAME")
    path = Path(path)
    if not path.is_dir():
        raise SrvolError(f"{path}: no such folder (SOURCE must be a training run or an exported asset folder)")
    if is_asset_dir(path):
        return Source("asset", f"asset:{path.name}", AssetScene.build(load_asset(path)),
                      (RIG_LIGHT_INTENSITY,) * 3, None)
    if is_run_dir(path):
        return load_run_source(path)
    raise SrvolError(f"{path}: neither a training run (no config.json) nor an exported asset (no asset.json)")


def load_run_source(run_dir: Path) -> Source:
    """A trained run through ``srvol.checkpoint.load_model`` (the one door into a model)."""
    try:
        from srvol.checkpoint import load_model
    except ImportError:
        raise SrvolError(f"{run_dir}: this srvol cannot load trained runs yet (srvol.checkpoint.load_model "
                         "is missing)") from None
    model, info = load_model(run_dir, device="cpu")
    scene = FieldScene(model.sdf, model.material, TraceOptions(step_scale=0.9))
    return Source("run", f"run:{Path(run_dir).name}", scene, tuple(float(c) for c in info.light_intensity),
                  info.scene_dir)


def default_camera(width: int, height: int, azimuth_deg: float = -60.0, elevation_deg: float = 20.0) -> Camera:
    """A camera of the built-in scenes' rig (:mod:`srvol.camera_rig`) at the given azimuth and elevation,
    looking at the origin, +z up, framing the unit sphere's object."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = torch.tensor([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    return rig_camera(direction, width, height)


def resize_camera(camera: Camera, width: int, height: int) -> Camera:
    """The same view at another resolution: intrinsics scaled per axis (pixel edges to pixel edges)."""
    K = camera.K.clone().double()
    K[0, :] *= width / camera.width
    K[1, :] *= height / camera.height
    K[2] = torch.tensor([0.0, 0.0, 1.0], dtype=K.dtype)
    return Camera(K=K, W2C=camera.W2C.double(), width=width, height=height)
