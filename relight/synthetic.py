"""Assets built straight from exact fields, for checking the asset path without the exporter.

:func:`latlong_asset` meshes a *star-shaped* surface (every ray from the origin crosses it
once, as the built-in "bumpy" sphere and the test spheres) on a latitude-longitude grid and
bakes its material into equirectangular textures. UVs are the grid's own parametrisation,
``u = phi / 2pi`` and ``v = 1 - theta / pi`` (theta from +z), with the seam column duplicated, so
a texel and the surface point it was baked from share the same UV. Normals are the SDF's
analytic normals at the vertices.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from srvol.export.types import Asset, Mesh, TextureSet
from srvol.relight.render import FieldScene, TraceOptions
from srvol.types import MaterialFn, Rays, SdfFn


def _surface_along(scene: FieldScene, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Surface points and normals met by rays from outside (radius = bound) towards the origin."""
    origins = dirs * scene.options.bound
    hits = scene.intersect(Rays(origins, -dirs))
    if hits.index.numel() != dirs.shape[0]:
        raise ValueError("latlong_asset: the surface is not star-shaped about the origin")
    return hits.points, hits.normals


def _directions(theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    st = torch.sin(theta)
    return torch.stack([st * torch.cos(phi), st * torch.sin(phi), torch.cos(theta)], dim=-1)


def latlong_asset(sdf_fn: SdfFn, material_fn: MaterialFn, n_theta: int = 128, n_phi: int = 256,
                  texture_size: tuple[int, int] = (512, 256), options: TraceOptions = TraceOptions()) -> Asset:
    """Mesh (n_theta + 1) x (n_phi + 1) vertices; bake (W, H) = ``texture_size`` textures at texel centres."""
    scene = FieldScene(sdf_fn, material_fn, options)
    th = torch.linspace(0, math.pi, n_theta + 1)
    ph = torch.linspace(0, 2 * math.pi, n_phi + 1)
    T, P = torch.meshgrid(th, ph, indexing="ij")
    pts, nrm = _surface_along(scene, _directions(T.reshape(-1), P.reshape(-1)))
    uv = torch.stack([P.reshape(-1) / (2 * math.pi), 1 - T.reshape(-1) / math.pi], -1)
    i, j = np.meshgrid(np.arange(n_theta), np.arange(n_phi), indexing="ij")
    a = (i * (n_phi + 1) + j).reshape(-1)
    b, c, d = a + n_phi + 1, a + n_phi + 2, a + 1  # (i+1, j), (i+1, j+1), (i, j+1)
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    V = pts.double().numpy()
    fn = np.cross(V[faces[:, 1]] - V[faces[:, 0]], V[faces[:, 2]] - V[faces[:, 0]])
    if (fn * V[faces].mean(1)).sum() < 0:  # wind counter-clockwise seen from outside
        faces = faces[:, ::-1]
    W, H = texture_size
    tu = (torch.arange(W, dtype=torch.float32) + 0.5) / W
    tv = 1 - (torch.arange(H, dtype=torch.float32) + 0.5) / H
    TV, TU = torch.meshgrid(tv, tu, indexing="ij")  # row-major: row 0 = top = v near 1
    tex_pts, _ = _surface_along(scene, _directions((1 - TV.reshape(-1)) * math.pi, TU.reshape(-1) * 2 * math.pi))
    with torch.no_grad():
        m = scene.material_at_points(tex_pts)
    textures = TextureSet(albedo=m.albedo.reshape(H, W, 3).numpy(), specular=m.specular.reshape(H, W, 1).numpy(),
                          alpha=m.alpha.reshape(H, W, 1).numpy())
    mesh = Mesh(vertices=V.astype(np.float32), faces=np.ascontiguousarray(faces, dtype=np.int32),
                uv=uv.numpy().astype(np.float32), normals=nrm.numpy().astype(np.float32))
    return Asset(mesh=mesh, textures=textures)


def constant_textures(albedo=(0.5, 0.5, 0.5), specular: float = 0.04, alpha: float = 0.25,
                      size: int = 4) -> TextureSet:
    """Uniform textures (size x size texels): an asset whose material is the same everywhere."""
    return TextureSet(albedo=np.broadcast_to(np.asarray(albedo, np.float32), (size, size, 3)).copy(),
                      specular=np.full((size, size, 1), specular, np.float32),
                      alpha=np.full((size, size, 1), alpha, np.float32))
