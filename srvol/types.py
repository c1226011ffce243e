"""Typed values passed between srvol's stages, and the conventions they carry.

Conventions (the one place they are written down):

* **Frame.** The object is normalised into the unit sphere; every position
  (cameras, lights, surface points) is in that *scene frame*.
* **Cameras.** OpenCV: x right, y down, z forward (the camera looks along +z).
  ``W2C`` is the 4x4 world-to-camera matrix, ``K`` the 3x3 pinhole intrinsics
  in pixels. Pixel ``(i, j)`` (column i, row j) covers ``[i, i+1) x [j, j+1)``;
  its centre is ``(i + 0.5, j + 0.5)``.
* **Colour.** Everything internal is *linear* RGB float. sRGB exists only at
  8-bit PNG boundaries, and is converted there explicitly.
* **Light.** A point light of radiant intensity ``I`` (W/sr, per channel).
  Irradiance at x with normal n: ``I * max(0, n.l) / r^2``; ``l`` the unit
  vector from x to the light, ``r`` the distance. *Co-located* = the light
  sits at the camera centre (a phone flash).
* **Material.** Diffuse albedo ``rho``, specular reflectance at normal
  incidence ``F0`` (grey, ~0.04 for plastics) and GGX ``alpha``. Perceptual
  roughness ``r = sqrt(alpha)`` is what Blender, glTF and UsdPreviewSurface
  expect; exporters write ``r``, never ``alpha``.
* **Directions.** ``view_dir`` points from the surface to the eye,
  ``light_dir`` from the surface to the light; both unit length.

Tensor shapes are given in the annotations' comments: ``(N, 3)`` etc.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Protocol, Sequence

import torch
from torch import Tensor

ALPHA_MIN = 1e-3
"""Smallest GGX alpha any decoder produces (r ~ 0.03): keeps D finite."""


@dataclass(frozen=True)
class Camera:
    """A pinhole camera in OpenCV convention (see module docstring).

    K:   (3, 3) intrinsics in pixels.
    W2C: (4, 4) world-to-camera transform.
    width, height: image size in pixels.
    """

    K: Tensor
    W2C: Tensor
    width: int
    height: int

    @property
    def C2W(self) -> Tensor:
        return torch.linalg.inv(self.W2C)

    @property
    def center(self) -> Tensor:
        """(3,) camera centre in the scene frame."""
        R, t = self.W2C[:3, :3], self.W2C[:3, 3]
        return -R.T @ t

    def scaled(self, factor: float) -> "Camera":
        """The same camera at ``factor`` times the resolution (HR from LR).

        Pixel edges map to pixel edges: a point at LR pixel coordinate u sits at
        HR coordinate ``factor * u``, so the field of view is unchanged.
        """
        K = self.K.clone()
        K[:2, :] = K[:2, :] * factor
        return Camera(K=K, W2C=self.W2C, width=round(self.width * factor),
                      height=round(self.height * factor))

    def to(self, device: torch.device | str, dtype: torch.dtype = torch.float32) -> "Camera":
        return replace(self, K=self.K.to(device, dtype), W2C=self.W2C.to(device, dtype))

    def rays_at(self, uv: Tensor) -> "Rays":
        """Rays through continuous pixel coordinates ``uv`` (N, 2): (u right, v down).

        ``uv = (i + 0.5, j + 0.5)`` is the centre of pixel (i, j).
        """
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        skew = self.K[0, 1]
        y = (uv[:, 1] - cy) / fy
        x = (uv[:, 0] - cx - skew * y) / fx
        d_cam = torch.stack([x, y, torch.ones_like(x)], dim=-1)
        R = self.W2C[:3, :3]
        d = d_cam @ R  # R^T d_cam for row vectors
        d = d / d.norm(dim=-1, keepdim=True)
        o = self.center.expand_as(d)
        return Rays(origins=o, directions=d)

    def pixel_centers(self) -> Tensor:
        """(H*W, 2) centres of all pixels, row-major (j outer, i inner)."""
        j, i = torch.meshgrid(torch.arange(self.height, dtype=self.K.dtype, device=self.K.device),
                              torch.arange(self.width, dtype=self.K.dtype, device=self.K.device),
                              indexing="ij")
        return torch.stack([i.reshape(-1) + 0.5, j.reshape(-1) + 0.5], dim=-1)

    def project(self, points: Tensor) -> Tensor:
        """(N, 3) scene points -> (N, 2) continuous pixel coordinates."""
        p = points @ self.W2C[:3, :3].T + self.W2C[:3, 3]
        q = p @ self.K.T
        return q[:, :2] / q[:, 2:3]

    @staticmethod
    def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float],
                K: Tensor, width: int, height: int) -> "Camera":
        """A camera at ``eye`` looking at ``target``; ``up`` is roughly image-up (−y)."""
        eye_t = torch.as_tensor(eye, dtype=torch.float64)
        z = torch.as_tensor(target, dtype=torch.float64) - eye_t
        z = z / z.norm()
        up_t = torch.as_tensor(up, dtype=torch.float64)
        x = torch.linalg.cross(z, up_t)  # image right; then y = z x x points down, away from ``up``
        if x.norm() < 1e-8:  # looking along up: pick any perpendicular
            x = torch.linalg.cross(z, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
        x = x / x.norm()
        y = torch.linalg.cross(z, x)
        R = torch.stack([x, y, z])  # rows: camera axes in world coordinates
        W2C = torch.eye(4, dtype=torch.float64)
        W2C[:3, :3] = R
        W2C[:3, 3] = -R @ eye_t
        return Camera(K=K.to(torch.float64), W2C=W2C, width=width, height=height)


@dataclass(frozen=True)
class Rays:
    """origins (N, 3), unit directions (N, 3)."""

    origins: Tensor
    directions: Tensor

    def __len__(self) -> int:
        return self.origins.shape[0]

    def at(self, t: Tensor) -> Tensor:
        """Points at distance ``t`` (N,) or (N, S) -> (N, 3) or (N, S, 3)."""
        if t.dim() == 1:
            return self.origins + t[:, None] * self.directions
        return self.origins[:, None, :] + t[..., None] * self.directions[:, None, :]

    def __getitem__(self, idx) -> "Rays":
        return Rays(self.origins[idx], self.directions[idx])


@dataclass(frozen=True)
class PointLight:
    """An isotropic point light: position (3,) in the scene frame, radiant intensity (3,) RGB.

    ``position`` may also be (N, 3), one light per shaded point: a training batch
    mixes rays of several views, each lit by its own camera's flash.
    """

    position: Tensor
    intensity: Tensor

    @staticmethod
    def at_camera(camera: Camera, intensity: Tensor | Sequence[float]) -> "PointLight":
        """The co-located (flash) light of ``camera``."""
        I = torch.as_tensor(intensity, dtype=camera.W2C.dtype, device=camera.W2C.device)
        return PointLight(position=camera.center, intensity=I.expand(3).clone() if I.numel() == 1 else I)

    @staticmethod
    def make(position: Sequence[float], intensity: Sequence[float] | float) -> "PointLight":
        I = torch.as_tensor(intensity, dtype=torch.float32)
        if I.numel() == 1:
            I = I.reshape(1).expand(3).clone()
        return PointLight(position=torch.as_tensor(position, dtype=torch.float32), intensity=I)

    def to(self, device, dtype=torch.float32) -> "PointLight":
        return PointLight(self.position.to(device, dtype), self.intensity.to(device, dtype))


@dataclass(frozen=True)
class SurfaceMaterial:
    """BRDF parameters at N points, all linear.

    albedo:   (N, 3) diffuse albedo rho in [0, 1].
    specular: (N, 1) F0, specular reflectance at normal incidence, in [0, 1].
    alpha:    (N, 1) GGX alpha in [ALPHA_MIN, 1]. ``roughness`` = sqrt(alpha).
    """

    albedo: Tensor
    specular: Tensor
    alpha: Tensor

    @property
    def roughness(self) -> Tensor:
        """Perceptual roughness r = sqrt(alpha) (what exporters write)."""
        return self.alpha.sqrt()

    @staticmethod
    def from_roughness(albedo: Tensor, specular: Tensor, roughness: Tensor) -> "SurfaceMaterial":
        return SurfaceMaterial(albedo=albedo, specular=specular, alpha=roughness.square().clamp_min(ALPHA_MIN))

    @staticmethod
    def constant(n: int, albedo=(0.5, 0.5, 0.5), specular: float = 0.04, alpha: float = 0.25,
                 device=None, dtype=torch.float32) -> "SurfaceMaterial":
        a = torch.tensor(albedo, dtype=dtype, device=device).expand(n, 3).clone()
        s = torch.full((n, 1), specular, dtype=dtype, device=device)
        al = torch.full((n, 1), alpha, dtype=dtype, device=device)
        return SurfaceMaterial(albedo=a, specular=s, alpha=al)

    def __getitem__(self, idx) -> "SurfaceMaterial":
        return SurfaceMaterial(self.albedo[idx], self.specular[idx], self.alpha[idx])


SdfFn = Callable[[Tensor], Tensor]
"""(N, 3) points -> (N,) signed distance (negative inside)."""

MaterialFn = Callable[[Tensor], SurfaceMaterial]
"""(N, 3) surface points -> SurfaceMaterial at those points."""


class FieldModel(Protocol):
    """What every consumer of a trained model (eval, export, relight) sees.

    ``load_model(run)`` in :mod:`srvol.checkpoint` returns one of these.
    """

    def sdf(self, x: Tensor) -> Tensor:  # (N, 3) -> (N,)
        ...

    def material(self, x: Tensor) -> SurfaceMaterial:  # (N, 3) -> SurfaceMaterial
        ...


@dataclass(frozen=True)
class RenderResult:
    """Per-ray output of a renderer.

    rgb:     (N, 3) linear radiance.
    opacity: (N,) accumulated opacity in [0, 1].
    normal:  (N, 3) expected (weight-averaged) world normal, not re-normalised.
    depth:   (N,) expected distance along the ray.
    """

    rgb: Tensor
    opacity: Tensor
    normal: Tensor
    depth: Tensor
