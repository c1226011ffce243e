"""The scene format of DESIGN.md section 4: round trip, IDR/IRON layout, and one-line errors."""
from __future__ import annotations

import json
import math
import shutil
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from srvol.data import camera_to_json, load_scene, read_cameras_json
from srvol.errors import SceneError, SrvolError
from srvol.images import linear_to_srgb, write_png

from .conftest import TINY_H, TINY_INFO, TINY_STEMS, TINY_W, tiny_camera, tiny_views, write_tiny_scene


# ----------------------------------------------------------------------------- round trip

def test_round_trip_keeps_cameras_images_masks_and_info(tiny_scene):
    scene = load_scene(tiny_scene)
    assert list(scene.views) == list(TINY_STEMS)
    assert scene.train == ["000", "001"] and scene.test == ["002"]
    assert scene.info == TINY_INFO
    assert scene.has_masks
    for k, want in enumerate(tiny_views()):
        got = scene.views[want.name]
        torch.testing.assert_close(got.camera.K, want.camera.K)
        torch.testing.assert_close(got.camera.W2C, want.camera.W2C)
        assert (got.camera.width, got.camera.height) == (TINY_W, TINY_H)
        np.testing.assert_array_equal(got.image, want.image)  # float32 EXR is lossless
        np.testing.assert_array_equal(got.mask, want.mask)
    # the HR camera defaults to the LR one scaled by sr_factor
    hr = scene.hr_camera("002")
    assert (hr.width, hr.height) == (2 * TINY_W, 2 * TINY_H)
    assert hr.K[0, 0].item() == 20.0


def test_read_cameras_json_is_the_scene_readers_camera_reader(tiny_scene, tmp_path):
    cams = read_cameras_json(tiny_scene / "cameras.json")
    assert list(cams) == ["000.exr", "001.exr", "002.exr"]  # keyed as in the file, in key order
    scene = load_scene(tiny_scene, load_images=False)
    for key, cam in cams.items():
        torch.testing.assert_close(cam.W2C, scene.views[Path(key).stem].camera.W2C)
    # any cameras.json-style file: keys need not be image names; 3x3 K is accepted too
    entry = camera_to_json(tiny_camera(1))
    entry["K"] = np.asarray(entry["K"]).reshape(4, 4)[:3, :3].reshape(-1).tolist()
    (tmp_path / "b.json").write_text(json.dumps({"zz": camera_to_json(tiny_camera(0)), "aa": entry}))
    cams = read_cameras_json(tmp_path / "b.json")
    assert list(cams) == ["aa", "zz"] and cams["aa"].K.shape == (3, 3)
    with pytest.raises(SceneError, match="no such camera file"):
        read_cameras_json(tmp_path / "none.json")
    (tmp_path / "empty.json").write_text("{}")
    with pytest.raises(SceneError, match="empty.json: expected a non-empty object of cameras"):
        read_cameras_json(tmp_path / "empty.json")


def test_defaults_without_scene_json(tiny_scene):
    (tiny_scene / "scene.json").unlink()
    scene = load_scene(tiny_scene)
    assert scene.info.psf_sigma_lr_px == 0.375 and scene.info.sr_factor == 4
    assert scene.info.light_intensity is None
    assert scene.train == list(TINY_STEMS) and scene.test == []


def test_without_masks_the_scene_has_none(tiny_scene):
    shutil.rmtree(tiny_scene / "mask")
    scene = load_scene(tiny_scene)
    assert not scene.has_masks and scene.views["000"].mask is None


def test_idr_iron_layout_with_srgb_pngs_loads(tmp_path):
    # IRON's cam_dict_norm.json keyed by image file name, sRGB 8-bit PNGs, masks as RGB PNGs
    root = tmp_path / "iron"
    views = tiny_views()
    cams = {f"{v.name}.png": camera_to_json(v.camera) for v in views}
    (root / "image").mkdir(parents=True)
    (root / "cam_dict_norm.json").write_text(json.dumps(cams))
    for v in views:
        write_png(root / "image" / f"{v.name}.png", v.image, srgb=True)
        write_png(root / "mask" / f"{v.name}.png", np.repeat(v.mask[..., None], 3, -1).astype(np.float32), srgb=False)
    scene = load_scene(root)
    assert scene.train == list(TINY_STEMS)
    for v in views:
        got = scene.views[v.name]
        # 8-bit sRGB: the decoded linear value is within half a code value of the truth
        enc = np.round(linear_to_srgb(v.image) * 255) / 255
        want = np.where(enc <= 0.04045, enc / 12.92, ((enc + 0.055) / 1.055) ** 2.4)
        np.testing.assert_allclose(got.image, want, atol=1e-6)
        np.testing.assert_array_equal(got.mask, v.mask)


def png16(path: Path, pixels: np.ndarray) -> None:
    """Write a 16-bit PNG (grey, RGB or RGBA by the last axis) with the zlib module alone.

    Row j uses filter type j % 5 (None, Sub, Up, Average, Paeth), so a reader must undo all five.
    """
    H, W, C = pixels.shape
    colour_type = {1: 0, 3: 2, 4: 6}[C]
    rows = pixels.astype(">u2").view(np.uint8).reshape(H, W * C * 2).astype(np.int64)
    bpp = 2 * C
    filtered = []
    for j in range(H):
        x = rows[j]
        up = rows[j - 1] if j else np.zeros_like(x)
        left = np.concatenate([np.zeros(bpp, np.int64), x[:-bpp]])
        up_left = np.concatenate([np.zeros(bpp, np.int64), up[:-bpp]])
        p = left + up - up_left
        pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - up_left)
        paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, up_left))
        pred = [np.zeros_like(x), left, up, (left + up) // 2, paeth][j % 5]
        filtered.append(bytes([j % 5]) + ((x - pred) % 256).astype(np.uint8).tobytes())

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 16, colour_type, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"".join(filtered))) + chunk(b"IEND", b""))


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_16bit_png_keeps_16_bits(tiny_scene, channels):
    # code values spread over 0..65535 with a dark corner (an 8-bit reading is off by up to 1/510)
    (tiny_scene / "image" / "000.exr").unlink()
    codes = (np.arange(TINY_H * TINY_W * channels).reshape(TINY_H, TINY_W, channels) * 7919 % 65536).astype(np.uint16)
    codes[0, 0] = 1
    png16(tiny_scene / "image" / "000.png", codes)
    scene = load_scene(tiny_scene)  # color_space "linear" in scene.json: stored as is
    want = codes.astype(np.float32) / 65535.0
    want = np.repeat(want, 3, -1) if channels == 1 else want[..., :3]
    np.testing.assert_allclose(scene.views["000"].image, want, rtol=0, atol=1e-7)


# ----------------------------------------------------------------------------- one-line errors

def expect_scene_error(root: Path, *words: str) -> str:
    with pytest.raises(SceneError) as info:
        load_scene(root)
    msg = str(info.value)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, f"{w!r} not in {msg!r}"
    return msg


def edit_camera(root: Path, fname: str, key: str, value) -> None:
    path = root / "cameras.json"
    cams = json.loads(path.read_text())
    cams[fname][key] = value
    path.write_text(json.dumps(cams))


def test_missing_image(tiny_scene):
    (tiny_scene / "image" / "001.exr").unlink()
    expect_scene_error(tiny_scene, "001.exr", "missing image")


def test_image_size_differs_from_img_size(tiny_scene):
    edit_camera(tiny_scene, "000.exr", "img_size", [TINY_W + 1, TINY_H])
    expect_scene_error(tiny_scene, str(tiny_scene / "image" / "000.exr"), "differs from img_size")


def test_nan_in_w2c(tiny_scene):
    w2c = camera_to_json(tiny_camera(1))["W2C"]
    w2c[5] = math.nan
    edit_camera(tiny_scene, "001.exr", "W2C", w2c)
    expect_scene_error(tiny_scene, "cameras.json", "'001.exr'", "non-finite")


def test_singular_k(tiny_scene):
    K = camera_to_json(tiny_camera(0))["K"]
    K[0] = 0.0  # fx = 0
    edit_camera(tiny_scene, "000.exr", "K", K)
    expect_scene_error(tiny_scene, "cameras.json", "'000.exr'", "K is singular")


def test_singular_w2c(tiny_scene):
    w2c = np.asarray(camera_to_json(tiny_camera(2))["W2C"]).reshape(4, 4)
    w2c[2, :3] = w2c[1, :3]  # two equal rows: rank 2
    edit_camera(tiny_scene, "002.exr", "W2C", w2c.reshape(-1).tolist())
    expect_scene_error(tiny_scene, "cameras.json", "'002.exr'", "W2C is not a rigid transform")


def test_empty_mask(tiny_scene):
    write_png(tiny_scene / "mask" / "002.png", np.zeros((TINY_H, TINY_W), np.float32), srgb=False)
    expect_scene_error(tiny_scene, str(tiny_scene / "mask" / "002.png"), "empty mask")


def test_malformed_cameras_json(tiny_scene):
    (tiny_scene / "cameras.json").write_text('{"000.exr": {"K": [1, 2,')
    expect_scene_error(tiny_scene, str(tiny_scene / "cameras.json"), "malformed JSON")


def test_malformed_scene_json(tiny_scene):
    (tiny_scene / "scene.json").write_text("{'format': 1}")
    expect_scene_error(tiny_scene, str(tiny_scene / "scene.json"), "malformed JSON")


def test_unknown_colour_space(tiny_scene):
    info = json.loads((tiny_scene / "scene.json").read_text())
    info["color_space"] = "acescg"
    (tiny_scene / "scene.json").write_text(json.dumps(info))
    expect_scene_error(tiny_scene, "scene.json", "unknown color_space 'acescg'")


def test_split_naming_a_missing_view(tiny_scene):
    info = json.loads((tiny_scene / "scene.json").read_text())
    info["split"]["test"] = ["002", "007"]
    (tiny_scene / "scene.json").write_text(json.dumps(info))
    expect_scene_error(tiny_scene, "scene.json", "'007'")


def test_missing_mask_when_masks_exist(tiny_scene):
    (tiny_scene / "mask" / "001.png").unlink()
    expect_scene_error(tiny_scene, "001.png", "missing mask")


def test_a_camera_name_with_a_newline_stays_a_one_line_error(tiny_scene):
    """A name read from cameras.json is written with Python escapes (found by the property test below)."""
    path = tiny_scene / "cameras.json"
    cams = json.loads(path.read_text())
    cams["bad\nname"] = None
    path.write_text(json.dumps(cams))
    expect_scene_error(tiny_scene, "cameras.json", "bad\\nname")


def test_image_of_random_bytes(tiny_scene):
    (tiny_scene / "image" / "000.exr").write_bytes(b"not an exr at all")
    expect_scene_error(tiny_scene, "000.exr")


# ----------------------------------------------------------------------------- property tests

@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    return write_tiny_scene(tmp_path_factory.mktemp("pristine") / "scene")


def load_corrupted(pristine: Path, edit) -> None:
    """Copy the pristine scene, apply ``edit(root)`` and load: only SrvolError may escape."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "scene"
        shutil.copytree(pristine, root)
        edit(root)
        try:
            load_scene(root)
        except SrvolError as e:
            assert "\n" not in str(e), str(e)


json_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**30, 10**30),
                         st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
json_values = st.recursive(json_scalars, lambda inner: st.one_of(st.lists(inner, max_size=20),
                                                                 st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                           max_leaves=40)
numbers = st.one_of(st.sampled_from([math.nan, math.inf, -math.inf, 0, -1, 1e300, 2.5, 8, 6]),
                    st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30))
camera_entries = st.fixed_dictionaries({}, optional={
    "K": st.one_of(st.lists(numbers, min_size=0, max_size=17), json_values),
    "W2C": st.one_of(st.lists(numbers, min_size=0, max_size=17), json_values),
    "img_size": st.one_of(st.lists(numbers, min_size=2, max_size=2), st.lists(numbers, max_size=3), json_values),
})
PROPERTY = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@PROPERTY
@given(content=st.one_of(json_values, st.dictionaries(st.sampled_from(["000.exr", "001.exr", "002.exr", "x.png", "", "../scene.json", "sub/002.exr", "a\x00.png"]),
                                                       st.one_of(camera_entries, json_values), max_size=3)))
def test_corrupted_cameras_json_gives_only_scene_errors(pristine, content):
    load_corrupted(pristine, lambda root: (root / "cameras.json").write_text(json.dumps(content)))


@PROPERTY
@given(fname=st.sampled_from(["000.exr", "001.exr"]), entry=camera_entries)
@example(fname="000.exr", entry={"img_size": [math.inf, 6]})  # int(inf) raised OverflowError once
@example(fname="000.exr", entry={"img_size": [8.5, 6]})
@example(fname="001.exr", entry={"K": [1e308] * 9})
def test_corrupted_camera_entry_gives_only_scene_errors(pristine, fname, entry):
    def edit(root: Path) -> None:
        cams = json.loads((root / "cameras.json").read_text())
        cams[fname] = {**cams[fname], **entry}
        (root / "cameras.json").write_text(json.dumps(cams))

    load_corrupted(pristine, edit)


@PROPERTY
@given(content=st.one_of(json_values, st.fixed_dictionaries({}, optional={
    "format": json_values, "color_space": json_values, "light": json_values, "psf": json_values,
    "sr_factor": st.one_of(numbers, json_values), "split": json_values})))
@example(content={"sr_factor": math.inf})  # int(inf) raised OverflowError once
@example(content={"psf": {"sigma_lr_px": math.nan}})
@example(content={"light": {"intensity": [1, 2]}})
def test_corrupted_scene_json_gives_only_scene_errors(pristine, content):
    load_corrupted(pristine, lambda root: (root / "scene.json").write_text(json.dumps(content)))


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"


@PROPERTY
@given(target=st.sampled_from(["image/000.exr", "mask/001.png", "image/002.png"]),
       prefix=st.sampled_from([b"", PNG_MAGIC, EXR_MAGIC]), data=st.binary(max_size=200))
def test_random_bytes_as_image_files_give_only_scene_errors(pristine, target, prefix, data):
    def edit(root: Path) -> None:
        if target == "image/002.png":
            (root / "image" / "002.exr").unlink()
        (root / target).write_bytes(prefix + data)

    load_corrupted(pristine, edit)
