"""Wavefront OBJ + MTL writer.

``model.obj`` names ``mtllib model.mtl`` and ``usemtl srvol_material``; faces are
``v/vt/vn`` (1-based), vt is (u, v) with v up (OBJ's convention, as in Mesh).
The MTL references PNGs relative to itself: ``map_Kd`` (sRGB albedo), the PBR
extension keys ``Pr``/``map_Pr`` (perceptual roughness r, 16-bit linear) and
``Ks``/``map_Ks`` (F0, 16-bit linear), ``Pm 0`` (dielectric), and ``norm`` for
the optional tangent-space normal map.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from srvol.export.textures import TextureFiles
from srvol.export.types import Mesh


def mtl_text(files: TextureFiles) -> str:
    lines = ["# srvol export", "newmtl srvol_material", "Ka 0 0 0", "Kd 1 1 1", f"map_Kd {files.albedo_png}",
             "Ks 1 1 1", f"map_Ks {files.specular_png}", "Ns 100", "Pr 1", f"map_Pr {files.roughness_png}",
             "Pm 0", "d 1", "illum 2"]
    if files.normal_png is not None:
        lines.append(f"norm {files.normal_png}")
    return "\n".join(lines) + "\n"


def write_obj(path: Path, mesh: Mesh, files: TextureFiles) -> None:
    """Write ``path`` (.obj) and the .mtl beside it."""
    mtl = path.with_suffix(".mtl")
    mtl.write_text(mtl_text(files))
    f = mesh.faces.astype(np.int64) + 1
    parts = [f"# srvol export\nmtllib {mtl.name}\no srvol_asset\n",
             "".join(f"v {x:.7g} {y:.7g} {z:.7g}\n" for x, y, z in mesh.vertices.tolist()),
             "".join(f"vt {u:.7g} {v:.7g}\n" for u, v in mesh.uv.tolist())]
    if mesh.normals is not None:
        parts.append("".join(f"vn {x:.6g} {y:.6g} {z:.6g}\n" for x, y, z in mesh.normals.tolist()))
        parts.append("usemtl srvol_material\n")
        parts.append("".join(f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}\n" for a, b, c in f.tolist()))
    else:
        parts.append("usemtl srvol_material\n")
        parts.append("".join(f"f {a}/{a} {b}/{b} {c}/{c}\n" for a, b, c in f.tolist()))
    path.write_text("".join(parts))
