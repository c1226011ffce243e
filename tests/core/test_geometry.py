"""The shared geometry, camera rig and field adapters as worked examples with hand-computed answers."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from srvol.camera_rig import CAMERA_DISTANCE, OBJECT_RADIUS, rig_camera, rig_intrinsics
from srvol.field_adapters import material_in_float64, sdf_in_float64
from srvol.geometry import MeshRayCaster, ray_sphere, sdf_normals, spherical_uv
from srvol.types import Rays, SurfaceMaterial


def test_ray_sphere_hand_computed_entries_and_exits():
    # Rays along +z against the unit sphere. From (0, 0.6, -3): b = o.d = -3, c = |o|^2 - 1 = 8.36,
    # b^2 - c = 0.64, so t = 3 -+ 0.8. From the centre: entry clamped to 0, exit at 1.
    o = torch.tensor([[0.0, 0.0, -3.0], [0.0, 0.6, -3.0], [0.0, 0.0, 0.0], [0.0, 2.0, -3.0], [0.0, 1.0, -3.0]],
                     dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).expand(5, 3)
    near, far = ray_sphere(Rays(o, d), 1.0)
    torch.testing.assert_close(near[:3], torch.tensor([2.0, 2.2, 0.0], dtype=torch.float64))
    torch.testing.assert_close(far[:3], torch.tensor([4.0, 3.8, 1.0], dtype=torch.float64))
    # a miss and a tangent ray: entry 1 > exit 0
    assert near[3:].tolist() == [1.0, 1.0] and far[3:].tolist() == [0.0, 0.0]


def test_sdf_normals_of_a_sphere_point_away_from_its_centre():
    centre = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64)

    def sdf(x):
        return (x - centre).norm(dim=-1) - 0.4

    x = centre + torch.tensor([[0.4, 0.0, 0.0], [0.0, 0.0, -0.4], [0.3, 0.4, 0.0], [1.0, 2.0, 2.0],
                               [0.0, -0.1, 0.0]], dtype=torch.float64)
    expected = torch.tensor([[1.0, 0, 0], [0, 0, -1], [0.6, 0.8, 0], [1 / 3, 2 / 3, 2 / 3], [0, -1, 0]],
                            dtype=torch.float64)
    n = sdf_normals(sdf, x)
    assert n.dtype == torch.float64 and not n.requires_grad
    torch.testing.assert_close(n, expected)
    torch.testing.assert_close(sdf_normals(sdf, x, chunk=2), n)  # chunking changes nothing
    assert sdf_normals(sdf, x[:0]).shape == (0, 3)


def test_spherical_uv_of_the_six_axis_points():
    axes = torch.tensor([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    uv = spherical_uv(2.0 * axes)  # the radius does not matter
    # u = atan2(y, x) / 2pi + 0.5: +x 0.5, -x 1 (the seam), +y 0.75, -y 0.25; the poles sit at u = 0.5
    # v = 1 - theta / pi: 1 at the north pole (+z), 0.5 on the equator, 0 at the south pole
    expected = torch.tensor([[0.5, 0.5], [1.0, 0.5], [0.75, 0.5], [0.25, 0.5], [0.5, 1.0], [0.5, 0.0]])
    torch.testing.assert_close(uv, expected)


@pytest.fixture
def triangle_caster() -> MeshRayCaster:
    import trimesh

    mesh = trimesh.Trimesh(vertices=[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]], process=False)
    return MeshRayCaster.build(mesh)


def test_mesh_ray_caster_finds_distance_point_and_barycentric_weights(triangle_caster):
    # Down onto the triangle z = 0 at (0.25, 0.25): t = 2, weights (1 - 0.25 - 0.25, 0.25, 0.25).
    # The second ray misses (x + y > 1), the third is parallel to the plane.
    o = np.array([[0.25, 0.25, 2.0], [0.8, 0.8, 2.0], [0.2, 0.2, 1.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    hits = triangle_caster.first_hits(o, d)
    assert hits.ray.tolist() == [0] and hits.face.tolist() == [0]
    np.testing.assert_allclose(hits.t, [2.0])
    np.testing.assert_allclose(hits.points, [[0.25, 0.25, 0.0]], atol=1e-12)
    np.testing.assert_allclose(hits.bary, [[0.5, 0.25, 0.25]])
    # per-vertex values 0, 1, 2 (and a second channel 10x): 0.5 * 0 + 0.25 * 1 + 0.25 * 2 = 0.75
    values = np.array([[0.0, 0.0], [1.0, 10.0], [2.0, 20.0]])
    np.testing.assert_allclose(triangle_caster.interpolate(hits, values), [[0.75, 7.5]])
    np.testing.assert_allclose(triangle_caster.face_normals, [[0.0, 0.0, 1.0]])  # counter-clockwise: +z
    idx, tri, t = triangle_caster.first_faces(o, d)
    assert idx.tolist() == [0] and tri.tolist() == [0] and t.tolist() == hits.t.tolist()


def test_rig_camera_looks_at_the_origin_and_frames_the_object():
    W, H = 80, 60
    cam = rig_camera(np.array([0.6, 0.0, 0.8]), W, H)
    torch.testing.assert_close(cam.center, torch.tensor([0.6, 0.0, 0.8], dtype=torch.float64) * CAMERA_DISTANCE)
    centre = cam.project(torch.zeros(1, 3, dtype=torch.float64))[0]
    torch.testing.assert_close(centre, torch.tensor([W / 2, H / 2], dtype=torch.float64))
    # The object's bounding sphere, seen under half-angle asin(R / distance), fills 95 % of the height.
    half_angle = math.asin(OBJECT_RADIUS / CAMERA_DISTANCE)
    assert rig_intrinsics(W, H)[1, 1].item() * math.tan(half_angle) == pytest.approx(0.95 * H / 2)
    assert cam.K[0, 0] == cam.K[1, 1]


def test_float64_adapters_evaluate_in_float64_and_answer_in_the_callers_dtype():
    seen = []

    def sdf64(x):
        seen.append(x.dtype)
        return x.norm(dim=-1) - 1.0 / 3.0

    def material64(x):
        seen.append(x.dtype)
        return SurfaceMaterial.constant(x.shape[0], albedo=(0.1, 0.2, 0.3), dtype=x.dtype)

    x = torch.tensor([[0.5, 0.0, 0.0], [0.0, 0.25, 0.0]])
    d = sdf_in_float64(sdf64)(x)
    m = material_in_float64(material64)(x)
    assert seen == [torch.float64, torch.float64]
    assert d.dtype == torch.float32 and m.albedo.dtype == m.specular.dtype == m.alpha.dtype == torch.float32
    torch.testing.assert_close(d, torch.tensor([0.5 - 1 / 3, 0.25 - 1 / 3]))
    torch.testing.assert_close(m.albedo[1], torch.tensor([0.1, 0.2, 0.3]))
