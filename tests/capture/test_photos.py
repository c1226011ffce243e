"""Reading a capture's photos: formats, bit depths, EXIF orientation and focal, one-line errors."""
from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from srvol.capture.photos import apply_orientation, list_photos, read_photo_srgb
from srvol.cli import main
from srvol.errors import SrvolError


def pattern(h: int = 24, w: int = 32) -> np.ndarray:
    """An asymmetric image: a bright block in the top-left corner, a ramp in red."""
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = np.linspace(0, 255, w, dtype=np.uint8)[None, :]
    img[2:8, 2:6] = 255
    return img


@pytest.mark.parametrize("orientation, stored", [(1, lambda a: a), (3, lambda a: a[::-1, ::-1]),
                                                 (6, lambda a: np.rot90(a, 1)), (8, lambda a: np.rot90(a, -1))])
def test_exif_orientation_is_honoured(tmp_path, orientation, stored):
    """A camera stores the sensor's pixels and says how to turn them; srvol reads them upright."""
    up = pattern()
    path = tmp_path / "p.png"
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(np.ascontiguousarray(stored(up))).save(path, exif=exif.tobytes())
    got = read_photo_srgb(path)
    assert got.shape == up.shape
    assert np.abs(got - up / 255.0).max() < 1e-6
    (info,) = list_photos(tmp_path)
    assert info.size == (up.shape[1], up.shape[0])


def test_apply_orientation_matches_pillow_for_all_eight():
    from PIL import ImageOps

    raw = pattern()
    for o in range(1, 9):
        im = Image.fromarray(raw)
        exif = im.getexif()
        exif[0x0112] = o
        im.info["exif"] = exif.tobytes()
        want = np.asarray(ImageOps.exif_transpose(im))
        assert np.array_equal(apply_orientation(raw, o), want), o


def test_exif_35mm_focal_becomes_a_prior_in_pixels(tmp_path):
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 28
    Image.fromarray(pattern(30, 40)).save(tmp_path / "a.jpg", exif=exif.tobytes())
    Image.fromarray(pattern(30, 40)).save(tmp_path / "b.jpg")
    a, b = list_photos(tmp_path)
    assert a.focal.source == "35mm"
    assert a.focal.pixels == pytest.approx(28 / math.hypot(36, 24) * 50.0)
    assert b.focal is None


def test_16_bit_tiff_and_png_keep_their_precision(tmp_path):
    import tifffile

    rng = np.random.default_rng(0)
    img16 = (rng.random((20, 30, 3)) * 65535).astype(np.uint16)
    tifffile.imwrite(tmp_path / "a.tif", img16)
    assert np.allclose(read_photo_srgb(tmp_path / "a.tif"), img16 / 65535.0, atol=1e-7)
    grey16 = (rng.random((20, 30)) * 65535).astype(np.uint16)
    Image.fromarray(grey16).save(tmp_path / "b.png")
    got = read_photo_srgb(tmp_path / "b.png")
    assert got.shape == (20, 30, 3) and np.allclose(got[..., 1], grey16 / 65535.0, atol=1e-7)


def test_bad_folders_get_one_line_and_exit_2(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["import", str(empty), "--out", str(tmp_path / "s")]) == 2
    assert capsys.readouterr().err.strip() == f"srvol: error: {empty}: no photos (JPEG, PNG or TIFF) in the folder"

    bad = tmp_path / "bad"
    bad.mkdir()
    Image.fromarray(pattern()).save(bad / "good.jpg")
    (bad / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    (bad / "notes.txt").write_text("hello")
    assert main(["import", str(bad), "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "notes.txt" in err[0] and "skipped" in err[0]  # a notice, not an error
    assert err[-1].startswith(f"srvol: error: {bad / 'broken.jpg'}: not a readable photo")
    assert not (tmp_path / "s").exists()


def test_duplicate_stems_are_refused(tmp_path):
    Image.fromarray(pattern()).save(tmp_path / "a.jpg")
    Image.fromarray(pattern()).save(tmp_path / "a.png")
    with pytest.raises(SrvolError, match="two photos named 'a'"):
        list_photos(tmp_path)


def test_photos_needing_different_decimations_are_refused_by_name(tmp_path, capsys):
    Image.fromarray(pattern(240, 320)).save(tmp_path / "small.jpg")
    Image.fromarray(pattern(480, 640)).save(tmp_path / "large.jpg")
    assert main(["import", str(tmp_path), "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("srvol: error: photos of different sizes") and "large.jpg" in err and "small.jpg" in err
