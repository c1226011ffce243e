"""Narrow-band marching cubes on exact fields: a sphere of radius 0.5 (hand-known surface)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from srvol.errors import SrvolError
from srvol.export.extract import EMPTY_SDF_MESSAGE, ExtractOptions, extract_mesh, face_normals, weld
from export_testfields import RADIUS, sphere_sdf


def _edges_shared_twice(faces: np.ndarray) -> bool:
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


def test_sphere_radius_normals_watertight_outward():
    r = extract_mesh(sphere_sdf, ExtractOptions(resolution=64))
    v, f = r.mesh.vertices.astype(np.float64), r.mesh.faces
    h = 2.0 / 64
    # Linear interpolation of an exact SDF along a cell edge errs by at most ~h^2 / (8 R).
    assert np.abs(np.linalg.norm(v, axis=1) - RADIUS).max() < h * h / RADIUS
    # Vertex normals come from the field: equal to the radial direction.
    radial = v / np.linalg.norm(v, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip((radial * r.mesh.normals).sum(1), -1, 1))).max() < 0.05  # float32 round-off
    # Closed genus-0 surface: every edge shared by exactly two faces, V - E + F = 2.
    assert _edges_shared_twice(f)
    assert len(v) - 3 * len(f) // 2 + len(f) == 2
    # Outward winding: face normals point away from the centre.
    centres = v[f].mean(1)
    assert ((face_normals(v, f) * centres).sum(1) > 0).all()
    # Narrow band: far fewer evaluations than the 65^3 dense grid.
    assert r.sdf_evaluations < 65 ** 3


def test_inside_out_field_is_rewound():
    """-d (positive inside) has the same zero level; normals +grad(-d) point inwards, and faces follow."""
    r = extract_mesh(lambda x: -sphere_sdf(x), ExtractOptions(resolution=32))
    v, f = r.mesh.vertices.astype(np.float64), r.mesh.faces
    assert ((face_normals(v, f) * v[f].mean(1)).sum(1) < 0).all()


def test_floater_dropped():
    def two_spheres(x):
        big = x.norm(dim=-1) - 0.5
        small = (x - torch.tensor([0.8, 0.0, 0.0])).norm(dim=-1) - 0.08
        return torch.minimum(big, small)

    r = extract_mesh(two_spheres, ExtractOptions(resolution=64))
    assert r.dropped_components == 1
    assert np.linalg.norm(r.mesh.vertices, axis=1).max() < 0.51


def test_empty_sdf_one_line_error():
    with pytest.raises(SrvolError, match=EMPTY_SDF_MESSAGE):
        extract_mesh(lambda x: x.norm(dim=-1) + 0.1, ExtractOptions(resolution=32))
    with pytest.raises(SrvolError, match=EMPTY_SDF_MESSAGE):  # all inside: no zero crossing either
        extract_mesh(lambda x: x.norm(dim=-1) - 5.0, ExtractOptions(resolution=32))


def test_weld_merges_near_duplicates_and_drops_collapsed_faces():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1e-9, 0, 0], [1, 1e-9, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [3, 4, 2], [0, 3, 1]])
    wv, wf = weld(v, f, tol=1e-6)
    assert len(wv) == 3
    assert wf.tolist() == [[0, 1, 2], [0, 1, 2]]  # the third face collapsed (0 and 3 merged)


def test_refined_block_sampling_gives_the_dense_mesh_with_fewer_evaluations():
    """Evaluating in-between lattice points only where the surface can pass changes no triangle."""
    def bumpy(x: torch.Tensor) -> torch.Tensor:
        r = x.norm(dim=-1)
        return r - RADIUS - 0.04 * torch.sin(9 * x[:, 0]) * torch.cos(7 * x[:, 1]) * torch.sin(5 * x[:, 2])

    dense = extract_mesh(bumpy, ExtractOptions(resolution=96, refine=False, normals=False))
    fast = extract_mesh(bumpy, ExtractOptions(resolution=96, refine=True, normals=False))
    assert fast.mesh.faces.shape == dense.mesh.faces.shape
    key = lambda v: np.round(v.astype(np.float64), 6)[np.lexsort(np.round(v, 6).T)]
    np.testing.assert_array_equal(key(fast.mesh.vertices), key(dense.mesh.vertices))
    assert fast.sdf_evaluations < 0.6 * dense.sdf_evaluations
