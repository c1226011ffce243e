"""Image files: float EXR (linear) and 8/16-bit PNG (sRGB or linear, declared by the caller).

Arrays are (H, W, C) float32, linear unless a function says otherwise. Writes
are atomic (:mod:`srvol.atomic`): a file is written beside its target and renamed into place.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from srvol.atomic import atomic_path
from srvol.errors import SrvolError


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


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
    """(H, W, C) float32 in [0, 1]; decoded from sRGB to linear when ``srgb``.

    8- and 16-bit grey, grey+alpha, RGB, RGBA and palette PNGs. Pillow reduces
    16-bit colour PNGs to 8 bits, so those are decoded here (:func:`_decode_png16`).
    """
    from PIL import Image

    try:
        header = Path(path).read_bytes()[:29]
        if _is_png16_colour(header):
            x = _decode_png16(Path(path).read_bytes())
        else:
            with Image.open(path) as im:
                if im.mode in ("P", "PA"):
                    im = im.convert("RGBA" if "transparency" in im.info or im.mode == "PA" else "RGB")
                arr = np.asarray(im)
            scale = {np.dtype(np.bool_): 1.0, np.dtype(np.uint8): 255.0}.get(arr.dtype, 65535.0)
            x = arr.astype(np.float32) / scale
    except SrvolError:
        raise
    except Exception as e:
        raise SrvolError(f"{path}: not a readable PNG file ({e})") from None
    if x.ndim == 2:
        x = x[..., None]
    return srgb_to_linear(x) if srgb else x


_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}  # colour type -> samples per pixel


def _is_png16_colour(header: bytes) -> bool:
    """A non-interlaced 16-bit PNG with colour or alpha (what Pillow would cut to 8 bits)."""
    return (len(header) >= 29 and header[:8] == _PNG_MAGIC and header[12:16] == b"IHDR"
            and header[24] == 16 and header[25] in (2, 4, 6) and header[28] == 0)


def _decode_png16(data: bytes) -> np.ndarray:
    """(H, W, C) float32 in [0, 1] from a non-interlaced 16-bit PNG of colour type 2, 4 or 6."""
    import struct
    import zlib

    pos, idat, W = 8, [], 0
    while pos + 8 <= len(data):
        length, tag = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if tag == b"IHDR":
            W, H, _, colour_type = struct.unpack(">IIBB", body[:10])
        elif tag == b"IDAT":
            idat.append(body)
        elif tag == b"IEND":
            break
        pos += 12 + length
    if not W or not idat:
        raise SrvolError("truncated PNG (no IHDR or IDAT)")
    C = _PNG_CHANNELS[colour_type]
    bpp, stride = 2 * C, 2 * C * W
    raw = zlib.decompress(b"".join(idat))
    if len(raw) < H * (stride + 1):
        raise SrvolError("truncated PNG image data")
    out = np.empty((H, stride), np.uint8)
    prev = bytearray(stride)
    for j in range(H):
        ftype = raw[j * (stride + 1)]
        row = bytearray(raw[j * (stride + 1) + 1:(j + 1) * (stride + 1)])
        _unfilter_row(ftype, row, prev, bpp)
        out[j] = np.frombuffer(bytes(row), np.uint8)
        prev = row
    return (out.view(">u2").reshape(H, W, C).astype(np.float32) / 65535.0)


def _unfilter_row(ftype: int, row: bytearray, prev: bytearray, bpp: int) -> None:
    """Undo one PNG scanline filter in place (PNG spec section 9)."""
    n = len(row)
    if ftype == 0:
        return
    if ftype == 1:
        for i in range(bpp, n):
            row[i] = (row[i] + row[i - bpp]) & 0xFF
    elif ftype == 2:
        for i in range(n):
            row[i] = (row[i] + prev[i]) & 0xFF
    elif ftype == 3:
        for i in range(n):
            left = row[i - bpp] if i >= bpp else 0
            row[i] = (row[i] + ((left + prev[i]) >> 1)) & 0xFF
    elif ftype == 4:
        for i in range(n):
            a = row[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            p = a + b - c
            pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
            row[i] = (row[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 0xFF
    else:
        raise SrvolError(f"unknown PNG filter type {ftype}")


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
