"""Blender side of the export, driven from the main process through a subprocess.

``import bpy`` crashes a process that has loaded embree (trimesh's ray module),
so everything touching bpy runs in ``python -m srvol.export.blender_check``;
this module only builds its command lines and reads its JSON reports.

Light units: a Blender point light of power P (W) with radius 0 and no soft
falloff has radiant intensity I = P / (4 pi) W/sr in Cycles, so srvol's
``PointLight(intensity=I)`` becomes ``energy = 4 pi I``; the film uses the
Standard view transform with exposure 0 and the render is saved as linear EXR.

Specular fix: Blender's USD importer maps ``specularColor`` to Specular Tint
with Specular IOR Level 0.5 and IOR 1.5 (effective F0 = 0.04 * F0). After
import the tint texture is scaled by 1 / f0_ref and the IOR set to the one
whose F0 is f0_ref, so that F0_blender = f0_ref * F0 / f0_ref = F0; the GGX
distribution is set to single-scatter GGX, as in srvol's BRDF.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from srvol.errors import SrvolError


@dataclass(frozen=True)
class BlenderView:
    """A pinhole view and a point light for the check render (scene frame, +z up).

    fov_deg: horizontal field of view; intensity: radiant intensity I (W/sr), grey; filter_width:
    Cycles pixel filter in pixels (0.01 ~ one ray through each pixel centre, for comparisons)."""

    eye: tuple[float, float, float] = (0.0, -3.0, 1.0)
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fov_deg: float = 35.0
    width: int = 128
    height: int = 96
    light: tuple[float, float, float] = (1.5, -2.5, 2.0)
    intensity: float = 10.0
    samples: int = 32
    filter_width: float = 1.5


def light_power_watts(intensity: float) -> float:
    """Blender point-light power P for radiant intensity I: P = 4 pi I."""
    return 4.0 * math.pi * intensity


def run_blender_check(asset_dir: Path, out_png: Path, view: BlenderView = BlenderView(),
                      blend: Path | None = None, exr: Path | None = None, report: Path | None = None,
                      source: str = "usd", render: bool = True, timeout: float = 600) -> dict:
    """Run the bpy check in a subprocess; returns its JSON report (wiring values)."""
    report = report or out_png.with_suffix(".json")
    cmd = [sys.executable, "-m", "srvol.export.blender_check", str(asset_dir), "--out", str(out_png),
           "--report", str(report), "--source", source, "--view", json.dumps(view.__dict__)]
    if blend is not None:
        cmd += ["--blend", str(blend)]
    if exr is not None:
        cmd += ["--exr", str(exr)]
    if not render:
        cmd.append("--no-render")
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "2"))
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise SrvolError(f"Blender check of {asset_dir} failed: {tail[0]}")
    return json.loads(Path(report).read_text())


def write_blend(asset_dir: Path, blend: Path, f0_ref: float) -> None:
    """A ready .blend (the asset from its USD, fixed materials, a point light and a camera); its
    textures are referenced relative to the .blend, i.e. the asset folder's raw/ and textures/."""
    usd = next((asset_dir / n for n in ("model.usda", "model.usdc") if (asset_dir / n).is_file()), None)
    if usd is None:
        from srvol.export.textures import TextureFiles
        from srvol.export.usd import write_usd
        import numpy as np
        from srvol.export.types import Mesh

        with np.load(asset_dir / "raw" / "mesh.npz") as z:
            mesh = Mesh(z["vertices"], z["faces"], z["uv"], z["normals"])
        has_normal = (asset_dir / "textures" / "normal.png").is_file()
        write_usd(asset_dir / ".blend_source.usda", mesh,
                  TextureFiles(normal_png="textures/normal.png" if has_normal else None))
    tmp_png = asset_dir / ".blend_preview.png"
    try:
        run_blender_check(asset_dir, tmp_png, BlenderView(), blend=blend, render=False,
                          report=asset_dir / ".blend_report.json")
    finally:
        for p in (tmp_png, asset_dir / ".blend_report.json", asset_dir / ".blend_source.usda"):
            p.unlink(missing_ok=True)
