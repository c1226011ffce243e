"""Built-in ground-truth scenes: analytic shapes and a scanned mesh from an installed wheel.

Every scene lives in the unit sphere and has an exact surface (for the GT
renderer), a material callable (albedo from scikit-image's bundled textures)
and a GT mesh.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from srvol.errors import SrvolError
from srvol.geometry import spherical_uv
from srvol.synth.assets import sample_mesh, sample_texture, texture, triplanar
from srvol.synth.options import SynthOptions
from srvol.synth.surfaces import AnalyticSurface, MeshSurface, Surface
from srvol.types import SurfaceMaterial


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
    tex = texture("astronaut")
    uv = spherical_uv(x)  # the texture's row 0 (grid_sample's -1) at the north pole: v runs down from +z
    alb = 0.05 + 0.8 * sample_texture(tex, 2 * uv[:, 0], 1 - uv[:, 1])
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
    tex = texture("brick")
    base = 0.1 + 0.6 * triplanar(tex, x, 1.2)
    tint = torch.stack([0.9 + 0.1 * torch.sin(3 * x[:, 0]), 0.55 + 0.1 * x[:, 1], 0.35 + 0.1 * x[:, 2]], -1)
    albedo = (base * tint).clamp(0.02, 0.95)
    # roughness in stripes along z (0.15 .. 0.6), specular by azimuth (0.02 .. 0.3)
    rough = 0.375 + 0.225 * torch.sin(9.0 * x[:, 2])
    spec = 0.16 + 0.14 * torch.cos(torch.atan2(x[:, 1], x[:, 0]) * 2)
    return SurfaceMaterial(albedo=albedo, specular=spec[:, None], alpha=(rough ** 2)[:, None])


def bunny_mesh():
    return sample_mesh("bunny.obj", 0.8)


def bunny_material(x: Tensor) -> SurfaceMaterial:
    tex = texture("coffee")
    alb = 0.05 + 0.85 * triplanar(tex, x, 1.5)
    n = x.shape[0]
    return SurfaceMaterial(albedo=alb, specular=torch.full((n, 1), 0.06, dtype=x.dtype),
                           alpha=torch.full((n, 1), 0.35 ** 2, dtype=x.dtype))


@dataclass(frozen=True)
class BuiltinScene:
    """A built-in scene: its GT surface and the capture ``srvol synth NAME`` makes of it by default."""

    name: str
    description: str
    make_surface: Callable[[], Surface]
    synth: SynthOptions = SynthOptions()


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


def _suite(name: str) -> Callable[[], Surface]:
    """The factory of a suite scene's surface (imported when the scene is made)."""
    def make() -> Surface:
        from srvol.synth.suite import SURFACES

        return SURFACES[name]()

    return make


def _scene(name: str, description: str, lr: tuple[int, int], psf_sigma: float, views: int, test_views: int,
           zoom: float, aim: tuple[float, float] = (0.0, 0.0), exposure: float = 1.0) -> BuiltinScene:
    """A suite scene with its capture: LR size, PSF, views and framing (see ``SynthOptions``)."""
    opts = SynthOptions(lr=lr, psf_sigma=psf_sigma, views=views, test_views=test_views, zoom=zoom, aim=aim,
                        exposure=exposure)
    return BuiltinScene(name, description, _suite(name), opts)


SCENES: dict[str, BuiltinScene] = {
    "bumpy": BuiltinScene("bumpy", "analytic bumpy sphere, sub-LR-pixel grooves, astronaut albedo (default)", _bumpy),
    "bunny": BuiltinScene("bunny", "Stanford bunny from the pymeshlab wheel, coffee texture", _bunny),
    "glossy": BuiltinScene("glossy", "bowl-cut sphere + ball, varying roughness/specular, cast shadows", _glossy),
    "dark": BuiltinScene("dark", "the default shape with a very dark albedo (0.005..0.085; stability study)", _dark),
    "shiny": BuiltinScene("shiny", "the default shape under a near-mirror coat, roughness 0.1, F0 0.3 "
                                   "(stability study)", _shiny),
    "torus": _scene("torus", "genus 1: tipped torus, high-frequency gravel albedo, large in the frame",
                    (160, 120), 0.25, 40, 6, zoom=1.12),
    "stool": _scene("stool", "thin legs and crossbars, flat seat with sharp edges, near-uniform pale wood; "
                             "small, off-centre", (160, 120), 0.6, 32, 6, zoom=0.84, aim=(0.2, -0.1)),
    "airplane": _scene("airplane", "pymeshlab's airplane: thin wings and tail, glossy paint over a photo; "
                                   "off-centre", (320, 240), 0.5, 24, 4, zoom=0.96, aim=(-0.05, 0.05)),
    "cup": _scene("cup", "a cup: concavity, thin wall, handle (genus 1), glossy near-uniform glaze; off-centre",
                  (160, 120), 0.45, 40, 6, zoom=1.0, aim=(0.15, 0.1), exposure=0.8),
    "die": _scene("die", "flat faces, sharp edges, 21 carved pips; high-frequency text albedo; small, off-centre",
                  (120, 90), 0.75, 64, 8, zoom=0.8, aim=(-0.25, 0.2)),
    "rings": _scene("rings", "two linked rings (genus 2, thin tubes), dark metal", (240, 180), 0.3, 32, 6,
                    zoom=0.94, exposure=0.7),
    "cow": _scene("cow", "pymeshlab's cow: smooth organic body, thin legs and horns, cat-photo albedo; "
                         "off-centre", (320, 240), 0.7, 24, 4, zoom=0.9, aim=(0.1, -0.05)),
}
DEFAULT_SCENE = "bumpy"

TUNING_SCENES = ("bumpy", "dark", "shiny", "glossy", "torus", "stool", "airplane")
"""Scenes that presets may be tuned on (the default scene and its material variants among them)."""

REPORT_SCENES = ("bunny", "cup", "die", "rings", "cow")
"""Held-out scenes: reported, never tuned on (no shape or material shared with the tuning set)."""


def scene_set(name: str) -> str:
    """'tuning', 'report' or '' for a built-in scene."""
    return "tuning" if name in TUNING_SCENES else "report" if name in REPORT_SCENES else ""


def get_scene(name: str) -> BuiltinScene:
    if name not in SCENES:
        raise SrvolError(f"unknown scene {name!r} (built-in: {', '.join(SCENES)})")
    return SCENES[name]
