"""Fixtures of the capture tests: one small synthetic capture (20 photos of the bunny, 320x240, a
120-degree walk) and its import, made once per session (~10 s on 2 cores)."""
from __future__ import annotations

import pytest

SMALL_PHOTOS = 20


@pytest.fixture(scope="session")
def small_capture(tmp_path_factory):
    from srvol.synth.capture import CaptureOptions, synthesize_capture

    out = tmp_path_factory.mktemp("capture") / "bunny"
    synthesize_capture("bunny", out, CaptureOptions(photos=SMALL_PHOTOS, arc_deg=120, test_views=1, relit_views=0,
                                                    mesh_resolution=64), progress=False)
    return out


@pytest.fixture(scope="session")
def small_import(small_capture, tmp_path_factory):
    from srvol.capture.importer import ImportOptions, import_capture

    scene = tmp_path_factory.mktemp("imported") / "scene"
    report = import_capture(small_capture / "photos", scene, ImportOptions(progress=False))
    return scene, report
