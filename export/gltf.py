"""glTF 2.0 writer (.glb and .gltf + .bin), JSON and binary written directly.

* Images are PNG only, embedded in the binary buffer: baseColor = albedo.png
  (sRGB), metallicRoughness = metallic_roughness.png (G = r, B = 0, so metallic
  is 0 whatever metallicFactor says), optional normal.png.
* Specular: ``KHR_materials_specular`` with ``specularColorTexture`` =
  specular_color.png (sRGB, F0 / f0_ref) and ``KHR_materials_ior`` with the IOR
  whose Fresnel F0 is f0_ref, so that the dielectric F0 of the spec,
  ``((ior - 1) / (ior + 1))^2 * specularColor``, equals the baked F0; F90 stays 1
  as in srvol's Schlick term.
* UVs: glTF puts t = 0 at the image top, so TEXCOORD_0 = (u, 1 - v).
"""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from srvol.export.textures import TextureFiles, ior_from_f0
from srvol.export.types import Mesh

_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_CLAMP, _LINEAR, _LINEAR_MIPMAP_LINEAR = 33071, 9729, 9987


class _Buffer:
    def __init__(self):
        self.chunks: list[bytes] = []
        self.length = 0
        self.views: list[dict] = []

    def add(self, data: bytes, target: int | None = None) -> int:
        pad = (-self.length) % 4
        if pad:
            self.chunks.append(b"\0" * pad)
            self.length += pad
        view = {"buffer": 0, "byteOffset": self.length, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.chunks.append(data)
        self.length += len(data)
        self.views.append(view)
        return len(self.views) - 1

    def bytes(self) -> bytes:
        data = b"".join(self.chunks)
        return data + b"\0" * ((-len(data)) % 4)


def build_gltf(mesh: Mesh, root: Path, files: TextureFiles, f0_ref: float) -> tuple[dict, bytes]:
    """The glTF JSON document and its binary buffer (images embedded)."""
    buf = _Buffer()
    accessors = []

    def accessor(arr: np.ndarray, kind: str, target: int, minmax: bool = False) -> int:
        comp = _UINT if arr.dtype == np.uint32 else _FLOAT
        acc = {"bufferView": buf.add(np.ascontiguousarray(arr).tobytes(), target), "componentType": comp,
               "count": int(arr.shape[0]), "type": kind}
        if minmax:
            acc["min"] = arr.min(0).astype(float).tolist()
            acc["max"] = arr.max(0).astype(float).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    attrs = {"POSITION": accessor(mesh.vertices.astype(np.float32), "VEC3", _ARRAY_BUFFER, minmax=True)}
    if mesh.normals is not None:
        n = mesh.normals.astype(np.float32)
        n = n / np.linalg.norm(n, axis=1, keepdims=True).clip(1e-12)
        attrs["NORMAL"] = accessor(n.astype(np.float32), "VEC3", _ARRAY_BUFFER)
    tc = np.stack([mesh.uv[:, 0], 1.0 - mesh.uv[:, 1]], -1).astype(np.float32)
    attrs["TEXCOORD_0"] = accessor(tc, "VEC2", _ARRAY_BUFFER)
    indices = accessor(mesh.faces.reshape(-1).astype(np.uint32), "SCALAR", _ELEMENT_ARRAY_BUFFER)

    images, textures = [], []

    def texture(rel: str) -> int:
        images.append({"bufferView": buf.add((root / rel).read_bytes()), "mimeType": "image/png"})
        textures.append({"sampler": 0, "source": len(images) - 1})
        return len(textures) - 1

    material = {
        "name": "srvol_material",
        "pbrMetallicRoughness": {
            "baseColorTexture": {"index": texture(files.albedo_png)},
            "metallicFactor": 1.0,
            "roughnessFactor": 1.0,
            "metallicRoughnessTexture": {"index": texture(files.metallic_roughness_png)},
        },
        "extensions": {
            "KHR_materials_specular": {"specularFactor": 1.0, "specularColorFactor": [1.0, 1.0, 1.0],
                                       "specularColorTexture": {"index": texture(files.specular_color_png)}},
            "KHR_materials_ior": {"ior": ior_from_f0(f0_ref)},
        },
    }
    if files.normal_png is not None:
        material["normalTexture"] = {"index": texture(files.normal_png)}
    doc = {
        "asset": {"version": "2.0", "generator": "srvol export"},
        "extensionsUsed": ["KHR_materials_specular", "KHR_materials_ior"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        # glTF is +y up; the scene frame is +z up: rotate -90 degrees about x (z -> y, y -> -z).
        "nodes": [{"name": "srvol_asset", "mesh": 0, "rotation": [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476]}],
        "meshes": [{"name": "srvol_mesh", "primitives": [{"attributes": attrs, "indices": indices,
                                                          "material": 0, "mode": 4}]}],
        "materials": [material],
        "textures": textures,
        "images": images,
        "samplers": [{"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP_LINEAR, "wrapS": _CLAMP, "wrapT": _CLAMP}],
        "accessors": accessors,
        "bufferViews": buf.views,
        "buffers": [{"byteLength": 0}],
    }
    data = buf.bytes()
    doc["buffers"][0]["byteLength"] = len(data)
    return doc, data


def write_glb(path: Path, mesh: Mesh, root: Path, files: TextureFiles, f0_ref: float) -> None:
    doc, data = build_gltf(mesh, root, files, f0_ref)
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * ((-len(js)) % 4)
    total = 12 + 8 + len(js) + 8 + len(data)
    with open(path, "wb") as fh:
        fh.write(struct.pack("<4sII", b"glTF", 2, total))
        fh.write(struct.pack("<I4s", len(js), b"JSON") + js)
        fh.write(struct.pack("<I4s", len(data), b"BIN\0") + data)


def write_gltf(path: Path, mesh: Mesh, root: Path, files: TextureFiles, f0_ref: float) -> None:
    """``path`` (.gltf) with its buffer in ``path.stem + '.bin'`` beside it."""
    doc, data = build_gltf(mesh, root, files, f0_ref)
    bin_path = path.with_suffix(".bin")
    bin_path.write_bytes(data)
    doc["buffers"][0]["uri"] = bin_path.name
    path.write_text(json.dumps(doc, indent=1))


def read_glb(path: Path) -> tuple[dict, bytes]:
    """(JSON document, binary chunk) of a .glb file."""
    raw = Path(path).read_bytes()
    magic, version, total = struct.unpack_from("<4sII", raw, 0)
    if magic != b"glTF" or version != 2 or total != len(raw):
        raise ValueError(f"{path}: not a glTF 2.0 binary")
    jlen, jtype = struct.unpack_from("<I4s", raw, 12)
    doc = json.loads(raw[20:20 + jlen])
    blen, _ = struct.unpack_from("<I4s", raw, 20 + jlen)
    return doc, raw[28 + jlen:28 + jlen + blen]
