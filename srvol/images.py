"""Image files: float EXR (linear) and 8/16-bit PNG (sRGB or linear, declared by the caller).

Arrays are (H, W, C) float32, linear unless a function says otherwise. Writes
are atomic: a file is written beside its target and renamed into place.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from srvol.errors import SrvolError


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def atomic_path(path: Path):
    """A temporary path in ``path``'s folder; rename it onto ``path`` when written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    return Path(tmp)


def write_exr(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a float image (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) as a ZIP-compressed float32 EXR."""
    import OpenEXR

    img = np.ascontiguousarray(np.asarray(image, dtype=np.float32))
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 2:
        channels = {"Y": img}
    elif img.shape[2] == 3:
        channels = {"RGB": img}
    elif img.shape[2] == 4:
        channels = {"RGBA": img}
    else:
        raise ValueError(f"cannot write an image of shape {img.shape} as EXR")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    tmp = atomic_path(Path(path))
    try:
        OpenEXR.File(header, channels).write(str(tmp))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """(H, W, 3) or (H, W, 1) float32 from an EXR (RGB/RGBA/Y channels)."""
    import OpenEXR

    try:
        chans = OpenEXR.File(str(path)).channels()
    except Exception as e:  # OpenEXR raises plain Exceptions for unreadable files
        raise SrvolError(f"{path}: not a readable EXR file ({e})") from None
    for key in ("RGB", "RGBA"):
        if key in chans:
            return np.asarray(chans[key].pixels, dtype=np.float32)[..., :3]
    if "Y" in chans:
        return np.asarray(chans["Y"].pixels, dtype=np.float32)[..., None]
    if all(c in chans for c in "RGB"):
        return np.stack([np.asarray(chans[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
    if len(chans) == 1:
        return np.asarray(next(iter(chans.values())).pixels, dtype=np.float32).reshape(*np.shape(next(iter(chans.values())).pixels)[:2], -1)
    raise SrvolError(f"{path}: EXR has no RGB or Y channels (found {sorted(chans)})")


def read_png(path: str | os.PathLike, srgb: bool) -> np.ndarray:
    """(H, W, C) float32 in [0, 1]; decoded from sRGB to linear when ``srgb``."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            arr = np.asarray(im)
    except Exception as e:
        raise SrvolError(f"{path}: not a readable PNG file ({e})") from None
    scale = 65535.0 if arr.dtype == np.uint16 or arr.max(initial=0) > 255 else 255.0
    if arr.dtype == np.bool_:
        scale = 1.0
    x = arr.astype(np.float32) / scale
    if x.ndim == 2:
        x = x[..., None]
    return srgb_to_linear(x) if srgb else x


def write_png(path: str | os.PathLike, image: np.ndarray, srgb: bool = True) -> None:
    """Write a linear float image as 8-bit PNG, sRGB-encoded when ``srgb`` (else stored as is)."""
    from PIL import Image

    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    enc = linear_to_srgb(img) if srgb else np.clip(img, 0.0, 1.0)
    tmp = atomic_path(Path(path))
    try:
        Image.fromarray((enc * 255.0 + 0.5).astype(np.uint8)).save(tmp, format="PNG")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def read_image(path: str | os.PathLike, srgb: bool) -> np.ndarray:
    """An EXR (always linear) or PNG (decoded as ``srgb`` says)."""
    p = Path(path)
    if p.suffix.lower() == ".exr":
        return read_exr(p)
    if p.suffix.lower() == ".png":
        return read_png(p, srgb)
    raise SrvolError(f"{path}: unsupported image type (use .exr or .png)")


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    tmp = atomic_path(Path(path))
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
