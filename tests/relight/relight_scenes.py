"""Hand-built scenes for the relighting tests (shared by import: ``from relight_scenes import ...``)."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import torch

from srvol.export.types import Asset, Mesh
from srvol.images import write_exr
from srvol.relight.synthetic import constant_textures
from srvol.types import Camera, PointLight, SurfaceMaterial


@dataclass(frozen=True)
class SphereOnPlane:
    """A ball of radius R centred at (0, 0, c) above the plane z = -h, lit from (0, 0, L).

    The shadow on the plane is a disk about the z axis: the light's cone tangent to the ball
    has half-angle asin(R / (L - c)), and the plane lies L + h below the light, so
    shadow_radius = (L + h) R / sqrt((L - c)^2 - R^2).
    """

    R: float = 0.3
    c: float = 0.2
    h: float = 0.3
    L: float = 1.5

    @property
    def shadow_radius(self) -> float:
        D = self.L - self.c
        return (self.L + self.h) * self.R / math.sqrt(D * D - self.R * self.R)

    def light(self) -> PointLight:
        return PointLight.make([0.0, 0.0, self.L], 10.0)

    def sdf(self, x: torch.Tensor) -> torch.Tensor:
        ball = (x - x.new_tensor([0.0, 0.0, self.c])).norm(dim=-1) - self.R
        return torch.minimum(ball, x[:, 2] + self.h)

    @staticmethod
    def material(x: torch.Tensor) -> SurfaceMaterial:
        return SurfaceMaterial.constant(x.shape[0], albedo=(0.7, 0.6, 0.5), specular=0.04, alpha=0.09,
                                        dtype=x.dtype, device=x.device)

    def asset(self) -> Asset:
        """An icosphere (subdivision 4) + a ground quad, constant textures matching ``material``."""
        import trimesh

        ball = trimesh.creation.icosphere(subdivisions=4, radius=self.R)
        bv = np.asarray(ball.vertices) + [0.0, 0.0, self.c]
        bn = np.asarray(ball.vertices) / self.R
        qv = np.array([[-1, -1, -self.h], [1, -1, -self.h], [1, 1, -self.h], [-1, 1, -self.h]], float)
        qf = np.array([[0, 1, 2], [0, 2, 3]]) + len(bv)
        verts = np.concatenate([bv, qv])
        faces = np.concatenate([np.asarray(ball.faces), qf])
        normals = np.concatenate([bn, np.tile([0.0, 0.0, 1.0], (4, 1))])
        mesh = Mesh(vertices=verts.astype(np.float32), faces=faces.astype(np.int32),
                    uv=np.full((len(verts), 2), 0.5, np.float32), normals=normals.astype(np.float32))
        return Asset(mesh=mesh, textures=constant_textures((0.7, 0.6, 0.5), 0.04, 0.09))


def oblique_camera(width: int = 96, height: int = 72) -> Camera:
    """Looking down at the ground from the side, so that the shadow ring shows around the ball."""
    f = 0.9 * width
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64)
    return Camera.look_at([0.0, -1.9, 1.6], [0.0, 0.0, -0.3], [0, 0, 1], K, width, height)


def write_asset_folder(root, asset) -> None:
    """An asset folder by the contract of srvol.export.asset (what `srvol export` writes)."""
    (root / "raw").mkdir(parents=True)
    m, t = asset.mesh, asset.textures
    np.savez(root / "raw" / "mesh.npz", vertices=m.vertices, faces=m.faces, uv=m.uv, normals=m.normals)
    write_exr(root / "raw" / "albedo.exr", t.albedo)
    write_exr(root / "raw" / "specular.exr", t.specular)
    write_exr(root / "raw" / "alpha.exr", t.alpha)
    write_exr(root / "raw" / "roughness.exr", np.sqrt(t.alpha))
    (root / "asset.json").write_text(json.dumps({
        "format": "srvol-asset/1", "mesh": "raw/mesh.npz",
        "textures": {"albedo": "raw/albedo.exr", "specular": "raw/specular.exr", "alpha": "raw/alpha.exr",
                     "roughness": "raw/roughness.exr"}, "files": {}, "stats": {}}))
