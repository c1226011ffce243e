"""The one door into a trained model: ``load_model(run_dir)``.

A run folder (DESIGN.md section 5) holds config.json (plain JSON with a schema
version), model.pt (state dict) and checkpoints/. Consumers (eval, export,
relight) get a :class:`~srvol.types.FieldModel` and a :class:`RunInfo`; they
never import the training loop.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RunInfo:
    """What a consumer needs to know about a trained run besides the fields.

    run_dir: the run folder; scene_dir: the scene it was trained on (None if unknown);
    light_intensity: the co-located light's intensity (given or learned), RGB;
    sr_factor: HR/LR ratio; hr_pixel_size: scene units covered by one HR pixel at the
    object's distance (median over training views) -- sizes marching cubes, faces and textures.
    """

    run_dir: Path
    scene_dir: Path | None
    light_intensity: tuple[float, float, float]
    sr_factor: int
    hr_pixel_size: float
