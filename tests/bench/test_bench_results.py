"""The committed benchmark results name no path of the machine they ran on.

Every bench script writes its tables through ``bench.paths.write_result``: a recorded command reads
``srvol train bench/work/scene_bumpy --out bench/work/runs/...`` (run it from the repository root),
a temporary folder reads ``<tmp>/bench_export.r4ya42na/asset``.
"""
from __future__ import annotations

import re
import tempfile
from pathlib import Path

import pytest

from bench.paths import REPO, repo_relative, without_machine_paths, write_result

RESULTS = REPO / "bench" / "results"
MACHINE_PATH = re.compile(r"(?<![\w.])/(?:work|tmp|home|root|usr|var|opt|mnt|Users)/")
COMMITTED = sorted([*RESULTS.glob("*.md"), *RESULTS.glob("*.json")])


def test_there_are_results_to_check():
    assert len(COMMITTED) >= 10


@pytest.mark.parametrize("path", COMMITTED, ids=lambda p: p.name)
def test_committed_results_have_no_machine_paths(path):
    text = path.read_text()
    found = [text[max(m.start() - 30, 0):m.end() + 30] for m in MACHINE_PATH.finditer(text)]
    assert not found, f"{path.name}: absolute paths (write it through bench.paths.write_result): {found}"
    assert without_machine_paths(text) == text


@pytest.mark.parametrize("path, shown", [
    (f"{REPO}/bench/work/scene_bumpy", "bench/work/scene_bumpy"),
    (f"{REPO}/.venv/bin/python", ".venv/bin/python"),
    ("/work/main/bench/work/runs/bumpy_auto_gaussian_600s", "bench/work/runs/bumpy_auto_gaussian_600s"),
    ("/tmp/bench_export.r4ya42na/asset/raw/albedo.exr", "<tmp>/bench_export.r4ya42na/asset/raw/albedo.exr"),
    (f"{tempfile.gettempdir()}/bench_synth_x/bumpy", "<tmp>/bench_synth_x/bumpy"),
    ("/home/someone/runs/my_run", "my_run"),
])
def test_repo_relative(path, shown):
    assert repo_relative(path) == shown


def test_a_recorded_command_runs_from_the_repository_root():
    command = (f"srvol train {REPO}/bench/work/scene_bumpy --out {REPO}/bench/work/runs/r --force && "
               f"srvol eval {REPO}/bench/work/runs/r --json=/tmp/m.json")
    assert without_machine_paths(command) == ("srvol train bench/work/scene_bumpy --out bench/work/runs/r --force && "
                                              "srvol eval bench/work/runs/r --json=<tmp>/m.json")


@pytest.mark.parametrize("text", ["bench/work/runs/r", "I = 25 W/sr", "load 1.0 / 0.9 (1/5/15 min)",
                                  "`<tmp>/bench_export.x/asset`", "https://example.org/a/b", "~/runs/r"])
def test_text_without_absolute_paths_is_kept(text):
    assert without_machine_paths(text) == text


def test_write_result_strips_json_values(tmp_path: Path):
    out = tmp_path / "results" / "t.json"
    write_result(out, '{"out_dir": "/tmp/bench_export.abc/asset", "run": "%s/bench/work/runs/r"}' % REPO)
    assert out.read_text() == '{"out_dir": "<tmp>/bench_export.abc/asset", "run": "bench/work/runs/r"}'
