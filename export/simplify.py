"""Decimation to a face budget, and the automatic choice of that budget.

``decimate`` uses fast_simplification (quadric, seconds for a million faces)
and falls back to pymeshlab's quadric edge collapse when it is unavailable.

``choose_face_count`` ("--faces auto") tries budgets from small to large and
keeps the smallest whose error stays under a tolerance tied to the HR pixel
footprint ``p`` (RunInfo.hr_pixel_size):

* distance: the 95th percentile of the first-order distance ``|d| / |grad d|``
  of the field at points sampled on the decimated mesh, <= ``distance_px * p``;
* normals: the mean angle between face normals and the field's normals at the
  same points, <= the full-resolution mesh's own mean angle + ``normal_deg``
  (None: no normal criterion -- when a normal map restores the field's normals).

The reference is the field whose zero level the full-resolution mesh samples;
measuring against it costs a few thousand field queries per candidate instead
of a point-to-mesh search over a million faces.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from srvol.export.extract import compact, face_normals, sdf_gradient
from srvol.export.types import Mesh
from srvol.types import SdfFn


@dataclass(frozen=True)
class SimplifyOptions:
    """faces: a face budget, or None for auto; hr_pixel_size: scene units per HR pixel;
    distance_px / normal_deg: the auto tolerances; min_faces / max_faces: the auto search range
    (max bounds UV-unwrap time: xatlas takes ~3 s at 20k faces, ~60 s at 100k); samples: points
    per error estimate."""

    faces: int | None = None
    hr_pixel_size: float = 0.005
    distance_px: float = 0.5
    normal_deg: float | None = 2.0
    min_faces: int = 2000
    max_faces: int = 30000
    samples: int = 20000


@dataclass(frozen=True)
class MeshError:
    """distance_p95 in scene units; normal_mean_deg in degrees."""

    distance_p95: float
    normal_mean_deg: float


@dataclass(frozen=True)
class SimplifyResult:
    mesh: Mesh
    faces: int
    error: MeshError
    reference_error: MeshError
    within_tolerance: bool
    tried: tuple[int, ...]


def decimate(mesh: Mesh, faces: int) -> Mesh:
    """Quadric decimation to about ``faces`` faces (no-op when the mesh is already smaller)."""
    n = len(mesh.faces)
    if faces >= n:
        return Mesh(vertices=mesh.vertices, faces=mesh.faces)
    try:
        import fast_simplification

        v, f = fast_simplification.simplify(mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32),
                                            target_reduction=1.0 - faces / n)
    except ImportError:
        v, f = _decimate_pymeshlab(mesh, faces)
    v, f = compact(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64))
    return Mesh(vertices=v.astype(np.float32), faces=f)


def _decimate_pymeshlab(mesh: Mesh, faces: int) -> tuple[np.ndarray, np.ndarray]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(mesh.vertices.astype(np.float64), mesh.faces.astype(np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=faces, preservenormal=True)
    m = ms.current_mesh()
    return m.vertex_matrix(), m.face_matrix()


def sample_surface(mesh: Mesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n points uniformly by area on the mesh -> (points (n, 3), face index (n,))."""
    rng = np.random.default_rng(seed)
    v = mesh.vertices.astype(np.float64)
    a, b, c = v[mesh.faces[:, 0]], v[mesh.faces[:, 1]], v[mesh.faces[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    fi = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    p = (1 - s)[:, None] * a[fi] + (s * (1 - r2))[:, None] * b[fi] + (s * r2)[:, None] * c[fi]
    return p, fi


def mesh_error(sdf_fn: SdfFn, mesh: Mesh, samples: int = 20000) -> MeshError:
    """Distance and normal error of ``mesh`` against the field (see module docstring)."""
    p, fi = sample_surface(mesh, samples)
    d, g = sdf_gradient(sdf_fn, p)
    gn = np.linalg.norm(g, axis=1).clip(1e-12)
    dist = np.abs(d) / gn
    fn = face_normals(mesh.vertices, mesh.faces)[fi]
    cos = np.clip((fn * g).sum(1) / gn, -1.0, 1.0)
    return MeshError(distance_p95=float(np.percentile(dist, 95)),
                     normal_mean_deg=float(np.degrees(np.arccos(cos)).mean()))


def _ok(err: MeshError, ref: MeshError, opts: SimplifyOptions) -> bool:
    return (err.distance_p95 <= opts.distance_px * opts.hr_pixel_size
            and (opts.normal_deg is None or err.normal_mean_deg <= ref.normal_mean_deg + opts.normal_deg))


def simplify(sdf_fn: SdfFn, mesh: Mesh, opts: SimplifyOptions = SimplifyOptions()) -> SimplifyResult:
    """Decimate to ``opts.faces``, or (None) to the smallest budget meeting the tolerance."""
    ref = mesh_error(sdf_fn, mesh, opts.samples)
    if opts.faces is not None:
        out = decimate(mesh, opts.faces)
        err = mesh_error(sdf_fn, out, opts.samples)
        return SimplifyResult(out, len(out.faces), err, ref, _ok(err, ref, opts), (opts.faces,))
    budgets = []
    f = opts.min_faces
    while f < min(opts.max_faces, len(mesh.faces)):
        budgets.append(f)
        f = int(f * 1.5)
    budgets.append(min(opts.max_faces, len(mesh.faces)))
    tried = []
    coarse = decimate(mesh, budgets[-1])  # candidates decimate this (fast) rather than the full mesh
    for f in budgets:
        out = decimate(coarse, f)
        err = mesh_error(sdf_fn, out, opts.samples)
        tried.append(f)
        if _ok(err, ref, opts):
            return SimplifyResult(out, len(out.faces), err, ref, True, tuple(tried))
    return SimplifyResult(out, len(out.faces), err, ref, False, tuple(tried))
