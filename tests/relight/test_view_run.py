"""`srvol view RUN`: the neural path renders DRAG_SIZE while the state changes, FULL_SIZE once still."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch

from srvol.config import RunConfig, SceneRecord, write_run_config
from srvol.presets import fast_config
from srvol.fields import FieldConfig, SceneFields
from srvol.psf import GaussianPSF
from srvol.relight.view import ViewOptions, Viewer
from srvol.relight.view_state import DRAG_SIZE, FULL_SIZE

from view_fixtures import free_port

TINY_FIELDS = FieldConfig(sdf_levels=(4, 4, 8), mat_levels=2, mat_min_res=4, mat_max_res=8, mat_table_log2=8,
                          sdf_hidden=8, mat_hidden=8)


def tiny_run(root: Path) -> Path:
    """A finished run of tiny untrained fields (their initialisation is a sphere): config.json + model.pt."""
    run = root / "run"
    run.mkdir()
    write_run_config(run, RunConfig(train=replace(fast_config(), fields=TINY_FIELDS), scene=SceneRecord(
        path=None, psf=GaussianPSF(0.5, 2), hr_pixel_size=0.01, light_intensity=(2.0, 2.0, 2.0))))
    torch.manual_seed(0)
    torch.save(SceneFields(TINY_FIELDS, learn_intensity=False).state_dict(), run / "model.pt")
    return run


def sizes_until_full(viewer: Viewer, since: int, limit: int = 6) -> list[tuple[int, int]]:
    """(W, H) of each render shown after the first ``since`` ones, up to the first at full size."""
    for _ in range(limit):
        sizes = [r.size for r in list(viewer.recent)[since:]]
        if FULL_SIZE in sizes:
            return sizes[:sizes.index(FULL_SIZE) + 1]
        viewer.wait_for_render(viewer.renders, timeout=120)
    return sizes


def test_a_run_renders_small_while_moving_and_full_once_still(tmp_path):
    viewer = Viewer(tiny_run(tmp_path), ViewOptions(port=free_port(), out=tmp_path / "out"))
    try:
        assert viewer.source.kind == "run" and viewer.intensity.value == 2.0  # the run's flash
        # a new state: the quick render first, then (nothing moves) the full one
        assert sizes_until_full(viewer, since=0) == [DRAG_SIZE, FULL_SIZE]
        shown = len(viewer.recent)
        viewer.light_handle.position = (0.0, -2.0, 1.0)
        assert sizes_until_full(viewer, since=shown) == [DRAG_SIZE, FULL_SIZE]
        assert viewer.last_image.mask.mean() > 0.02  # the sphere is in view
    finally:
        viewer.stop()
