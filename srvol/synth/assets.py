"""Ground truth from installed wheels, looked up at run time (DESIGN.md section 8): scikit-image's
bundled textures (linear RGB) and the sample meshes inside the pymeshlab wheel (normalised into
the unit sphere, z up). Nothing is vendored or downloaded.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from srvol.errors import SrvolError
from srvol.images import srgb_to_linear


@lru_cache(maxsize=None)
def texture(name: str) -> Tensor:
    """A scikit-image bundled texture as a linear RGB (1, 3, H, W) float64 tensor."""
    import skimage.data

    img = getattr(skimage.data, name)()
    if img.ndim == 2:
        img = np.stack([img] * 3, axis=-1)
    lin = srgb_to_linear(img[..., :3].astype(np.float32) / 255.0)
    return torch.from_numpy(lin).double().permute(2, 0, 1)[None]


def sample_texture(tex: Tensor, u: Tensor, v: Tensor) -> Tensor:
    """Bilinear, wrapping lookup of (1, 3, H, W) at u, v in [0, 1) -> (N, 3)."""
    u = torch.remainder(u, 1.0) * 2 - 1
    v = torch.remainder(v, 1.0) * 2 - 1
    grid = torch.stack([u, v], -1)[None, None]
    return F.grid_sample(tex, grid.to(tex), mode="bilinear", padding_mode="border",
                         align_corners=False)[0, :, 0].T


def triplanar(tex: Tensor, x: Tensor, scale: float) -> Tensor:
    """Triplanar projection of a texture (weights |n|^4 by the position's direction)."""
    w = (x / x.norm(dim=-1, keepdim=True).clamp_min(1e-9)).abs() ** 4
    w = w / w.sum(-1, keepdim=True)
    cx = sample_texture(tex, x[:, 1] * scale, x[:, 2] * scale)
    cy = sample_texture(tex, x[:, 0] * scale, x[:, 2] * scale)
    cz = sample_texture(tex, x[:, 0] * scale, x[:, 1] * scale)
    return w[:, :1] * cx + w[:, 1:2] * cy + w[:, 2:] * cz


# ----------------------------------------------------------------------------- meshes

def pymeshlab_sample_mesh(name: str) -> Path:
    """Path of a mesh shipped inside the installed pymeshlab wheel (not vendored)."""
    try:
        import pymeshlab
    except ImportError:
        raise SrvolError("the mesh scenes need pymeshlab installed (its wheel ships the meshes)") from None
    path = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / name
    if not path.is_file():
        raise SrvolError(f"{path}: sample mesh not found in the installed pymeshlab")
    return path


def normalized_mesh(vertices: np.ndarray, faces: np.ndarray, radius: float, y_up: bool):
    """A watertight mesh centred on its bounding box, scaled into a sphere of ``radius``, z up."""
    import trimesh

    v = np.asarray(vertices, dtype=np.float64)
    v = v - 0.5 * (v.max(0) + v.min(0))
    v = v / np.linalg.norm(v, axis=1).max() * radius
    if y_up:  # rotate so that +z is up, as in the other scenes
        v = v[:, [0, 2, 1]] * np.array([1, -1, 1])
    m = trimesh.Trimesh(vertices=v, faces=np.asarray(faces), process=True)
    trimesh.repair.fix_normals(m)
    return m


@lru_cache(maxsize=None)
def sample_mesh(name: str, radius: float):
    """A y-up mesh shipped inside the installed pymeshlab wheel, normalised (not vendored)."""
    import trimesh

    mesh = trimesh.load(pymeshlab_sample_mesh(name), force="mesh", process=True)
    mesh.merge_vertices()
    return normalized_mesh(mesh.vertices, mesh.faces, radius, y_up=True)
