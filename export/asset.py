"""The asset folder contract shared by ``srvol export`` (writer) and ``srvol relight`` (reader).

::

    ASSET/
      asset.json          {"format": "srvol-asset/1", "mesh": "raw/mesh.npz",
                           "textures": {"albedo": "raw/albedo.exr", "specular": "raw/specular.exr",
                                        "alpha": "raw/alpha.exr", "roughness": "raw/roughness.exr",
                                        ["normal": "raw/normal.exr"]},
                           "files": {"usd": "model.usda", ...}, "stats": {...}}
      raw/mesh.npz        vertices, faces, uv[, normals]  (see Mesh)
      raw/*.exr           lossless linear float textures (alpha AND roughness = sqrt(alpha))
      model.usda, model.glb, model.obj, ...   the formats asked for

``load_asset`` is the one reader.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from srvol.errors import SrvolError
from srvol.images import read_exr
from srvol.export.types import Asset, Mesh, TextureSet

ASSET_FORMAT = "srvol-asset/1"


def is_asset_dir(path: Path) -> bool:
    return (Path(path) / "asset.json").is_file()


def load_asset(path: str | Path) -> Asset:
    root = Path(path)
    manifest = root / "asset.json"
    if not manifest.is_file():
        raise SrvolError(f"{root}: not an srvol asset folder (no asset.json)")
    try:
        meta = json.loads(manifest.read_text())
    except json.JSONDecodeError as e:
        raise SrvolError(f"{manifest}: malformed JSON ({e.msg})") from None
    if meta.get("format") != ASSET_FORMAT:
        raise SrvolError(f"{manifest}: unknown format {meta.get('format')!r}")
    mesh_path = root / meta["mesh"]
    try:
        with np.load(mesh_path) as z:
            mesh = Mesh(vertices=z["vertices"].astype(np.float32), faces=z["faces"].astype(np.int32),
                        uv=z["uv"].astype(np.float32) if "uv" in z else None,
                        normals=z["normals"].astype(np.float32) if "normals" in z else None)
    except (OSError, KeyError, ValueError) as e:
        raise SrvolError(f"{mesh_path}: unreadable mesh ({e})") from None
    tex = meta["textures"]
    textures = TextureSet(
        albedo=read_exr(root / tex["albedo"])[..., :3],
        specular=read_exr(root / tex["specular"])[..., :1],
        alpha=read_exr(root / tex["alpha"])[..., :1],
        normal=read_exr(root / tex["normal"]) if "normal" in tex else None,
    )
    return Asset(mesh=mesh, textures=textures)
