"""Relit images against a scene's ground truth: metrics and comparison sheets.

A synthetic scene lists its moved-light GT renders in gt/relit.json (name, camera stem,
light_pos, intensity; images at HR in gt/relit/<name>.exr, cameras in gt/hr_cameras.json).
Each :class:`NamedScene` (the neural fields, an asset, ...) is rendered from the same HR camera
under the same light, scored with PSNR and SSIM (linear, peak 1, whole image) and laid out as
one sheet row per light: GT | each renderer | |error| of each renderer.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from srvol.data import load_scene
from srvol.errors import SrvolError
from srvol.metrics import psnr, ssim
from srvol.relight.edits import MaterialEdit
from srvol.relight.render import RelightScene, RelitImage, render_scene
from srvol.sheets import Tile, error_to_rgb, write_sheet

ERROR_VMAX = 0.1
"""|error| (linear radiance, mean over RGB) shown at full heat in the sheets."""


@dataclass(frozen=True)
class NamedScene:
    """A renderer to compare: a label for the sheet and a scene to render."""

    name: str
    scene: RelightScene


@dataclass(frozen=True)
class RelitScore:
    """One renderer on one GT light: PSNR (dB) and SSIM of the whole HR image, render seconds."""

    light: str
    renderer: str
    psnr: float
    ssim: float
    seconds: float


@dataclass(frozen=True)
class RelitComparison:
    scores: list[RelitScore]
    rows: list[list[Tile]]

    def mean(self, renderer: str) -> tuple[float, float]:
        """Mean PSNR and SSIM of one renderer over all lights."""
        mine = [s for s in self.scores if s.renderer == renderer]
        return float(np.mean([s.psnr for s in mine])), float(np.mean([s.ssim for s in mine]))


def compare_relit(scene_dir: str | Path, renderers: Sequence[NamedScene], ss: int = 2,
                  shadows: bool = True, edit: MaterialEdit = MaterialEdit()) -> RelitComparison:
    """Render every GT light of ``scene_dir`` with every renderer; score and build sheet rows."""
    scene = load_scene(scene_dir, load_images=False)
    specs = scene.gt.relit()
    if not specs:
        raise SrvolError(f"{scene.gt.root / 'relit.json'}: no relit ground truth in this scene")
    cams = scene.gt.hr_cameras()
    scores: list[RelitScore] = []
    rows: list[list[Tile]] = []
    for spec in specs:
        gt = scene.gt.image("relit", spec.name)
        if gt is None:
            raise SrvolError(f"{scene.gt.root / 'relit' / (spec.name + '.exr')}: missing relit GT image")
        camera = cams[spec.camera] if spec.camera in cams else scene.hr_camera(spec.camera)
        images: list[tuple[str, RelitImage]] = []
        for r in renderers:
            t0 = time.perf_counter()
            img = render_scene(r.scene, camera, spec.light, edit, shadows=shadows, ss=ss)
            seconds = time.perf_counter() - t0
            images.append((r.name, img))
            scores.append(RelitScore(light=spec.name, renderer=r.name, psnr=psnr(img.rgb, gt),
                                     ssim=ssim(img.rgb, gt), seconds=seconds))
        row: list[Tile] = [(f"GT {spec.name}", gt)]
        row += [(f"{name}", img.rgb) for name, img in images]
        row += [(f"|err| {name}", error_to_rgb(np.abs(img.rgb - gt), ERROR_VMAX)) for name, img in images]
        rows.append(row)
    return RelitComparison(scores=scores, rows=rows)


def write_comparison_sheet(path: str | Path, comparison: RelitComparison, title: str) -> None:
    """The sheet PNG: one row per light; heat maps are already display-encoded."""
    encoded = [label for row in comparison.rows for label, _ in row if label.startswith("|err|")]
    write_sheet(path, comparison.rows, encoded_labels=encoded,
                title=f"{title}   (|err| full scale = {ERROR_VMAX} linear)")
