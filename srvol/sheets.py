"""Comparison sheets: labelled grids of images written as one PNG (sRGB at the boundary)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from srvol.images import linear_to_srgb, write_png

Tile = tuple[str, np.ndarray]
"""A label and an image (H, W, 3) or (H, W): linear radiance unless the label's caller encoded it."""


def normal_to_rgb(normal: np.ndarray) -> np.ndarray:
    """World normals (H, W, 3) -> displayable [0, 1] colours (0.5 + 0.5 n), black where n = 0."""
    valid = np.linalg.norm(normal, axis=-1, keepdims=True) > 1e-6
    return np.where(valid, 0.5 + 0.5 * normal, 0.0).astype(np.float32)


def error_to_rgb(err: np.ndarray, vmax: float) -> np.ndarray:
    """|error| (H, W) or (H, W, 3) -> a heat map in [0, 1] (display-encoded)."""
    import matplotlib

    e = err.mean(-1) if err.ndim == 3 else err
    return matplotlib.colormaps["inferno"](np.clip(e / max(vmax, 1e-12), 0, 1))[..., :3].astype(np.float32)


def _to_display(img: np.ndarray, encoded: bool) -> np.ndarray:
    x = np.asarray(img, np.float32)
    if x.ndim == 2:
        x = x[..., None]
    if x.shape[2] == 1:
        x = np.repeat(x, 3, axis=2)
    return np.clip(x[..., :3], 0, 1) if encoded else linear_to_srgb(x[..., :3])


def _resize_nearest(img: np.ndarray, h: int, w: int) -> np.ndarray:
    ys = (np.arange(h) * img.shape[0] / h).astype(int)
    xs = (np.arange(w) * img.shape[1] / w).astype(int)
    return img[ys][:, xs]


def write_sheet(path: str | Path, rows: Sequence[Sequence[Tile]], encoded_labels: Sequence[str] = (),
                title: str | None = None) -> None:
    """Write rows of (label, image) tiles; every tile is resized (nearest) to the largest tile's size.

    Tiles whose label is in ``encoded_labels`` are already display values in [0, 1]
    (normal maps, heat maps); others are linear radiance and get the sRGB curve.
    """
    from PIL import Image, ImageDraw

    h = max(img.shape[0] for row in rows for _, img in row)
    w = max(img.shape[1] for row in rows for _, img in row)
    pad, label_h = 4, 16
    title_h = 20 if title else 0
    ncol = max(len(r) for r in rows)
    H = title_h + len(rows) * (h + label_h + pad) + pad
    W = ncol * (w + pad) + pad
    canvas = Image.new("RGB", (W, H), (24, 24, 24))
    draw = ImageDraw.Draw(canvas)
    if title:
        draw.text((pad, 4), title, fill=(230, 230, 230))
    for r, row in enumerate(rows):
        y = title_h + pad + r * (h + label_h + pad)
        for c, (label, img) in enumerate(row):
            x = pad + c * (w + pad)
            disp = _resize_nearest(_to_display(img, label in encoded_labels), h, w)
            canvas.paste(Image.fromarray((disp * 255 + 0.5).astype(np.uint8)), (x, y + label_h))
            draw.text((x + 2, y + 2), label, fill=(230, 230, 230))
    arr = np.asarray(canvas).astype(np.float32) / 255.0
    write_png(path, arr, srgb=False)
