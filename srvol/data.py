"""The scene (dataset) format of DESIGN.md section 4: reader, validator and writer.

::

    SCENE/
      cameras.json   {"<image file name>": {"K": [16], "W2C": [16], "img_size": [W, H]}}
                     (or cam_dict_norm.json: IDR/IRON layout)
      image/<stem>.exr|png      LR inputs
      mask/<stem>.png           optional, foreground > 0.5
      scene.json                optional metadata (see SceneInfo)
      gt/                       optional ground truth (see GroundTruth)

Every problem found while reading raises :class:`SceneError` with one line that
names the file and the problem.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from srvol.errors import SceneError, SrvolError
from srvol.atomic import atomic_write_text
from srvol.images import read_exr, read_image, write_exr, write_png
from srvol.psf import DEFAULT_SIGMA_LR_PX, GaussianPSF
from srvol.types import Camera, PointLight

SCENE_FORMAT = "srvol-scene/1"
COLOR_SPACES = ("linear", "srgb")


@dataclass(frozen=True)
class SceneInfo:
    """scene.json, with its defaults applied.

    color_space:     "linear" | "srgb" | None (None: by file type, sRGB for PNG, linear for EXR).
    light_intensity: co-located light's radiant intensity (r, g, b), or None = learn it.
    psf_sigma_lr_px: Gaussian PSF standard deviation in LR pixels.
    sr_factor:       HR / LR resolution ratio.
    train, test:     view stems; default all views are train, none test.
    """

    color_space: str | None = None
    light_intensity: tuple[float, float, float] | None = None
    psf_sigma_lr_px: float = DEFAULT_SIGMA_LR_PX
    sr_factor: int = 4
    train: tuple[str, ...] = ()
    test: tuple[str, ...] = ()

    @property
    def psf(self) -> GaussianPSF:
        return GaussianPSF(self.psf_sigma_lr_px, self.sr_factor)

    def to_json(self) -> dict:
        d: dict = {"format": SCENE_FORMAT}
        if self.color_space is not None:
            d["color_space"] = self.color_space
        d["light"] = {"type": "colocated",
                      "intensity": list(self.light_intensity) if self.light_intensity else None}
        d["psf"] = {"type": "gaussian", "sigma_lr_px": self.psf_sigma_lr_px}
        d["sr_factor"] = self.sr_factor
        d["split"] = {"train": list(self.train), "test": list(self.test)}
        return d


@dataclass(frozen=True)
class View:
    """One LR input: name (image stem), camera at LR, linear image (H, W, 3), mask (H, W) bool or None."""

    name: str
    camera: Camera
    image: np.ndarray
    mask: np.ndarray | None

    def light(self, intensity: Sequence[float]) -> PointLight:
        return PointLight.at_camera(self.camera, intensity)


@dataclass(frozen=True)
class RelitSpec:
    """One GT image under a non-co-located light (gt/relit.json)."""

    name: str
    camera: str
    light: PointLight


@dataclass
class GroundTruth:
    """Paths and loaders for a synthetic scene's gt/ folder; each part optional."""

    root: Path

    def exists(self) -> bool:
        return self.root.is_dir()

    def hr_cameras(self) -> dict[str, Camera]:
        path = self.root / "hr_cameras.json"
        return read_cameras_json(path) if path.is_file() else {}

    def image(self, kind: str, stem: str) -> np.ndarray | None:
        """kind: "hr", "normal", "albedo" or "relit"."""
        path = self.root / kind / f"{stem}.exr"
        return read_exr(path) if path.is_file() else None

    def relit(self) -> list[RelitSpec]:
        path = self.root / "relit.json"
        if not path.is_file():
            return []
        raw = _read_json(path)
        if not isinstance(raw, list):
            raise SceneError(f"{path}: expected a list of relit views")
        out = []
        for i, e in enumerate(raw):
            try:
                out.append(RelitSpec(name=str(e["name"]), camera=str(e["camera"]),
                                     light=PointLight.make(_floats(e["light_pos"], 3), _floats(e["intensity"], 3))))
            except (KeyError, TypeError, ValueError) as err:
                raise SceneError(f"{path}: entry {i} is malformed ({err})") from None
        return out

    @property
    def mesh_path(self) -> Path:
        return self.root / "mesh.ply"

    def parts(self) -> list[str]:
        if not self.exists():
            return []
        names = []
        for kind in ("hr", "normal", "albedo", "relit"):
            d = self.root / kind
            if d.is_dir():
                names.append(f"{kind}({len(list(d.glob('*.exr')))})")
        if self.mesh_path.is_file():
            names.append("mesh")
        return names


@dataclass
class Scene:
    root: Path
    info: SceneInfo
    views: dict[str, View]
    train: list[str]
    test: list[str]
    gt: GroundTruth = field(repr=False)

    @property
    def has_masks(self) -> bool:
        return all(v.mask is not None for v in self.views.values())

    def train_views(self) -> list[View]:
        return [self.views[s] for s in self.train]

    def test_views(self) -> list[View]:
        return [self.views[s] for s in self.test]

    def hr_camera(self, stem: str) -> Camera:
        """The HR camera of a view: gt/hr_cameras.json if present, else the LR camera scaled."""
        cams = self.gt.hr_cameras()
        return cams[stem] if stem in cams else self.views[stem].camera.scaled(self.info.sr_factor)


# ----------------------------------------------------------------------------- reading

def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise SceneError(f"{path}: malformed JSON (line {e.lineno}: {e.msg})") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot read ({e.strerror})") from None


def _floats(value, n: int | None = None) -> list[float]:
    vals = [float(v) for v in value]
    if n is not None and len(vals) != n:
        raise ValueError(f"expected {n} numbers, got {len(vals)}")
    return vals


MAX_IMAGE_SIDE = 1 << 16


def _image_size(value) -> tuple[int, int]:
    """img_size [W, H]: two whole numbers (JSON may write them as 640.0)."""
    if isinstance(value, (str, bytes, dict)) or len(value) != 2:
        raise ValueError(f"img_size must be [W, H], is {value!r}")
    out = []
    for x in value:
        f = float(x)
        if not (math.isfinite(f) and f == int(f) and abs(f) <= MAX_IMAGE_SIDE):
            raise ValueError(f"img_size must hold whole numbers up to {MAX_IMAGE_SIDE}, is {value!r}")
        out.append(int(f))
    return out[0], out[1]


def _parse_camera(path: Path, key: str, entry) -> Camera:
    where = f"{path}: camera '{key}'"
    if not isinstance(entry, dict):
        raise SceneError(f"{where} is not an object")
    try:
        K = np.asarray(_floats(entry["K"]), dtype=np.float64)
        W2C = np.asarray(_floats(entry["W2C"]), dtype=np.float64)
        W, H = _image_size(entry["img_size"])
    except KeyError as e:
        raise SceneError(f"{where} lacks {e.args[0]}") from None
    except (TypeError, ValueError, IndexError, OverflowError) as e:
        raise SceneError(f"{where} has a malformed value ({e})") from None
    if K.size == 16:
        K = K.reshape(4, 4)[:3, :3]
    elif K.size == 9:
        K = K.reshape(3, 3)
    else:
        raise SceneError(f"{where}: K must have 9 or 16 numbers, has {K.size}")
    if W2C.size != 16:
        raise SceneError(f"{where}: W2C must have 16 numbers, has {W2C.size}")
    W2C = W2C.reshape(4, 4)
    if not (np.isfinite(K).all() and np.isfinite(W2C).all()):
        raise SceneError(f"{where}: non-finite value in K or W2C")
    if W <= 0 or H <= 0:
        raise SceneError(f"{where}: img_size must be positive, is {[W, H]}")
    if abs(np.linalg.det(K)) < 1e-9 or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise SceneError(f"{where}: K is singular or has non-positive focal length")
    R = W2C[:3, :3]
    if abs(abs(np.linalg.det(R)) - 1.0) > 1e-3 or np.abs(R @ R.T - np.eye(3)).max() > 1e-3 \
            or np.abs(W2C[3] - [0, 0, 0, 1]).max() > 1e-6:
        raise SceneError(f"{where}: W2C is not a rigid transform (singular or non-orthonormal rotation)")
    return Camera(K=torch.from_numpy(K), W2C=torch.from_numpy(W2C), width=W, height=H)


def read_cameras_json(path: str | os.PathLike) -> dict[str, Camera]:
    """The cameras of a cameras.json-style file (IDR/IRON cam_dict), keyed as in the file, in key order.

    ``{"<key>": {"K": [16 or 9 floats], "W2C": [16 floats], "img_size": [W, H]}, ...}``: a scene's
    cameras.json (keys: image file names), gt/hr_cameras.json (keys: view stems), or a camera file
    given to ``srvol relight --camera``. Raises :class:`SceneError` naming the file and the problem:
    missing file, malformed JSON, not a non-empty object, or a malformed camera.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: no such camera file")
    raw = _read_json(path)
    if not isinstance(raw, dict) or not raw:
        raise SceneError(f"{path}: expected a non-empty object of cameras")
    return {key: _parse_camera(path, key, raw[key]) for key in sorted(raw)}


def _parse_info(path: Path) -> SceneInfo:
    if not path.is_file():
        return SceneInfo()
    raw = _read_json(path)
    if not isinstance(raw, dict):
        raise SceneError(f"{path}: expected a JSON object")
    fmt = raw.get("format", SCENE_FORMAT)
    if fmt != SCENE_FORMAT:
        raise SceneError(f"{path}: unknown format {fmt!r} (expected {SCENE_FORMAT!r})")
    cs = raw.get("color_space")
    if cs is not None and cs not in COLOR_SPACES:
        raise SceneError(f"{path}: unknown color_space {cs!r} (expected one of {', '.join(COLOR_SPACES)})")
    try:
        light = raw.get("light") or {}
        if light.get("type", "colocated") != "colocated":
            raise SceneError(f"{path}: light type {light.get('type')!r} unsupported (only 'colocated')")
        inten = light.get("intensity")
        intensity = None
        if inten is not None:
            vals = _floats(inten) if isinstance(inten, list) else [float(inten)] * 3
            if len(vals) != 3 or not all(math.isfinite(v) and v > 0 for v in vals):
                raise SceneError(f"{path}: light intensity must be 3 positive numbers or null")
            intensity = tuple(vals)
        psf = raw.get("psf") or {}
        if psf.get("type", "gaussian") != "gaussian":
            raise SceneError(f"{path}: psf type {psf.get('type')!r} unsupported (only 'gaussian')")
        sigma = float(psf.get("sigma_lr_px", DEFAULT_SIGMA_LR_PX))
        sr = int(raw.get("sr_factor", 4))
        split = raw.get("split") or {}
        train = tuple(str(s) for s in split.get("train", []))
        test = tuple(str(s) for s in split.get("test", []))
    except SceneError:
        raise
    except (TypeError, ValueError, AttributeError, OverflowError) as e:
        raise SceneError(f"{path}: malformed value ({e})") from None
    if not (math.isfinite(sigma) and sigma >= 0):
        raise SceneError(f"{path}: psf sigma_lr_px must be a non-negative number, is {sigma}")
    if not 1 <= sr <= 64:
        raise SceneError(f"{path}: sr_factor must be in 1..64, is {sr}")
    return SceneInfo(color_space=cs, light_intensity=intensity, psf_sigma_lr_px=sigma,
                     sr_factor=sr, train=train, test=test)


def load_scene(root: str | os.PathLike, load_images: bool = True) -> Scene:
    """Read and validate a scene folder (srvol or IDR/IRON layout)."""
    root = Path(root)
    if not root.is_dir():
        raise SceneError(f"{root}: not a folder")
    cam_path = root / "cameras.json"
    if not cam_path.is_file():
        cam_path = root / "cam_dict_norm.json"
    if not cam_path.is_file():
        raise SceneError(f"{root}: no cameras.json (or cam_dict_norm.json)")
    info = _parse_info(root / "scene.json")
    cameras = read_cameras_json(cam_path)
    img_dir, mask_dir = root / "image", root / "mask"
    if not img_dir.is_dir():
        raise SceneError(f"{img_dir}: missing image folder")
    has_masks = mask_dir.is_dir()
    views: dict[str, View] = {}
    for fname, cam in cameras.items():
        stem = Path(fname).stem
        img_path = img_dir / fname
        if not img_path.is_file():
            found = sorted(img_dir.glob(f"{stem}.*"))
            if not found:
                raise SceneError(f"{img_dir / fname}: missing image for camera '{fname}'")
            img_path = found[0]
        image = _load_view_image(img_path, info, cam) if load_images else np.zeros((0, 0, 3), np.float32)
        mask = None
        if has_masks:
            mpath = mask_dir / f"{stem}.png"
            if not mpath.is_file():
                raise SceneError(f"{mpath}: missing mask for view '{stem}'")
            if load_images:
                m = read_image(mpath, srgb=False)
                if m.shape[:2] != (cam.height, cam.width):
                    raise SceneError(f"{mpath}: size {m.shape[1]}x{m.shape[0]} differs from img_size "
                                     f"{cam.width}x{cam.height}")
                mask = m[..., 0] > 0.5
                if not mask.any():
                    raise SceneError(f"{mpath}: empty mask (no foreground pixel)")
        if stem in views:
            raise SceneError(f"{cam_path}: two cameras for view '{stem}'")
        views[stem] = View(name=stem, camera=cam, image=image, mask=mask)
    for part, names in (("train", info.train), ("test", info.test)):
        for s in names:
            if s not in views:
                raise SceneError(f"{root / 'scene.json'}: split '{part}' names view '{s}' which has no camera")
    train = list(info.train) if info.train else [s for s in views if s not in info.test]
    if not train:
        raise SceneError(f"{root / 'scene.json'}: no training views")
    return Scene(root=root, info=info, views=views, train=train, test=list(info.test),
                 gt=GroundTruth(root / "gt"))


def _load_view_image(path: Path, info: SceneInfo, cam: Camera) -> np.ndarray:
    if path.suffix.lower() == ".png":
        srgb = info.color_space != "linear"
    elif path.suffix.lower() == ".exr":
        srgb = info.color_space == "srgb"
    else:
        raise SceneError(f"{path}: unsupported image type (use .exr or .png)")
    try:
        img = read_image(path, srgb=False)
    except SrvolError as e:
        raise SceneError(str(e)) from None
    if srgb:
        from srvol.images import srgb_to_linear
        img = srgb_to_linear(img)
    if img.shape[:2] != (cam.height, cam.width):
        raise SceneError(f"{path}: size {img.shape[1]}x{img.shape[0]} differs from img_size "
                         f"{cam.width}x{cam.height} in the cameras file")
    if not np.isfinite(img).all():
        raise SceneError(f"{path}: image has non-finite pixels")
    if img.shape[2] <= 2:  # grey or grey + alpha
        img = np.repeat(img[..., :1], 3, axis=2)
    return np.ascontiguousarray(img[..., :3], dtype=np.float32)


# ----------------------------------------------------------------------------- writing

def camera_to_json(cam: Camera) -> dict:
    K4 = np.eye(4)
    K4[:3, :3] = cam.K.detach().cpu().double().numpy()
    return {"K": K4.reshape(-1).tolist(), "W2C": cam.W2C.detach().cpu().double().numpy().reshape(-1).tolist(),
            "img_size": [cam.width, cam.height]}


def write_scene_folder(out: Path, views: Sequence[View], info: SceneInfo) -> None:
    """Write cameras.json, image/*.exr, mask/*.png and scene.json into ``out`` (which must exist)."""
    cams = {f"{v.name}.exr": camera_to_json(v.camera) for v in views}
    for v in views:
        write_exr(out / "image" / f"{v.name}.exr", v.image)
        if v.mask is not None:
            write_png(out / "mask" / f"{v.name}.png", v.mask.astype(np.float32), srgb=False)
    atomic_write_text(out / "cameras.json", json.dumps(cams, indent=1))
    atomic_write_text(out / "scene.json", json.dumps(info.to_json(), indent=1))
