"""Built-in ground-truth scenes: analytic shapes and a scanned mesh from an installed wheel.

Every scene lives in the unit sphere and has an exact surface (for the GT
renderer), a material callable (albedo from scikit-image's bundled textures)
and a GT mesh.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from srvol.errors import SrvolError
from srvol.geometry import spherical_uv
from srvol.images import srgb_to_linear
from srvol.synth.surfaces import AnalyticSurface, MeshSurface, Surface
from srvol.types import SurfaceMaterial


@lru_cache(maxsize=None)
def _texture(name: str) -> Tensor:
    """A scikit-image bundled texture as a linear RGB (1, 3, H, W) float64 tensor."""
    import skimage.data

    img = getattr(skimage.data, name)()
    if img.ndim == 2:
        img = np.stack([img] * 3, axis=-1)
    lin = srgb_to_linear(img[..., :3].astype(np.float32) / 255.0)
    return torch.from_numpy(lin).double().permute(2, 0, 1)[None]


def _sample(tex: Tensor, u: Tensor, v: Tensor) -> Tensor:
    """Bilinear, wrapping lookup of (1, 3, H, W) at u, v in [0, 1) -> (N, 3)."""
    u = torch.remainder(u, 1.0) * 2 - 1
    v = torch.remainder(v, 1.0) * 2 - 1
    grid = torch.stack([u, v], -1)[None, None]
    return F.grid_sample(tex, grid.to(tex), mode="bilinear", padding_mode="border",
                         align_corners=False)[0, :, 0].T


def _triplanar(tex: Tensor, x: Tensor, scale: float) -> Tensor:
    """Triplanar projection of a texture (weights |n|^4 by the position's direction)."""
    w = (x / x.norm(dim=-1, keepdim=True).clamp_min(1e-9)).abs() ** 4
    w = w / w.sum(-1, keepdim=True)
    cx = _sample(tex, x[:, 1] * scale, x[:, 2] * scale)
    cy = _sample(tex, x[:, 0] * scale, x[:, 2] * scale)
    cz = _sample(tex, x[:, 0] * scale, x[:, 1] * scale)
    return w[:, :1] * cx + w[:, 1:2] * cy + w[:, 2:] * cz


# ----------------------------------------------------------------------------- shapes

RADIUS = 0.7
GROOVES = 140  # around the equator: wavelength 2*pi*0.7/140 = 0.031
GROOVE_DEPTH = 0.0012  # slope 0.24, normals tilt up to ~13 degrees


def bumpy_sdf(x: Tensor) -> Tensor:
    """A sphere with smooth bumps and, in a band around the equator, grooves
    0.031 apart: about 1.5 LR pixels of the default scene, 6 HR pixels."""
    r = x.norm(dim=-1)
    bumps = 0.045 * torch.sin(5.0 * x[:, 0]) * torch.sin(5.0 * x[:, 1] + 1.0) * torch.sin(5.0 * x[:, 2] + 0.5)
    z = x[:, 2] / r.clamp_min(1e-9)
    band = torch.exp(-(z / 0.35) ** 2)
    phi = torch.atan2(x[:, 1], x[:, 0])
    grooves = GROOVE_DEPTH * band * torch.cos(GROOVES * phi)
    return r - RADIUS - bumps - grooves


def bumpy_material(x: Tensor) -> SurfaceMaterial:
    tex = _texture("astronaut")
    uv = spherical_uv(x)  # the texture's row 0 (grid_sample's -1) at the north pole: v runs down from +z
    alb = 0.05 + 0.8 * _sample(tex, 2 * uv[:, 0], 1 - uv[:, 1])
    n = x.shape[0]
    return SurfaceMaterial(albedo=alb, specular=torch.full((n, 1), 0.04, dtype=x.dtype),
                           alpha=torch.full((n, 1), 0.25, dtype=x.dtype))


def dark_material(x: Tensor) -> SurfaceMaterial:
    """The default scene's texture at a tenth of its albedo (0.005..0.085): coal-like, mostly specular light."""
    m = bumpy_material(x)
    return SurfaceMaterial(albedo=0.1 * m.albedo, specular=m.specular, alpha=m.alpha)


def shiny_material(x: Tensor) -> SurfaceMaterial:
    """The default scene's texture under a near-mirror coat: roughness 0.1 (alpha 0.01), F0 0.3."""
    m = bumpy_material(x)
    n = x.shape[0]
    return SurfaceMaterial(albedo=0.5 * m.albedo, specular=torch.full((n, 1), 0.3, dtype=x.dtype),
                           alpha=torch.full((n, 1), 0.01, dtype=x.dtype))


def glossy_sdf(x: Tensor) -> Tensor:
    """A sphere with a spherical bowl cut into its top (a concavity that casts shadows)
    and a small sphere resting in the bowl."""
    body = x.norm(dim=-1) - 0.65
    bowl = (x - x.new_tensor([0.0, 0.0, 0.72])).norm(dim=-1) - 0.42
    carved = torch.maximum(body, -bowl)
    ball = (x - x.new_tensor([0.12, 0.0, 0.38])).norm(dim=-1) - 0.12
    return torch.minimum(carved, ball)


def glossy_material(x: Tensor) -> SurfaceMaterial:
    tex = _texture("brick")
    base = 0.1 + 0.6 * _triplanar(tex, x, 1.2)
    tint = torch.stack([0.9 + 0.1 * torch.sin(3 * x[:, 0]), 0.55 + 0.1 * x[:, 1], 0.35 + 0.1 * x[:, 2]], -1)
    albedo = (base * tint).clamp(0.02, 0.95)
    # roughness in stripes along z (0.15 .. 0.6), specular by azimuth (0.02 .. 0.3)
    rough = 0.375 + 0.225 * torch.sin(9.0 * x[:, 2])
    spec = 0.16 + 0.14 * torch.cos(torch.atan2(x[:, 1], x[:, 0]) * 2)
    return SurfaceMaterial(albedo=albedo, specular=spec[:, None], alpha=(rough ** 2)[:, None])


def pymeshlab_sample_mesh(name: str) -> Path:
    """Path of a mesh shipped inside the installed pymeshlab wheel (not vendored)."""
    try:
        import pymeshlab
    except ImportError:
        raise SrvolError("the 'bunny' scene needs pymeshlab installed (its wheel ships the mesh)") from None
    path = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / name
    if not path.is_file():
        raise SrvolError(f"{path}: sample mesh not found in the installed pymeshlab")
    return path


@lru_cache(maxsize=None)
def bunny_mesh():
    import trimesh

    mesh = trimesh.load(pymeshlab_sample_mesh("bunny.obj"), force="mesh", process=True)
    mesh.merge_vertices()
    v = np.asarray(mesh.vertices, dtype=np.float64)
    center = 0.5 * (v.max(0) + v.min(0))
    v = v - center
    v = v / np.linalg.norm(v, axis=1).max() * 0.8
    # Stanford bunny is y-up: rotate so that +z is up, as in the other scenes.
    v = v[:, [0, 2, 1]] * np.array([1, -1, 1])
    m = trimesh.Trimesh(vertices=v, faces=np.asarray(mesh.faces), process=True)
    trimesh.repair.fix_normals(m)
    return m


def bunny_material(x: Tensor) -> SurfaceMaterial:
    tex = _texture("coffee")
    alb = 0.05 + 0.85 * _triplanar(tex, x, 1.5)
    n = x.shape[0]
    return SurfaceMaterial(albedo=alb, specular=torch.full((n, 1), 0.06, dtype=x.dtype),
                           alpha=torch.full((n, 1), 0.35 ** 2, dtype=x.dtype))


@dataclass(frozen=True)
class BuiltinScene:
    name: str
    description: str
    make_surface: Callable[[], Surface]


def _bumpy() -> Surface:
    return AnalyticSurface(sdf=bumpy_sdf, material=bumpy_material, lipschitz=1.6, bound=0.76)


def _dark() -> Surface:
    return AnalyticSurface(sdf=bumpy_sdf, material=dark_material, lipschitz=1.6, bound=0.76)


def _shiny() -> Surface:
    return AnalyticSurface(sdf=bumpy_sdf, material=shiny_material, lipschitz=1.6, bound=0.76)


def _glossy() -> Surface:
    return AnalyticSurface(sdf=glossy_sdf, material=glossy_material, lipschitz=1.0, bound=0.7)


def _bunny() -> Surface:
    return MeshSurface(mesh=bunny_mesh(), material=bunny_material)


SCENES: dict[str, BuiltinScene] = {
    "bumpy": BuiltinScene("bumpy", "analytic bumpy sphere, sub-LR-pixel grooves, astronaut albedo (default)", _bumpy),
    "bunny": BuiltinScene("bunny", "Stanford bunny from the pymeshlab wheel, coffee texture", _bunny),
    "glossy": BuiltinScene("glossy", "bowl-cut sphere + ball, varying roughness/specular, cast shadows", _glossy),
    "dark": BuiltinScene("dark", "the default shape with a very dark albedo (0.005..0.085; stability study)", _dark),
    "shiny": BuiltinScene("shiny", "the default shape under a near-mirror coat, roughness 0.1, F0 0.3 "
                                   "(stability study)", _shiny),
}
DEFAULT_SCENE = "bumpy"


def get_scene(name: str) -> BuiltinScene:
    if name not in SCENES:
        raise SrvolError(f"unknown scene {name!r} (built-in: {', '.join(SCENES)})")
    return SCENES[name]
