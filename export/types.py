"""The exported asset's data: a UV-mapped triangle mesh and its material textures.

Conventions: positions in the scene frame (unit sphere, metres when exported
with metersPerUnit = 1, +z up in the scene frame); UVs in [0, 1] with the
origin at the **bottom-left** (v up, as USD ``st`` and OBJ ``vt``); texture
row 0 is the image's top, so texel row = (1 - v) * height. Textures are stored
**linear**; writers convert to sRGB or perceptual roughness at the file boundary.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mesh:
    """vertices (V, 3) float32, faces (F, 3) int32 counter-clockwise seen from outside,
    uv (V, 2) float32 per vertex or None (vertices are split at UV seams),
    normals (V, 3) float32 unit or None."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    normals: np.ndarray | None = None


@dataclass(frozen=True)
class TextureSet:
    """Linear float textures (H, W, C), all the same size.

    albedo (H, W, 3) diffuse rho; specular (H, W, 1) F0; alpha (H, W, 1) GGX alpha;
    normal (H, W, 3) tangent-space normal map in [-1, 1] or None; coverage (H, W) bool,
    texels inside a UV chart (before gutter dilation).
    """

    albedo: np.ndarray
    specular: np.ndarray
    alpha: np.ndarray
    normal: np.ndarray | None = None
    coverage: np.ndarray | None = None

    @property
    def roughness(self) -> np.ndarray:
        """Perceptual roughness r = sqrt(alpha): what Blender, glTF and UsdPreviewSurface read."""
        return np.sqrt(np.clip(self.alpha, 0.0, 1.0))


@dataclass(frozen=True)
class Asset:
    mesh: Mesh
    textures: TextureSet
