"""The view state's small rules: panel sizes, the relight command a state writes."""
from __future__ import annotations

import shlex
from pathlib import Path

from srvol.relight.view_state import (DRAG_SIZE, FULL_SIZE, MaterialControls, ViewerPose, ViewState, panel_size,
                                      relight_command, render_size)

POSE = ViewerPose(position=(0.0, -2.6, 0.0), wxyz=(1.0, 0.0, 0.0, 0.0), fov_y=0.6, aspect=4 / 3)


def test_panel_follows_the_browser_aspect_at_a_fixed_width():
    assert panel_size(4 / 3, 640) == (640, 480)
    assert panel_size(16 / 9, 640) == (640, 360)
    assert panel_size(0.5, 640) == (640, 640)  # a tall canvas: clamped to square
    assert panel_size(5.0, 640) == (640, 320)  # a wide one: clamped to 2:1


def test_a_run_renders_small_while_moving_and_full_when_still_an_asset_always_full():
    assert render_size("run", settled=False, aspect=4 / 3) == DRAG_SIZE == (160, 120)
    assert render_size("run", settled=True, aspect=4 / 3) == FULL_SIZE == (640, 480)
    assert render_size("asset", settled=False, aspect=4 / 3) == FULL_SIZE


def test_relight_command_of_a_state():
    state = ViewState(pose=POSE, light_position=(-1.5, 0.25, 2.0), intensity=12.5, shadows=False,
                      material=MaterialControls(preset="no-specular", roughness_scale=0.5))
    cmd = relight_command(Path("my asset"), Path("cam.json"), (640, 480), state, Path("out.exr"))
    assert shlex.split(cmd) == ["relight", "my asset", "--camera", "cam.json", "--resolution", "640x480",
                                "--light-pos", "-1.5,0.25,2", "--intensity", "12.5",
                                "--material", "no-specular,roughness-scale=0.5", "--no-shadows", "--out", "out.exr"]
