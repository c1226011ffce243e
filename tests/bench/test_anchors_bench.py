"""bench_anchors: a point's distance to the true surface, read off points spread on the mesh."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from bench.bench_anchors import main, table
from srvol.capture.compare import point_distances


def test_points_on_and_off_a_sphere_read_their_distance():
    """On a sphere of radius 0.5 the distance of a point at radius r is |r - 0.5|: 0 on it, 0.1 just
    outside, 0.125 inside -- each too high by at most about the samples' spacing (0.004 at 200 000)."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    dirs = np.random.default_rng(0).normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for r in (0.5, 0.6, 0.375):
        err = point_distances(dirs * r, sphere, samples=200_000) - abs(r - 0.5)
        assert err.min() > -1e-3 and err.max() < 0.008


def test_no_points_no_distances():
    assert point_distances(np.zeros((0, 3)), trimesh.creation.box(), samples=1000).shape == (0,)


def test_the_table_names_each_scene_and_the_command():
    row = {"scene": "glossy", "train_views": 40, "points": 3353, "seconds": 41.0, "median": 0.004, "p90": 0.015,
           "beyond_tolerance": 0.1, "beyond_agree": 0.017, "tolerance": 0.015, "agree": 0.03, "lr_px": 0.02}
    text = table([row], "--scenes glossy")
    assert "| glossy | 40 | 3353 | 41.0 | 0.0040 | 0.0150 | 10.0% | 1.7% | 0.0200 |" in text
    assert "`python -m bench.bench_anchors --scenes glossy`" in text
    assert "`python -m bench.bench_anchors`" in table([row], "")


def test_an_unknown_scene_is_one_error_line(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--scenes", "teapot"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "teapot" in err
