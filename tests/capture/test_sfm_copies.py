"""The SfM copies of photos bigger than SIFT needs: twice the working resolution, shrunk before the
stretch, and SIFT without its doubled first octave on them."""
from __future__ import annotations

import numpy as np
from PIL import Image

from srvol.capture.resolution import choose_resolution
from srvol.capture.sfm import SFM_MAX_SIDE, sfm_copy_side, sfm_copy_size, write_sfm_image


def test_a_12_mp_photo_gets_a_copy_twice_its_working_size():
    res = choose_resolution((4032, 3024), None)  # f = 11: 366x274
    side = sfm_copy_side(max(res.size))
    assert side == 732
    assert sfm_copy_size(4032, 3024, side)[:2] == (732, 549)


def test_a_photo_at_its_working_size_is_copied_at_its_own_size():
    res = choose_resolution((320, 240), None)
    assert sfm_copy_size(320, 240, sfm_copy_side(max(res.size))) == (320, 240, 1.0)
    assert sfm_copy_side(5000) == SFM_MAX_SIDE


def test_the_shrunk_copy_is_the_area_mean_then_stretched(tmp_path):
    # left half 0.2, right half 0.6 at 400x300: shrunk x4 the halves stay flat and become the
    # stretch's two ends (CLAHE keeps a two-level image two-level)
    srgb = np.full((300, 400, 3), 0.2, np.float32)
    srgb[:, 200:] = 0.6
    write_sfm_image(tmp_path / "c.jpg", srgb, max_side=100)
    with Image.open(tmp_path / "c.jpg") as im:
        assert im.size == (100, 75)
        copy = np.asarray(im.convert("L"), np.float32)
    assert copy[:, :45].mean() < copy[:, 55:].mean() - 100
