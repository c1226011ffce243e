"""Decimation and the automatic face budget on the exact sphere."""
from __future__ import annotations

from srvol.export.extract import ExtractOptions, extract_mesh
from srvol.export.simplify import SimplifyOptions, mesh_error, simplify
from export_testfields import sphere_sdf


def test_auto_budget_is_smallest_within_tolerance():
    full = extract_mesh(sphere_sdf, ExtractOptions(resolution=64)).mesh
    opts = SimplifyOptions(hr_pixel_size=0.004, distance_px=0.5, normal_deg=2.0, min_faces=200, max_faces=6000,
                           samples=4000)
    r = simplify(sphere_sdf, full, opts)
    assert r.within_tolerance
    assert r.error.distance_p95 <= 0.5 * 0.004
    assert r.faces < len(full.faces) / 3
    # The budget tried just before the chosen one fails the tolerance (else it would have been chosen).
    if len(r.tried) > 1:
        from srvol.export.simplify import decimate

        smaller = mesh_error(sphere_sdf, decimate(full, r.tried[-2]), 4000)
        assert smaller.distance_p95 > 0.002 or smaller.normal_mean_deg > r.reference_error.normal_mean_deg + 2.0


def test_fixed_budget_error_reported():
    full = extract_mesh(sphere_sdf, ExtractOptions(resolution=64)).mesh
    r = simplify(sphere_sdf, full, SimplifyOptions(faces=500, samples=4000))
    assert abs(r.faces - 500) <= 10
    # A 500-face sphere of radius 0.5: chords sag by ~ edge^2 / (8 R), edge ~ sqrt(4 area / (sqrt(3) F)) = 0.08.
    assert 1e-4 < r.error.distance_p95 < 0.01
    assert not r.within_tolerance  # 0.5 px of 0.005 = 0.0025 is not met at 500 faces
