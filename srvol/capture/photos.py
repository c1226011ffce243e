"""The photos of a capture: listing a folder, reading one photo upright and linear, its EXIF focal.

A capture folder holds JPEG, PNG or TIFF photos (8 or 16 bit, sRGB-encoded as a phone writes them);
other files are skipped with a notice. Every photo is turned upright by its EXIF orientation before
anything else sees it, so the focal prior, the poses and the images all refer to the upright image.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from srvol.errors import SrvolError
from srvol.images import srgb_to_linear

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)

_EXIF_IFD = 0x8769
_FOCAL_35MM = 0xA405
_FOCAL_MM = 0x920A
_PLANE_X_RES = 0xA20E
_PLANE_UNIT = 0xA210
_EXIF_WIDTH = 0xA002
_ORIENTATION = 0x0112
_MM_PER_UNIT = {2: 25.4, 3: 10.0, 4: 1.0}  # inch, cm, mm


@dataclass(frozen=True)
class FocalPrior:
    """A focal length in pixels of the upright photo and where it came from ("35mm", "sensor")."""

    pixels: float
    source: str


@dataclass(frozen=True)
class PhotoInfo:
    """One photo of a capture: its file, view name (the stem), upright size and EXIF focal prior."""

    path: Path
    name: str
    width: int
    height: int
    focal: FocalPrior | None

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height


def notice(text: str) -> None:
    print(f"srvol: notice: {text}", file=sys.stderr)


def list_photos(folder: Path) -> list[PhotoInfo]:
    """The photos of ``folder``, sorted by name; each opened once to check it and read its EXIF.

    Raises :class:`SrvolError` for a missing or empty folder, an unreadable photo (named) and two
    photos with the same stem; other files are skipped with a notice.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SrvolError(f"{folder}: not a folder of photos")
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    photos = [p for p in files if p.suffix.lower() in PHOTO_SUFFIXES]
    skipped = [p.name for p in files if p.suffix.lower() not in PHOTO_SUFFIXES]
    if skipped:
        notice(f"skipped {len(skipped)} file(s) that are not JPEG/PNG/TIFF photos: {', '.join(skipped[:8])}"
               f"{' ...' if len(skipped) > 8 else ''}")
    if not photos:
        raise SrvolError(f"{folder}: no photos (JPEG, PNG or TIFF) in the folder")
    seen: dict[str, Path] = {}
    for p in photos:
        if p.stem in seen:
            raise SrvolError(f"{p}: same name as {seen[p.stem].name} (two photos named '{p.stem}')")
        seen[p.stem] = p
    return [photo_info(p) for p in photos]


def photo_info(path: Path) -> PhotoInfo:
    """Size (upright) and focal prior of one photo; the whole image is decoded once to check it."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.load()
            exif = im.getexif()
            w, h = im.size
    except Exception as e:  # PIL raises many types for broken files
        raise SrvolError(f"{path}: not a readable photo ({_why(e)})") from None
    if exif.get(_ORIENTATION, 1) in (5, 6, 7, 8):
        w, h = h, w
    return PhotoInfo(path=path, name=path.stem, width=w, height=h, focal=focal_prior(exif, w, h))


def _why(e: Exception) -> str:
    return str(e).splitlines()[0] if str(e) else type(e).__name__


def focal_prior(exif, width: int, height: int) -> FocalPrior | None:
    """The focal length in pixels of an upright ``width`` x ``height`` photo from its EXIF, or None.

    The 35 mm-equivalent focal (FocalLengthIn35mmFilm) scales with the diagonal, which the
    orientation does not change; else the focal length in mm with the focal-plane resolution,
    rescaled when the photo is smaller than the sensor image the resolution refers to.
    """
    try:
        ifd = exif.get_ifd(_EXIF_IFD)
    except Exception:
        return None
    f35 = ifd.get(_FOCAL_35MM)
    if f35 and float(f35) > 0:
        return FocalPrior(float(f35) / FULL_FRAME_DIAGONAL_MM * math.hypot(width, height), "35mm")
    f_mm, xres, unit = ifd.get(_FOCAL_MM), ifd.get(_PLANE_X_RES), ifd.get(_PLANE_UNIT, 2)
    if f_mm and xres and float(f_mm) > 0 and float(xres) > 0 and unit in _MM_PER_UNIT:
        px_per_mm = float(xres) / _MM_PER_UNIT[unit]
        exif_w = ifd.get(_EXIF_WIDTH)
        long_side = max(width, height)
        scale = long_side / float(exif_w) if exif_w and float(exif_w) >= long_side else 1.0
        return FocalPrior(float(f_mm) * px_per_mm * scale, "sensor")
    return None


def read_photo_srgb(path: Path) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1], still sRGB-encoded, upright by the EXIF orientation.

    8- and 16-bit JPEG/PNG/TIFF, grey or colour (alpha dropped). The pixels are decoded as stored
    (16-bit colour PNGs by :func:`srvol.images.read_png`, TIFFs by tifffile: Pillow would cut both
    to 8 bits), then turned by :func:`apply_orientation`.
    """
    from PIL import Image

    suffix = path.suffix.lower()
    try:
        with Image.open(path) as im:
            orientation = int(im.getexif().get(_ORIENTATION, 1) or 1)
            arr = _pil_pixels(im) if suffix in (".jpg", ".jpeg") else None
        if suffix == ".png":
            from srvol.images import read_png

            arr = read_png(path, srgb=False)
        elif suffix in (".tif", ".tiff"):
            arr = _tiff_pixels(path)
    except SrvolError as e:
        raise SrvolError(f"{path}: not a readable photo ({e})") from None
    except Exception as e:
        raise SrvolError(f"{path}: not a readable photo ({_why(e)})") from None
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.shape[2] in (1, 2):
        arr = np.repeat(arr[..., :1], 3, axis=2)
    return np.ascontiguousarray(apply_orientation(arr[..., :3], orientation), dtype=np.float32)


def _pil_pixels(im) -> np.ndarray:
    if im.mode not in ("RGB", "L"):
        im = im.convert("RGB")
    return np.asarray(im, dtype=np.float32) / 255.0


def _tiff_pixels(path: Path) -> np.ndarray:
    import tifffile

    arr = tifffile.imread(path)
    if arr.ndim == 3 and arr.shape[0] in (1, 3, 4) and arr.shape[2] not in (1, 3, 4):
        arr = np.moveaxis(arr, 0, -1)  # planar configuration
    scale = {np.dtype(np.uint16): 65535.0, np.dtype(np.uint8): 255.0}.get(arr.dtype, 1.0)
    return arr.astype(np.float32) / scale


def apply_orientation(arr: np.ndarray, orientation: int) -> np.ndarray:
    """``arr`` (H, W, ...) as displayed under EXIF/TIFF ``orientation`` 1..8 (6: turn clockwise)."""
    ops = {1: lambda a: a, 2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: np.swapaxes(a, 0, 1), 6: lambda a: np.rot90(a, -1),
           7: lambda a: np.swapaxes(a[::-1, ::-1], 0, 1), 8: lambda a: np.rot90(a, 1)}
    return ops.get(orientation, ops[1])(arr)


def read_photo_linear(path: Path) -> np.ndarray:
    """(H, W, 3) float32 linear RGB of a photo, upright (sRGB decoded)."""
    return srgb_to_linear(read_photo_srgb(path))
