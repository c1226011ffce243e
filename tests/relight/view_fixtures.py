"""A small exported asset and a free port for the ``srvol view`` tests (shared by import)."""
from __future__ import annotations

import socket
from pathlib import Path

import torch

from srvol.types import SurfaceMaterial

RADIUS = 0.5


def sphere_sdf(x: torch.Tensor) -> torch.Tensor:
    return x.norm(dim=-1) - RADIUS


def ramp_material(x: torch.Tensor) -> SurfaceMaterial:
    """A colour ramp along each axis (the mesh is recognisable by colour), F0 rising with z,
    GGX alpha 0.09 .. 0.39 along x (so that an edit of alpha shows texel by texel)."""
    u = x / RADIUS
    return SurfaceMaterial(albedo=(0.5 + 0.4 * u).clamp(0.0, 1.0), specular=0.04 + 0.05 * (u[:, 2:3] + 1.0),
                           alpha=0.09 + 0.15 * (u[:, 0:1] + 1.0))


def export_sphere(out: Path) -> Path:
    """The sphere as `srvol export` writes it (USD + GLB; 64^3, 1500 faces, 128^2 maps): ~1 s."""
    from srvol.export.pipeline import ExportOptions, export_fields

    export_fields(sphere_sdf, ramp_material, out, ExportOptions(formats=("usd", "glb"), resolution=64, faces=1500,
                                                                texture_size=128))
    return out


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
