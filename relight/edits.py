"""Material edits for relighting: ``--material SPEC`` -> :class:`MaterialEdit` -> a new SurfaceMaterial.

Specs (combinable with commas, or by repeating ``--material``; applied in this order:
preset, then albedo / albedo-texture, then roughness, then specular / no-specular):

* ``gold``             a metal-like gold within srvol's BRDF (see :data:`GOLD`).
* ``no-specular``      F0 = 0: highlights vanish, the diffuse lobe is untouched. What is left of the
  microfacet lobe is Schlick's grazing rise, F = (1 - v.h)^5 at F0 = 0 (srvol.brdf has no F90
  term to switch it off); measured below 1 % of the original specular energy.
* ``albedo=r,g,b``     constant linear diffuse albedo, each in [0, 1].
* ``albedo-texture=PNG``  an sRGB PNG (decoded to linear) as diffuse albedo. Mapping: with
  surface UVs (an exported asset) the texture is laid in the asset's UVs (origin bottom-left,
  texel row = (1 - v) * H, as :mod:`srvol.export.types`); without UVs (the neural model) it is
  projected spherically about the scene origin by :func:`srvol.geometry.spherical_uv`
  (``u = atan2(y, x) / 2pi + 0.5``, ``v = 1 - acos(z / |x|) / pi``), so that the image's top row
  lands on the north pole (+z).
* ``roughness=x``      perceptual roughness r in [0, 1]; writes GGX alpha = r^2 (floored at ALPHA_MIN).
* ``specular=x``       F0 (grey specular reflectance at normal incidence) in [0, 1].
* ``roughness-scale=k`` multiplies the *perceptual* roughness r = sqrt(alpha) by k in [0, 4]
  (r' = min(k r, 1), so alpha' = k^2 alpha, floored at ALPHA_MIN): what a roughness slider in Blender,
  glTF or ``srvol view`` means. Applied after the specs above, to what they left.
* ``specular-scale=k`` multiplies F0 by k in [0, 4] (clamped to [0, 1]).
* ``albedo-tint=r,g,b`` multiplies the diffuse albedo per channel, each in [0, 4] (clamped to [0, 1]).

**Gold, honestly.** Real gold's F0 is coloured, about (1.00, 0.71, 0.29) linear, and it has no
diffuse lobe. srvol's BRDF has one grey F0 per point (``specular`` is (N, 1)), so a coloured
mirror is not expressible. The preset keeps the two facts the BRDF can hold: the *magnitude* of
gold's reflectance goes to a strong grey F0 (0.75, the mean of gold's F0), and its *hue* goes to
a diffuse albedo of gold's F0 colour scaled to 0.25 (so albedo + F0 stays below 1 in every
channel). Roughness r = 0.3. Highlights are therefore white-ish rather than gold, and
the body colour is carried by the diffuse lobe; a faithful metal needs an (N, 3) F0 in the BRDF.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
import torch
from torch import Tensor

from srvol.errors import SrvolError
from srvol.geometry import spherical_uv
from srvol.types import ALPHA_MIN, SurfaceMaterial

if TYPE_CHECKING:
    from srvol.export.types import TextureSet

GOLD_F0_RGB = (1.00, 0.71, 0.29)
"""Gold's specular reflectance at normal incidence, linear RGB (what a coloured-F0 BRDF would use)."""


@dataclass(frozen=True)
class Preset:
    """A named material: constant albedo (linear RGB), F0 and perceptual roughness."""

    name: str
    albedo: tuple[float, float, float]
    specular: float
    roughness: float


GOLD = Preset(name="gold", albedo=tuple(0.25 * c for c in GOLD_F0_RGB), specular=0.75, roughness=0.3)
PRESETS = {"gold": GOLD}
SPEC_HELP = ("gold | no-specular | albedo=r,g,b | albedo-texture=PNG | roughness=x (perceptual) | "
             "specular=x (F0) | roughness-scale=k (scales perceptual r) | specular-scale=k | albedo-tint=r,g,b; "
             "combine with commas or repeat --material")


@dataclass(frozen=True, eq=False)
class AlbedoTexture:
    """A linear RGB texture (H, W, 3) float32 read from an sRGB PNG."""

    path: Path
    pixels: np.ndarray

    @staticmethod
    def read(path: str | Path) -> "AlbedoTexture":
        from srvol.images import read_png

        p = Path(path)
        if p.suffix.lower() != ".png" or not p.is_file():
            raise SrvolError(f"albedo-texture={path}: not an existing .png file")
        img = read_png(p, srgb=True)
        if img.shape[2] == 1:
            img = np.repeat(img, 3, axis=2)
        return AlbedoTexture(path=p, pixels=np.ascontiguousarray(img[..., :3], dtype=np.float32))


@dataclass(frozen=True)
class MaterialEdit:
    """What to change in a SurfaceMaterial; ``None`` / False leaves a parameter as it is."""

    preset: Preset | None = None
    albedo: tuple[float, float, float] | None = None
    albedo_texture: AlbedoTexture | None = None
    roughness: float | None = None
    specular: float | None = None
    no_specular: bool = False
    roughness_scale: float = 1.0
    specular_scale: float = 1.0
    albedo_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @property
    def is_identity(self) -> bool:
        return self == MaterialEdit()

    def describe(self) -> str:
        parts = []
        if self.preset:
            parts.append(self.preset.name)
        if self.albedo:
            parts.append("albedo=" + ",".join(f"{c:g}" for c in self.albedo))
        if self.albedo_texture:
            parts.append(f"albedo-texture={self.albedo_texture.path.name}")
        if self.roughness is not None:
            parts.append(f"roughness={self.roughness:g}")
        if self.specular is not None:
            parts.append(f"specular={self.specular:g}")
        if self.no_specular:
            parts.append("no-specular")
        if self.roughness_scale != 1.0:
            parts.append(f"roughness-scale={self.roughness_scale:g}")
        if self.specular_scale != 1.0:
            parts.append(f"specular-scale={self.specular_scale:g}")
        if self.albedo_tint != (1.0, 1.0, 1.0):
            parts.append("albedo-tint=" + ",".join(f"{c:g}" for c in self.albedo_tint))
        return ",".join(parts) or "as trained"

    def spec(self) -> str:
        """The ``--material`` value that parses back to this edit ("" for the identity); an
        albedo texture is named by its path."""
        if self.is_identity:
            return ""
        text = self.describe()
        if self.albedo_texture is not None:
            text = text.replace(f"albedo-texture={self.albedo_texture.path.name}",
                                f"albedo-texture={self.albedo_texture.path}")
        return text

    def apply(self, material: SurfaceMaterial, points: Tensor, uv: Tensor | None = None) -> SurfaceMaterial:
        """The edited material at ``points`` (N, 3) (scene frame); ``uv`` (N, 2) if the surface has UVs."""
        n = points.shape[0]
        dt, dev = material.albedo.dtype, material.albedo.device
        albedo, specular, alpha = material.albedo, material.specular, material.alpha
        if self.preset is not None:
            albedo = torch.tensor(self.preset.albedo, dtype=dt, device=dev).expand(n, 3)
            specular = torch.full((n, 1), self.preset.specular, dtype=dt, device=dev)
            alpha = torch.full((n, 1), max(self.preset.roughness ** 2, ALPHA_MIN), dtype=dt, device=dev)
        if self.albedo is not None:
            albedo = torch.tensor(self.albedo, dtype=dt, device=dev).expand(n, 3)
        if self.albedo_texture is not None:
            coords = uv if uv is not None else spherical_uv(points)
            albedo = sample_texture(torch.from_numpy(self.albedo_texture.pixels), coords.to(dt)).to(dev)
        if self.roughness is not None:
            alpha = torch.full((n, 1), max(self.roughness ** 2, ALPHA_MIN), dtype=dt, device=dev)
        if self.specular is not None:
            specular = torch.full((n, 1), self.specular, dtype=dt, device=dev)
        if self.no_specular:
            specular = torch.zeros((n, 1), dtype=dt, device=dev)
        if self.roughness_scale != 1.0:  # on perceptual r: alpha' = (k sqrt(alpha))^2
            r = (alpha.clamp_min(0).sqrt() * self.roughness_scale).clamp(max=1.0)
            alpha = r.square().clamp_min(ALPHA_MIN)
        if self.specular_scale != 1.0:
            specular = (specular * self.specular_scale).clamp(0.0, 1.0)
        if self.albedo_tint != (1.0, 1.0, 1.0):
            albedo = (albedo * torch.tensor(self.albedo_tint, dtype=dt, device=dev)).clamp(0.0, 1.0)
        return SurfaceMaterial(albedo=albedo.contiguous(), specular=specular.contiguous(), alpha=alpha.contiguous())


def sample_texture(texture: Tensor, uv: Tensor, wrap_u: bool = False) -> Tensor:
    """Bilinear lookup of a (H, W, C) texture at UVs (N, 2) -> (N, C).

    UV origin bottom-left: texel (row i, column j) has its centre at
    ``u = (j + 0.5) / W``, ``v = 1 - (i + 0.5) / H``. Coordinates are clamped to the edge
    texels (the exporter dilates into gutters), or wrapped in u when ``wrap_u``.
    """
    H, W, _ = texture.shape
    x = uv[:, 0].to(texture.dtype) * W - 0.5
    y = (1.0 - uv[:, 1].to(texture.dtype)) * H - 0.5
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.long(), y0.long()

    def col(c: Tensor) -> Tensor:
        return torch.remainder(c, W) if wrap_u else c.clamp(0, W - 1)

    xa, xb = col(x0), col(x0 + 1)
    ya, yb = y0.clamp(0, H - 1), (y0 + 1).clamp(0, H - 1)
    top = texture[ya, xa] * (1 - fx) + texture[ya, xb] * fx
    bottom = texture[yb, xa] * (1 - fx) + texture[yb, xb] * fx
    return top * (1 - fy) + bottom * fy


# ----------------------------------------------------------------------------- parsing

def _unit_number(key: str, text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise SrvolError(f"material {key}={text}: not a number") from None
    if not (math.isfinite(x) and 0.0 <= x <= 1.0):
        raise SrvolError(f"material {key}={text}: must be in [0, 1]")
    return x


MAX_SCALE = 4.0


def _rgb(key: str, value: str, number) -> tuple[float, float, float]:
    """``key=v`` (grey) or ``key=r,g,b``, each read by ``number(key, text)``."""
    parts = value.split(",")
    if len(parts) == 1:
        parts = parts * 3
    if len(parts) != 3:
        raise SrvolError(f"material {key}={value}: expected one or three numbers")
    return tuple(number(key, p) for p in parts)


def _scale_number(key: str, text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise SrvolError(f"material {key}={text}: not a number") from None
    if not (math.isfinite(x) and 0.0 <= x <= MAX_SCALE):
        raise SrvolError(f"material {key}={text}: must be in [0, {MAX_SCALE:g}]")
    return x


def _tokens(specs: Sequence[str]) -> list[str]:
    """Split specs on commas, re-attaching the bare numbers of ``albedo=r,g,b`` to their key."""
    out: list[str] = []
    for spec in specs:
        for part in (p.strip() for p in spec.split(",")):
            if not part:
                continue
            if out and "=" not in part and out[-1].startswith(("albedo=", "albedo-tint=")) and _is_number(part):
                out[-1] += "," + part
            else:
                out.append(part)
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def parse_material(specs: Sequence[str]) -> MaterialEdit:
    """``["gold", "roughness=0.2"]`` or ``["albedo=0.8,0.2,0.1,specular=0.5"]`` -> MaterialEdit.

    Unknown or malformed specs raise SrvolError with one line naming the spec.
    """
    edit = MaterialEdit()
    for tok in _tokens(specs):
        key, _, value = tok.partition("=")
        key = key.strip().lower()
        if key in PRESETS and not value:
            edit = replace(edit, preset=PRESETS[key])
        elif key == "no-specular" and not value:
            edit = replace(edit, no_specular=True)
        elif key == "albedo" and value:
            edit = replace(edit, albedo=_rgb(key, value, _unit_number))
        elif key == "albedo-texture" and value:
            edit = replace(edit, albedo_texture=AlbedoTexture.read(value))
        elif key == "roughness" and value:
            edit = replace(edit, roughness=_unit_number("roughness", value))
        elif key == "specular" and value:
            edit = replace(edit, specular=_unit_number("specular", value))
        elif key == "roughness-scale" and value:
            edit = replace(edit, roughness_scale=_scale_number(key, value))
        elif key == "specular-scale" and value:
            edit = replace(edit, specular_scale=_scale_number(key, value))
        elif key == "albedo-tint" and value:
            edit = replace(edit, albedo_tint=_rgb(key, value, _scale_number))
        else:
            raise SrvolError(f"unknown material spec {tok!r} (expected {SPEC_HELP})")
    if edit.no_specular and edit.specular is not None:
        raise SrvolError("material: no-specular contradicts specular=x (give one of them)")
    if edit.albedo is not None and edit.albedo_texture is not None:
        raise SrvolError("material: albedo=r,g,b contradicts albedo-texture=PNG (give one of them)")
    return edit


def texel_uvs(height: int, width: int) -> Tensor:
    """(H * W, 2) UVs of a texture's texel centres, row-major (origin bottom-left, row 0 = top)."""
    v = 1.0 - (torch.arange(height, dtype=torch.float32) + 0.5) / height
    u = (torch.arange(width, dtype=torch.float32) + 0.5) / width
    V, U = torch.meshgrid(v, u, indexing="ij")
    return torch.stack([U.reshape(-1), V.reshape(-1)], -1)


def edit_textures(textures: TextureSet, edit: MaterialEdit) -> TextureSet:
    """The asset's material maps with ``edit`` applied texel by texel (through :meth:`MaterialEdit.apply`,
    so an edited asset shades exactly as the edited render did). Normal map and coverage are kept."""
    from srvol.export.types import TextureSet

    H, W = textures.albedo.shape[:2]
    n = H * W

    def flat(a: np.ndarray, c: int) -> Tensor:
        return torch.from_numpy(np.ascontiguousarray(a[..., :c], np.float32)).reshape(n, c)

    material = SurfaceMaterial(albedo=flat(textures.albedo, 3), specular=flat(textures.specular, 1),
                               alpha=flat(textures.alpha, 1))
    out = edit.apply(material, torch.zeros(n, 3), texel_uvs(H, W))
    return TextureSet(albedo=out.albedo.reshape(H, W, 3).numpy(), specular=out.specular.reshape(H, W, 1).numpy(),
                      alpha=out.alpha.reshape(H, W, 1).numpy(), normal=textures.normal, coverage=textures.coverage)
