"""Object masks of an imported scene, at the working resolution.

Automatic: the flash lights the object far more than the background (which is farther from the
flash: irradiance falls with the squared distance), so each view's luminance has two modes. Per
view, Otsu's threshold on log luminance splits them; the mask is cleaned (opening, the large
components, holes filled). Then the views are made consistent: a visual hull is carved from all
masks (a voxel stays where at least 90 % of the views that frame it see it inside their mask), and
each mask loses what lies outside the hull's silhouette (background that other views show empty).

Given: ``--masks DIR`` holds one image per photo (same stem, photo size, upright), foreground > 0.5.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from srvol.capture.resolution import WorkingResolution
from srvol.errors import SrvolError
from srvol.types import Camera

HULL_RESOLUTION = 64
HULL_TOLERANCE = 0.1
BACKGROUND_PERCENTILE = 99.0


def outside_bound(cam: Camera, radius: float = 1.0) -> np.ndarray:
    """(H, W) bool: pixels whose ray misses the scene bound (the object cannot be there)."""
    import torch

    from srvol.geometry import ray_sphere

    c = cam.to("cpu", torch.float64)
    near, far = ray_sphere(c.rays_at(c.pixel_centers()), radius)
    return (near >= far).reshape(cam.height, cam.width).numpy()


def threshold_mask(linear: np.ndarray, background: np.ndarray | None = None,
                   percentile: float = BACKGROUND_PERCENTILE) -> np.ndarray:
    """(H, W) bool: the flash-lit object of a linear image (H, W, 3), cleaned.

    With ``background`` ((H, W) bool, pixels known to be background: their rays miss the scene
    bound) the threshold is the ``percentile`` of the background's luminance (the object is lit
    more than nearly all the background); without, Otsu's threshold on log luminance.
    """
    from skimage.filters import threshold_otsu

    lum = linear.mean(-1).astype(np.float64)
    if background is not None and background.sum() > 0.05 * background.size:
        thr = float(np.percentile(lum[background], percentile))
        mask = lum > thr
    else:
        log = np.log(np.clip(lum, 0, None) + 1e-4)
        mask = log > threshold_otsu(log)
    return clean_mask(mask)


def clean_mask(mask: np.ndarray, min_share: float = 0.05) -> np.ndarray:
    """Specks (under 0.2 % of the image) and components smaller than ``min_share`` of the largest
    dropped, holes filled."""
    labels, n = ndimage.label(mask)
    if n == 0:
        return mask
    areas = ndimage.sum(mask, labels, index=np.arange(1, n + 1))
    keep = np.zeros(n + 1, bool)
    keep[1:] = (areas >= min_share * areas.max()) & (areas >= 0.002 * mask.size)
    return ndimage.binary_fill_holes(keep[labels])


def _project(points: np.ndarray, cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel columns, rows (int) and depth of ``points`` (N, 3) in ``cam``; depth <= 0 behind."""
    W2C = cam.W2C.double().numpy()
    K = cam.K.double().numpy()
    pc = points @ W2C[:3, :3].T + W2C[:3, 3]
    z = pc[:, 2]
    zs = np.where(z > 1e-9, z, 1.0)
    u = K[0, 0] * pc[:, 0] / zs + K[0, 1] * pc[:, 1] / zs + K[0, 2]
    v = K[1, 1] * pc[:, 1] / zs + K[1, 2]
    return np.floor(u).astype(np.int64), np.floor(v).astype(np.int64), z


def visual_hull(masks: dict[str, np.ndarray], cameras: dict[str, Camera], resolution: int = HULL_RESOLUTION,
                tolerance: float = HULL_TOLERANCE) -> np.ndarray:
    """(M, 3) centres of the voxels in [-1, 1]^3 (scene frame) that at least 1 - ``tolerance`` of the
    views that frame them see inside their (2 px dilated) mask."""
    lin = (np.arange(resolution) + 0.5) / resolution * 2 - 1
    pts = np.stack(np.meshgrid(lin, lin, lin, indexing="ij"), -1).reshape(-1, 3)
    pts = pts[np.linalg.norm(pts, axis=1) <= 1.0]
    framed = np.zeros(len(pts))
    inside = np.zeros(len(pts))
    for name, mask in masks.items():
        cam = cameras[name]
        m = ndimage.binary_dilation(mask, iterations=2)
        u, v, z = _project(pts, cam)
        ok = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        framed += ok
        inside[ok] += m[v[ok], u[ok]]
    keep = (framed >= 3) & (inside >= (1 - tolerance) * framed)
    return pts[keep]


def hull_silhouette(hull: np.ndarray, cam: Camera, resolution: int = HULL_RESOLUTION) -> np.ndarray:
    """(H, W) bool: where the hull's voxels (cubes of side 2 / resolution) project in ``cam``."""
    out = np.zeros((cam.height, cam.width), bool)
    if len(hull) == 0:
        return out
    u, v, z = _project(hull, cam)
    ok = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    out[v[ok], u[ok]] = True
    radius = float(cam.K[0, 0]) * (np.sqrt(3) / resolution) / max(float(np.min(z[z > 0])), 1e-6)
    return ndimage.binary_dilation(out, iterations=int(np.ceil(radius)) + 1)


def consistent_masks(masks: dict[str, np.ndarray], cameras: dict[str, Camera],
                     max_loss: float = 0.3) -> dict[str, np.ndarray]:
    """Each mask less what falls outside the visual hull's silhouette in its view, holes filled.

    Where that would remove more than ``max_loss`` of a mask, the hull is wrong for that view (the
    object reaches past the scene bound, or a few views carved it), and the mask stays as it was.
    """
    hull = visual_hull(masks, cameras)
    out = {}
    for name, m in masks.items():
        cut = clean_mask(m & hull_silhouette(hull, cameras[name]))
        out[name] = cut if cut.sum() >= (1 - max_loss) * m.sum() else m
    return out


def read_given_mask(mask_dir: Path, name: str, res: WorkingResolution) -> np.ndarray:
    """(h, w) bool mask of photo ``name`` from ``mask_dir`` (any image type, photo size), decimated by
    the working factor (box average > 0.5)."""
    from srvol.capture.photos import PHOTO_SUFFIXES, read_photo_srgb

    found = [p for p in sorted(Path(mask_dir).glob(f"{name}.*")) if p.suffix.lower() in PHOTO_SUFFIXES]
    if not found:
        raise SrvolError(f"{Path(mask_dir) / name}.png: no mask for photo '{name}'")
    m = read_photo_srgb(found[0])[..., 0]
    W, H = res.crop
    if m.shape[0] < H or m.shape[1] < W:
        raise SrvolError(f"{found[0]}: mask size {m.shape[1]}x{m.shape[0]} is smaller than the photo")
    f = res.factor
    m = m[:H, :W].reshape(H // f, f, W // f, f).mean(axis=(1, 3))
    mask = m > 0.5
    if not mask.any():
        raise SrvolError(f"{found[0]}: empty mask (no foreground pixel)")
    return mask
