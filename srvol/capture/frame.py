"""Similarities between frames: the capture's (SfM, arbitrary scale) and the scene's (object in the
unit sphere, +z up), and the fit of one frame onto another from camera centres.

A :class:`Similarity` maps x -> s R x + t. ``scene.json``'s ``normalization`` records the one from
the capture frame to the scene frame (DESIGN.md section 4).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from srvol.errors import SrvolError
from srvol.types import Camera

OBJECT_RADIUS = 0.8
"""Radius the object's bounding sphere gets in the scene frame (the built-in scenes reach ~0.8)."""


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation; rotation (3, 3) proper, scale > 0, float64."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    @staticmethod
    def identity() -> "Similarity":
        return Similarity(1.0, np.eye(3), np.zeros(3))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N, 3)."""
        return self.scale * np.asarray(points, np.float64) @ self.rotation.T + self.translation

    def inverse(self) -> "Similarity":
        Rt = self.rotation.T
        return Similarity(1.0 / self.scale, Rt, -Rt @ self.translation / self.scale)

    def then(self, other: "Similarity") -> "Similarity":
        """``other`` after ``self``: x -> other(self(x))."""
        return Similarity(other.scale * self.scale, other.rotation @ self.rotation,
                          other.scale * other.rotation @ self.translation + other.translation)

    def camera(self, cam: Camera) -> Camera:
        """``cam`` (world-to-camera in the source frame) seen in the target frame: the same image.

        x_c = R_c x + t_c with x = S^-1(y) = R^T (y - t) / s; scaling the camera frame by s does not
        change the projection, so W2C' = [R_c R^T | s t_c - R_c R^T t].
        """
        W2C = cam.W2C.double().numpy()
        Rc, tc = W2C[:3, :3], W2C[:3, 3]
        R = Rc @ self.rotation.T
        out = np.eye(4)
        out[:3, :3] = R
        out[:3, 3] = self.scale * tc - R @ self.translation
        return Camera(K=cam.K.double(), W2C=torch.from_numpy(out), width=cam.width, height=cam.height)

    def to_json(self) -> dict:
        return {"scale": float(self.scale), "translation": [float(v) for v in self.translation],
                "rotation": [float(v) for v in self.rotation.reshape(-1)]}

    @staticmethod
    def from_json(d: dict, where: str = "normalization") -> "Similarity":
        try:
            s = float(d["scale"])
            t = np.asarray([float(v) for v in d["translation"]], np.float64)
            R = np.asarray([float(v) for v in d["rotation"]], np.float64).reshape(3, 3)
        except (KeyError, TypeError, ValueError) as e:
            raise SrvolError(f"{where}: malformed similarity ({e})") from None
        if not (s > 0 and t.shape == (3,) and np.abs(R @ R.T - np.eye(3)).max() < 1e-4):
            raise SrvolError(f"{where}: the similarity needs a positive scale and a rotation")
        return Similarity(s, R, t)


def read_normalization(scene_dir: Path) -> Similarity | None:
    """The capture-to-scene similarity an imported scene records in scene.json (None if absent)."""
    path = Path(scene_dir) / "scene.json"
    if not path.is_file():
        return None
    raw = json.loads(path.read_text())
    norm = raw.get("normalization") if isinstance(raw, dict) else None
    return Similarity.from_json(norm, f"{path}: normalization") if norm is not None else None


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector ``a`` onto unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1 + 1e-9:  # opposite: half a turn about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def fit_similarity(src: np.ndarray, dst: np.ndarray) -> Similarity:
    """Least-squares similarity with dst ~ s R src + t (Umeyama 1991); src, dst (N, 3), N >= 3."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if len(src) < 3:
        raise SrvolError(f"a similarity needs 3 or more corresponding points, got {len(src)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs ** 2).sum() / len(src)
    U, D, Vt = np.linalg.svd(xd.T @ xs / len(src))
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s) if var_s > 0 else 1.0
    return Similarity(s, R, mu_d - s * R @ mu_s)


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """The angle (degrees) of the rotation Ra Rb^T."""
    c = (np.trace(Ra @ Rb.T) - 1) / 2
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


# ----------------------------------------------------------------------------- normalisation

@dataclass(frozen=True)
class ObjectSphere:
    """The object's bounding sphere in the capture frame, from the sparse points most views see."""

    center: np.ndarray
    radius: float
    points_used: int
    points: np.ndarray | None = None  # (points_used, 3) the object's sparse points, when there were any


def visible_fraction(points: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """(N,) fraction of ``cameras`` in whose frame each point projects (in front, inside the image)."""
    count = np.zeros(len(points))
    for cam in cameras:
        W2C = cam.W2C.double().numpy()
        pc = points @ W2C[:3, :3].T + W2C[:3, 3]
        K = cam.K.double().numpy()
        z = pc[:, 2]
        uv = pc[:, :2] / np.where(z > 1e-9, z, 1.0)[:, None] @ K[:2, :2].T + K[:2, 2]
        inside = (z > 1e-9) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        count += inside
    return count / max(len(cameras), 1)


def object_sphere_from_points(points: np.ndarray, cameras: list[Camera], min_fraction: float = 0.75) -> ObjectSphere:
    """The bounding sphere of the sparse points that at least ``min_fraction`` of the views frame
    (the object, which every photo is aimed at; not the background, which each view sees a part of)
    and that lie nearer to where the optical axes meet than 0.6 x the cameras' median distance from
    there (a walk along a short arc frames the same patch of background in every photo):
    centre the middle of their robust bounding box, radius 1.1 x their 98th-percentile distance."""
    points = np.asarray(points, np.float64)
    frac = visible_fraction(points, cameras)
    aim = object_sphere_from_cameras(cameras).center
    reach = 0.6 * float(np.median([np.linalg.norm(c.center.double().numpy() - aim) for c in cameras]))
    frac = np.where(np.linalg.norm(points - aim, axis=1) < reach, frac, 0.0)
    keep = frac >= min_fraction
    if keep.sum() < 20:  # few points: the best-seen fifth
        keep = frac >= np.quantile(frac, 0.8) if len(frac) else keep
    if keep.sum() < 4:
        raise SrvolError(f"too few sparse points seen by most views ({int(keep.sum())}) to find the object")
    p = points[keep]
    lo, hi = np.percentile(p, 1, axis=0), np.percentile(p, 99, axis=0)
    center = (lo + hi) / 2
    radius = 1.1 * float(np.percentile(np.linalg.norm(p - center, axis=1), 98))
    return ObjectSphere(center=center, radius=radius, points_used=int(keep.sum()), points=p)


def object_sphere_from_cameras(cameras: list[Camera]) -> ObjectSphere:
    """Without sparse points: the point nearest to every optical axis (least squares), and the
    radius that fills 80 % of the median view's height."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    dists = []
    for cam in cameras:
        c = cam.center.double().numpy()
        d = cam.W2C[2, :3].double().numpy()
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c
    center = np.linalg.lstsq(A, b, rcond=None)[0]
    for cam in cameras:
        d = float(np.linalg.norm(cam.center.double().numpy() - center))
        half = math.atan(cam.height / 2 / float(cam.K[1, 1]))
        dists.append(d * math.sin(half) * 0.8)
    return ObjectSphere(center=center, radius=float(np.median(dists)), points_used=0)


def up_direction(cameras: list[Camera]) -> np.ndarray:
    """(3,) the capture's up: the mean image-up direction (-y of each camera) in the world."""
    ups = np.stack([-cam.W2C[1, :3].double().numpy() for cam in cameras])
    u = ups.sum(0)
    return u / max(np.linalg.norm(u), 1e-12)


def normalization(sphere: ObjectSphere, up: np.ndarray) -> Similarity:
    """Capture -> scene: the object's sphere onto the origin with radius :data:`OBJECT_RADIUS`, the
    capture's up onto +z."""
    R = rotation_between(up, np.array([0.0, 0.0, 1.0]))
    s = OBJECT_RADIUS / sphere.radius
    return Similarity(s, R, -s * R @ sphere.center)
