"""`srvol bench capacity`: each factor trained once in its own folder (x1 is the suite's own run), the
change against x1 tabulated per scene and on the mean, and a chart. Training is stood in for by a
fake that reports a fixed PSNR per factor (`bench suite`'s tests train for real)."""
from __future__ import annotations

import json

import pytest

bench_capacity = pytest.importorskip("bench.bench_capacity", reason="the benchmarks live in a source checkout")

# HR PSNR and normal MAE a fake run reports, per scene and factor
FAKE = {("dark", 0.5): (47.8, 3.1), ("dark", 1.0): (49.0, 3.2), ("shiny", 0.5): (33.0, 3.7), ("shiny", 1.0): (32.6, 3.7)}


def test_each_factor_trains_in_its_own_folder_and_the_table_gives_the_change(tmp_path, monkeypatch):
    calls = []

    def fake_train_and_eval(scene, run, sr, args, extra=(), eval_extra=()):
        factor = float(extra[1]) if extra else 1.0
        calls.append((scene.name, run.name, extra, eval_extra))
        hr, normals = FAKE[(scene.name, factor)]
        return {"command": f"srvol train {scene} --out {run} {' '.join(extra)}", "psnr_hr": hr,
                "normal_mae_deg": normals, "parameters": int(2e6 * factor ** 3), "iterations": 100,
                "train_seconds": 600.0, "stage2_step_swing_db": 1.0}

    monkeypatch.setattr(bench_capacity, "train_and_eval", fake_train_and_eval)
    monkeypatch.setattr(bench_capacity, "ensure_scene", lambda name, work, synth: work / "scenes" / name)
    results = tmp_path / "results"
    assert bench_capacity.main(["--scenes", "dark,shiny", "--factors", "0.5", "--work", str(tmp_path),
                                "--results", str(results)]) == 0
    # x1 is always run, in the suite's folder and scored as the suite scores it; x0.5 beside it
    assert calls == [("dark", "dark_auto_gaussian_600s_x0.5", ("--capacity", "0.5"), ("--no-relit",)),
                     ("dark", "dark_auto_gaussian_600s", (), ()),
                     ("shiny", "shiny_auto_gaussian_600s_x0.5", ("--capacity", "0.5"), ("--no-relit",)),
                     ("shiny", "shiny_auto_gaussian_600s", (), ())]
    text = (results / "capacity_table.md").read_text()
    assert "| dark (tuning) | 47.80, 3.10 deg (-1.20) | 49.00, 3.20 deg |" in text
    assert "| shiny (tuning) | 33.00, 3.70 deg (+0.40) | 32.60, 3.70 deg |" in text
    assert "| **mean change against x1** | **-0.40 dB**, -0.05 deg | - |" in text  # (-1.20 + 0.40) / 2
    rows = json.loads((results / "capacity_table.json").read_text())
    assert [sorted(r["runs"]) for r in rows] == [["0.5", "1"], ["0.5", "1"]]
    assert (results / "capacity_psnr.png").stat().st_size > 0


def test_unknown_scene_or_bad_factor_is_one_line():
    for bad in (["--scenes", "teapot"], ["--factors", "half"], ["--factors", "0,1"]):
        with pytest.raises(SystemExit) as e:
            bench_capacity.main(bad)
        assert e.value.code == 2
