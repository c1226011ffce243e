"""Geometry shared by every renderer: rays against the bounding sphere, SDF normals, rays against a
triangle mesh, and the spherical UV projection.

Users: the volume renderer (:mod:`srvol.render`), the ground-truth ray caster
(:mod:`srvol.synth.surfaces`), the relighting renderer (``srvol.relight.render``) and the exporter
(``srvol.export``). Positions are in the scene frame of :mod:`srvol.types` (object in the unit
sphere, +z up); ray directions are unit length.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from srvol.types import Rays, SdfFn


def ray_sphere(rays: Rays, radius: float) -> tuple[Tensor, Tensor]:
    """Entry and exit distances (N,) of ``rays`` through the origin-centred sphere of ``radius``.

    The entry is clamped at 0 (a ray starting inside enters at its origin). On a miss (or a tangent
    ray) entry = 1 > exit = 0, so ``near < far`` tells the rays that cross the sphere.
    """
    b = (rays.origins * rays.directions).sum(-1)
    c = (rays.origins * rays.origins).sum(-1) - radius * radius
    disc = b * b - c
    s = disc.clamp_min(0).sqrt()
    near = torch.where(disc > 0, (-b - s).clamp_min(0.0), torch.ones_like(b))
    far = torch.where(disc > 0, -b + s, torch.zeros_like(b))
    return near, far


def sdf_normals(sdf_fn: SdfFn, points: Tensor, chunk: int = 1 << 16) -> Tensor:
    """(N, 3) unit outward normals grad d / |grad d| at ``points`` (N, 3), by autograd.

    Evaluated in the points' dtype, ``chunk`` points per SDF call; the result carries no graph.
    """
    out = []
    for s in range(0, points.shape[0], chunk):
        with torch.enable_grad():
            x = points[s:s + chunk].detach().requires_grad_(True)
            (g,) = torch.autograd.grad(sdf_fn(x).sum(), x)
        out.append(g / g.norm(dim=-1, keepdim=True).clamp_min(1e-12))
    return torch.cat(out) if out else points.new_zeros(0, 3)


def spherical_uv(points: Tensor) -> Tensor:
    """(N, 3) points -> (N, 2) UVs of the spherical projection about the origin.

    ``u = atan2(y, x) / 2pi + 0.5`` (0 and 1 on the -x half-plane, 0.5 towards +x) and
    ``v = 1 - theta / pi`` with theta the angle from +z: **v = 1 at the north pole (+z), 0 at the
    south pole**. This is srvol's UV convention (origin bottom-left, v up, as in
    ``srvol.export.types``): an image laid on these UVs stands upright, its top row at +z.
    """
    r = points.norm(dim=-1).clamp_min(1e-9)
    u = torch.atan2(points[:, 1], points[:, 0]) / (2 * math.pi) + 0.5
    v = 1.0 - torch.acos((points[:, 2] / r).clamp(-1, 1)) / math.pi
    return torch.stack([u, v], dim=-1)


# ----------------------------------------------------------------------------- triangle meshes

def barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(M, 3) barycentric weights of points p (M, 3) in triangles (a, b, c), each (M, 3)."""
    v0, v1, v2 = b - a, c - a, p - a
    d00 = (v0 * v0).sum(-1)
    d01 = (v0 * v1).sum(-1)
    d11 = (v1 * v1).sum(-1)
    d20 = (v2 * v0).sum(-1)
    d21 = (v2 * v1).sum(-1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) < 1e-30, 1e-30, den)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.stack([1 - v - w, v, w], axis=-1)


@dataclass(frozen=True)
class MeshHits:
    """First hits of a batch of N rays on a triangle mesh (M of them hit), float64 numpy.

    ray (M,) which rays of the batch; face (M,) the triangle hit; t (M,) distance along the ray;
    points (M, 3) = origin + t direction; bary (M, 3) barycentric weights of the points in their
    triangle (vertex order of ``faces``).
    """

    ray: np.ndarray
    face: np.ndarray
    t: np.ndarray
    points: np.ndarray
    bary: np.ndarray


@dataclass(frozen=True)
class MeshRayCaster:
    """Embree ray casting of a triangle mesh (trimesh's ``RayMeshIntersector``), its BVH built once.

    mesh: the ``trimesh.Trimesh``; vertices (V, 3) float64, faces (F, 3), face_normals (F, 3) its
    unit geometric normals (counter-clockwise winding, right-hand rule).
    """

    mesh: object
    vertices: np.ndarray
    faces: np.ndarray
    face_normals: np.ndarray
    intersector: object

    @staticmethod
    def build(mesh) -> "MeshRayCaster":
        """A caster of ``mesh`` (a ``trimesh.Trimesh``)."""
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        intersector = RayMeshIntersector(mesh)
        intersector.intersects_first(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))  # build the BVH now
        return MeshRayCaster(mesh=mesh, vertices=np.asarray(mesh.vertices, np.float64), faces=np.asarray(mesh.faces),
                             face_normals=np.asarray(mesh.face_normals, np.float64), intersector=intersector)

    def first_faces(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Indices of the rays that hit, their triangles and distances: embree's first hit, the
        distance computed exactly against the triangle's plane. origins, directions (N, 3) float64."""
        tri = np.asarray(self.intersector.intersects_first(origins, directions))
        idx = np.nonzero(tri >= 0)[0]
        tri = tri[idx]
        fn = self.face_normals[tri]
        p0 = self.vertices[self.faces[tri, 0]]
        denom = (directions[idx] * fn).sum(-1)
        t = ((p0 - origins[idx]) * fn).sum(-1) / np.where(np.abs(denom) < 1e-12, 1e-12, denom)
        return idx, tri, t

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> MeshHits:
        """:meth:`first_faces` with the hit points and their barycentric weights."""
        idx, tri, t = self.first_faces(origins, directions)
        pts = origins[idx] + t[:, None] * directions[idx]
        f = self.faces[tri]
        bary = barycentric(pts, self.vertices[f[:, 0]], self.vertices[f[:, 1]], self.vertices[f[:, 2]])
        return MeshHits(ray=idx, face=tri, t=t, points=pts, bary=bary)

    def interpolate(self, hits: MeshHits, values: np.ndarray) -> np.ndarray:
        """(M, C) per-vertex ``values`` (V, C) (normals, UVs) interpolated at the hits, barycentrically."""
        return np.einsum("mk,mkc->mc", hits.bary, values[self.faces[hits.face]])
