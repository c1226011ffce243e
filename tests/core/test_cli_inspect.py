"""`srvol inspect` and `srvol synth` through the real command line, one subprocess per case.

Each process spends seconds importing torch, so the module starts all of them at
once (a module fixture) and each test reads the result of its own.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from .conftest import TINY_W, write_tiny_scene


@dataclass
class Finished:
    returncode: int
    stdout: str
    stderr: str


class Launched:
    """A running ``python -m srvol ...``; ``result()`` waits for it."""

    def __init__(self, *args: str):
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", "srvol", *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env)

    def result(self) -> Finished:
        out, err = self.proc.communicate(timeout=180)
        return Finished(self.proc.returncode, out, err)


def assert_one_line_error(proc: Finished, *words: str) -> None:
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("srvol: error:"), lines[0]
    for w in words:
        assert w in lines[0], lines[0]


def edit_camera(root: Path, fname: str, key: str, index: int, value) -> None:
    cams = json.loads((root / "cameras.json").read_text())
    cams[fname][key][index] = value
    (root / "cameras.json").write_text(json.dumps(cams))


@dataclass
class Runs:
    good: Launched
    image_deleted: Launched
    nan_w2c: Launched
    img_size_wrong: Launched
    synth_list: Launched
    synth_no_out: Launched
    synth_existing: Launched
    synth_bad_size: Launched
    existing_dir: Path


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Runs:
    base = tmp_path_factory.mktemp("cli")
    good = write_tiny_scene(base / "good")
    deleted = write_tiny_scene(base / "deleted")
    (deleted / "image" / "001.exr").unlink()
    nan = write_tiny_scene(base / "nan")
    edit_camera(nan, "002.exr", "W2C", 3, math.nan)
    size = write_tiny_scene(base / "size")
    edit_camera(size, "000.exr", "img_size", 0, TINY_W * 2)
    existing = base / "existing" / "taken"
    existing.mkdir(parents=True)
    (existing / "keep.txt").write_text("mine")
    return Runs(good=Launched("inspect", str(good)),
                image_deleted=Launched("inspect", str(deleted)),
                nan_w2c=Launched("inspect", str(nan)),
                img_size_wrong=Launched("inspect", str(size)),
                synth_list=Launched("synth", "--list"),
                synth_no_out=Launched("synth"),
                synth_existing=Launched("synth", "--out", str(existing), "--lr", "16x12", "--views", "2",
                                        "--test-views", "1"),
                synth_bad_size=Launched("synth", "--out", str(base / "never"), "--lr", "wide"),
                existing_dir=existing)


def test_inspect_good_scene(runs):
    proc = runs.good.result()
    assert proc.returncode == 0, proc.stderr
    assert "views      3 (2 train, 1 test)" in proc.stdout
    assert "PSF        gaussian, sigma 0.5 LR px" in proc.stdout
    assert proc.stdout.strip().endswith("ok")


def test_inspect_one_image_deleted(runs):
    assert_one_line_error(runs.image_deleted.result(), "001.exr", "missing image")


def test_inspect_nan_in_w2c(runs):
    assert_one_line_error(runs.nan_w2c.result(), "cameras.json", "non-finite")


def test_inspect_img_size_wrong(runs):
    assert_one_line_error(runs.img_size_wrong.result(), "000.exr", "differs from img_size")


def test_synth_list_names_the_builtin_scenes(runs):
    proc = runs.synth_list.result()
    assert proc.returncode == 0, proc.stderr
    header, *lines = proc.stdout.strip().splitlines()
    assert header.split()[:3] == ["name", "set", "LR"]
    from srvol.synth.scenes import SCENES, scene_set

    assert [line.split()[0] for line in lines] == list(SCENES)
    assert [line.split()[1] for line in lines] == [scene_set(n) for n in SCENES]
    assert lines[0].startswith("bumpy     tuning  120x90") and "[default]" in lines[0]


def test_synth_without_out_is_a_one_line_error(runs):
    assert_one_line_error(runs.synth_no_out.result(), "--out")


def test_synth_refuses_an_existing_folder_and_leaves_it_untouched(runs):
    assert_one_line_error(runs.synth_existing.result(), "already exists", "--force")
    out = runs.existing_dir
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    assert (out / "keep.txt").read_text() == "mine"
    assert sorted(p.name for p in out.parent.iterdir()) == ["taken"]  # no temporary folder left beside it


def test_a_malformed_option_is_one_line_not_a_usage_block(runs):
    assert_one_line_error(runs.synth_bad_size.result(), "synth: argument --lr", "expected WxH", "--help")
