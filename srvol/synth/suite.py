"""Shapes and materials of the scene suite: what users bring, beyond the default sphere.

Thin parts (a stool's legs and crossbars, a cup's wall, an airplane's wings), concavities (a
cup, a die's pips), genus > 0 (a torus, a cup's handle, two linked rings), flat faces with
sharp edges (a die, a stool's seat) and smooth organic surfaces (a cow); glossy, dark,
high-frequency and near-uniform materials. Analytic SDFs (exact normals) and meshes from the
installed pymeshlab and trimesh wheels; albedo from scikit-image's bundled textures. The
scenes, their framing and their synthesis defaults are registered in ``srvol.synth.scenes``.
"""
from __future__ import annotations

from functools import lru_cache, partial
from typing import Callable

import numpy as np
import torch
from torch import Tensor

from srvol.synth.assets import normalized_mesh, sample_mesh, texture, triplanar
from srvol.synth.surfaces import AnalyticSurface, MeshSurface, Surface
from srvol.types import SurfaceMaterial

# ----------------------------------------------------------------------------- SDF primitives


def torus_sdf_z(x: Tensor, major: float, minor: float) -> Tensor:
    """A torus around the z axis through the origin."""
    q = x[:, :2].norm(dim=-1) - major
    return torch.sqrt(q * q + x[:, 2] ** 2) - minor


def round_box_sdf(x: Tensor, half: tuple[float, float, float], radius: float) -> Tensor:
    """A box of half-sizes ``half`` centred at the origin, edges rounded by ``radius``."""
    q = x.abs() - x.new_tensor(half) + radius
    return q.clamp_min(0).norm(dim=-1) + q.max(dim=-1).values.clamp_max(0) - radius


def capsule_sdf(x: Tensor, a: tuple[float, float, float], b: tuple[float, float, float], radius: float) -> Tensor:
    """A segment from ``a`` to ``b`` thickened by ``radius``."""
    a_t, b_t = x.new_tensor(a), x.new_tensor(b)
    ab = b_t - a_t
    h = (((x - a_t) @ ab) / (ab @ ab)).clamp(0, 1)
    return (x - a_t - h[:, None] * ab).norm(dim=-1) - radius


def cylinder_sdf_z(x: Tensor, radius: float, z0: float, z1: float) -> Tensor:
    """A capped cylinder around the z axis from height z0 to z1."""
    dr = x[:, :2].norm(dim=-1) - radius
    dz = (x[:, 2] - 0.5 * (z0 + z1)).abs() - 0.5 * (z1 - z0)
    d = torch.stack([dr, dz], -1)
    return d.clamp_min(0).norm(dim=-1) + d.max(dim=-1).values.clamp_max(0)


def _constant(x: Tensor, albedo: Tensor, specular: float, roughness: float) -> SurfaceMaterial:
    """A material with per-point albedo (N, 3) and constant F0 and perceptual roughness."""
    n = x.shape[0]
    return SurfaceMaterial(albedo=albedo.to(x.dtype), specular=torch.full((n, 1), specular, dtype=x.dtype),
                           alpha=torch.full((n, 1), roughness ** 2, dtype=x.dtype))


# ----------------------------------------------------------------------------- torus (tuning)

def torus_sdf(x: Tensor) -> Tensor:
    """Genus 1: a torus (radii 0.52 and 0.2) tipped 30 degrees about x."""
    c, s = 0.8660254037844387, 0.5
    y = torch.stack([x[:, 0], c * x[:, 1] + s * x[:, 2], -s * x[:, 1] + c * x[:, 2]], -1)
    return torus_sdf_z(y, 0.52, 0.2)


def gravel_material(x: Tensor) -> SurfaceMaterial:
    """High-frequency albedo: scikit-image's gravel, small grains (triplanar, 3 tiles per unit)."""
    return _constant(x, 0.04 + 0.85 * triplanar(texture("gravel"), x, 3.0), 0.04, 0.55)


# ----------------------------------------------------------------------------- stool (tuning)

LEGS = ((0.36, 0.36), (-0.36, 0.36), (-0.36, -0.36), (0.36, -0.36))


def stool_sdf(x: Tensor) -> Tensor:
    """Flat faces with sharp edges and thin parts: a square seat (edges rounded by 0.015) on four
    legs 0.08 thick, joined by two crossbars 0.045 thick."""
    seat = round_box_sdf(x - x.new_tensor([0.0, 0.0, 0.42]), (0.5, 0.5, 0.06), 0.015)
    parts = [seat]
    for lx, ly in LEGS:
        parts.append(capsule_sdf(x, (lx, ly, 0.38), (1.2 * lx, 1.2 * ly, -0.5), 0.04))
    parts.append(capsule_sdf(x, (0.396, 0.396, -0.1), (-0.396, -0.396, -0.1), 0.0225))
    parts.append(capsule_sdf(x, (-0.396, 0.396, -0.1), (0.396, -0.396, -0.1), 0.0225))
    return torch.stack(parts, -1).min(dim=-1).values


def pale_wood_material(x: Tensor) -> SurfaceMaterial:
    """Near-uniform: a pale wood colour with +-4% low-frequency variation, matte."""
    base = x.new_tensor([0.55, 0.42, 0.28])
    vary = 1 + 0.04 * torch.sin(2.0 * x[:, 0] + 1.3 * x[:, 2])[:, None]
    return _constant(x, base * vary, 0.04, 0.6)


# ----------------------------------------------------------------------------- cup (report)

def cup_sdf(x: Tensor) -> Tensor:
    """A concavity with thin walls and genus 1: a cup (wall 0.04, bottom 0.06) with a ring handle."""
    outer = cylinder_sdf_z(x, 0.42, -0.42, 0.38)
    inner = cylinder_sdf_z(x, 0.38, -0.36, 0.6)
    body = torch.maximum(outer, -inner)
    xz = torch.stack([x[:, 0] - 0.42, x[:, 2], x[:, 1]], -1)  # the handle's ring lies in the xz plane
    handle = torch.maximum(torus_sdf_z(xz, 0.2, 0.045), 0.4 - x[:, 0])
    return torch.minimum(body, handle)


def glazed_material(x: Tensor) -> SurfaceMaterial:
    """Glossy and near-uniform: an off-white glaze (F0 0.06, roughness 0.15) with a faint blue band."""
    band = torch.exp(-((x[:, 2] - 0.2) / 0.05) ** 2)[:, None]
    albedo = x.new_tensor([0.72, 0.70, 0.64]) * (1 - band) + x.new_tensor([0.15, 0.25, 0.55]) * band
    return _constant(x, albedo, 0.06, 0.15)


# ----------------------------------------------------------------------------- die (report)

PIP_SPOTS = {1: ((0, 0),), 2: ((-1, -1), (1, 1)), 3: ((-1, -1), (0, 0), (1, 1)),
             4: ((-1, -1), (-1, 1), (1, -1), (1, 1)), 5: ((-1, -1), (-1, 1), (0, 0), (1, -1), (1, 1)),
             6: ((-1, -1), (-1, 0), (-1, 1), (1, -1), (1, 0), (1, 1))}
"""Pips of each face in the face's 3 x 3 grid (-1, 0, 1 along its two in-plane axes)."""

DIE_FACES = ((2, 1.0, 1), (2, -1.0, 6), (0, 1.0, 2), (0, -1.0, 5), (1, 1.0, 3), (1, -1.0, 4))
"""(normal axis, side, pips): opposite faces add up to seven."""

DIE_HALF = 0.45


@lru_cache(maxsize=None)
def pip_centres() -> np.ndarray:
    """(21, 3) centres of the spheres carving the pips, just outside the faces."""
    out = []
    for axis, side, pips in DIE_FACES:
        u, v = [a for a in range(3) if a != axis]
        for i, j in PIP_SPOTS[pips]:
            c = np.zeros(3)
            c[axis] = side * (DIE_HALF + 0.035)
            c[u], c[v] = 0.22 * i, 0.22 * j
            out.append(c)
    return np.array(out)


def pips_sdf(x: Tensor) -> Tensor:
    centres = torch.from_numpy(pip_centres()).to(x)
    return (torch.cdist(x, centres).min(dim=-1).values - 0.08)


def die_sdf(x: Tensor) -> Tensor:
    """Flat faces, sharp edges (rounded by 0.04) and 21 small concavities: a die."""
    return torch.maximum(round_box_sdf(x, (DIE_HALF,) * 3, 0.04), -pips_sdf(x))


def die_material(x: Tensor) -> SurfaceMaterial:
    """High-frequency albedo: scikit-image's page of text on ivory; dark red pips; satin plastic."""
    text = triplanar(texture("page"), x, 1.6)
    albedo = x.new_tensor([0.85, 0.8, 0.68]) * (0.15 + 0.85 * text)
    in_pip = (pips_sdf(x) < 0.004)[:, None]
    albedo = torch.where(in_pip, x.new_tensor([0.25, 0.02, 0.02]).expand_as(albedo), albedo)
    return _constant(x, albedo, 0.05, 0.3)


# ----------------------------------------------------------------------------- meshes

@lru_cache(maxsize=None)
def rings_mesh():
    """Genus 2 and thin: two linked rings (tube radius 0.07 before scaling), trimesh's torus."""
    import trimesh

    a = trimesh.creation.torus(major_radius=0.5, minor_radius=0.07, major_sections=96, minor_sections=24)
    b = a.copy()
    b.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    b.apply_translation([0.5, 0.0, 0.0])
    both = trimesh.util.concatenate([a, b])
    return normalized_mesh(both.vertices, both.faces, 0.85, y_up=False)


def dark_metal_material(x: Tensor) -> SurfaceMaterial:
    """Dark: near-black albedo (0.02..0.06, coffee texture) under a strong, rough metallic specular."""
    return _constant(x, 0.02 + 0.04 * triplanar(texture("coffee"), x, 2.0), 0.5, 0.35)


def painted_material(x: Tensor) -> SurfaceMaterial:
    """Glossy paint over scikit-image's rocket photo (F0 0.08, roughness 0.25)."""
    return _constant(x, 0.05 + 0.75 * triplanar(texture("rocket"), x, 1.0), 0.08, 0.25)


def fur_material(x: Tensor) -> SurfaceMaterial:
    """Organic, mid-frequency albedo: scikit-image's cat photo (chelsea), matte."""
    return _constant(x, 0.05 + 0.8 * triplanar(texture("chelsea"), x, 1.2), 0.04, 0.5)


# ----------------------------------------------------------------------------- surfaces

SURFACES: dict[str, Callable[[], Surface]] = {
    "torus": partial(AnalyticSurface, sdf=torus_sdf, material=gravel_material, bound=0.75),
    "stool": partial(AnalyticSurface, sdf=stool_sdf, material=pale_wood_material, bound=0.9),
    "airplane": lambda: MeshSurface(mesh=sample_mesh("airplane.obj", 0.85), material=painted_material),
    "cup": partial(AnalyticSurface, sdf=cup_sdf, material=glazed_material, bound=0.72),
    "die": partial(AnalyticSurface, sdf=die_sdf, material=die_material, bound=0.8),
    "rings": lambda: MeshSurface(mesh=rings_mesh(), material=dark_metal_material),
    "cow": lambda: MeshSurface(mesh=sample_mesh("cow.obj", 0.85), material=fur_material),
}
"""The suite's GT surfaces by scene name (exact SDFs: Lipschitz 1; registered with their framing in
``scenes.SCENES``)."""
