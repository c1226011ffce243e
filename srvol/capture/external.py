"""Poses that already exist: a COLMAP sparse model (text or binary) or a nerfstudio / instant-ngp
``transforms.json``. Both are matched to the photos by file stem and scaled to each photo's size.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from srvol.capture.photos import PhotoInfo
from srvol.capture.sfm import Registration, registration_from_reconstruction
from srvol.errors import SrvolError
from srvol.types import Camera

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Camera axes of OpenGL / nerfstudio (x right, y up, z back) to OpenCV's (x right, y down, z forward)."""


def load_colmap(model_dir: Path, photos: list[PhotoInfo]) -> Registration:
    """A COLMAP sparse model folder (cameras/images/points3D as .bin or .txt)."""
    import pycolmap

    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise SrvolError(f"{model_dir}: not a folder (--colmap takes a sparse model folder)")
    found = {p.name for p in model_dir.iterdir()}
    if not ({"cameras.bin", "images.bin"} <= found or {"cameras.txt", "images.txt"} <= found):
        raise SrvolError(f"{model_dir}: no COLMAP model (cameras and images .bin or .txt)")
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:
        raise SrvolError(f"{model_dir}: unreadable COLMAP model ({str(e).splitlines()[0] if str(e) else e})") from None
    return registration_from_reconstruction(rec, [p.name for p in photos], {p.name: p.size for p in photos},
                                            "colmap")


def load_transforms(path: Path, photos: list[PhotoInfo]) -> Registration:
    """A nerfstudio / instant-ngp transforms.json: per-frame ``transform_matrix`` (camera-to-world,
    OpenGL axes), intrinsics (``fl_x``/``fl_y``/``cx``/``cy`` or ``camera_angle_x``, with ``w``/``h``)
    at the top level or per frame."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except OSError as e:
        raise SrvolError(f"{path}: cannot read ({e.strerror})") from None
    except json.JSONDecodeError as e:
        raise SrvolError(f"{path}: malformed JSON (line {e.lineno}: {e.msg})") from None
    frames = raw.get("frames") if isinstance(raw, dict) else None
    if not isinstance(frames, list) or not frames:
        raise SrvolError(f"{path}: no 'frames' list")
    sizes = {p.name: p.size for p in photos}
    cams: dict[str, Camera] = {}
    for i, fr in enumerate(frames):
        try:
            name = Path(str(fr["file_path"])).stem
            if name not in sizes:
                continue
            c2w = np.asarray(fr["transform_matrix"], np.float64).reshape(-1, 4)
            if c2w.shape == (3, 4):
                c2w = np.vstack([c2w, [0, 0, 0, 1]])
            W, H = sizes[name]
            K = _intrinsics({**raw, **fr}, W, H)
        except (KeyError, TypeError, ValueError) as e:
            raise SrvolError(f"{path}: frame {i} is malformed ({e})") from None
        if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
            raise SrvolError(f"{path}: frame {i}: transform_matrix must be 4x4 and finite")
        c2w = c2w @ GL_TO_CV
        R = c2w[:3, :3]
        scale = np.cbrt(np.linalg.det(R))
        if not scale > 0:
            raise SrvolError(f"{path}: frame {i}: transform_matrix has no proper rotation")
        R = R / scale  # some writers fold a scale into the rotation
        W2C = np.eye(4)
        W2C[:3, :3] = R.T
        W2C[:3, 3] = -R.T @ c2w[:3, 3]
        cams[name] = Camera(K=torch.from_numpy(K), W2C=torch.from_numpy(W2C), width=W, height=H)
    unreg = tuple(p.name for p in photos if p.name not in cams)
    return Registration(cameras={p.name: cams[p.name] for p in photos if p.name in cams},
                        points=np.zeros((0, 3)), unregistered=unreg, source="transforms")


def _intrinsics(d: dict, W: int, H: int) -> np.ndarray:
    """(3, 3) K of a transforms.json frame (or its top level), scaled from its w x h to W x H."""
    w = float(d.get("w", W))
    h = float(d.get("h", H))
    if "fl_x" in d:
        fx = float(d["fl_x"])
        fy = float(d.get("fl_y", fx))
    elif "camera_angle_x" in d:
        fx = 0.5 * w / math.tan(0.5 * float(d["camera_angle_x"]))
        fy = 0.5 * h / math.tan(0.5 * float(d["camera_angle_y"])) if "camera_angle_y" in d else fx
    else:
        raise ValueError("no focal length (fl_x or camera_angle_x)")
    cx = float(d.get("cx", w / 2))
    cy = float(d.get("cy", h / 2))
    sx, sy = W / w, H / h
    return np.array([[fx * sx, 0, cx * sx], [0, fy * sy, cy * sy], [0, 0, 1.0]])
