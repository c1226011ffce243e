"""`srvol bench suite` end to end on two tiny scenes: a table, a chart, and no work done twice."""
from __future__ import annotations

import json

import pytest

bench_suite = pytest.importorskip("bench.bench_suite", reason="the benchmarks live in a source checkout")

TINY = ["--scenes", "cup,rings", "--variants", "gaussian", "--iters", "5",
        "--synth=--lr 24x18 --views 4 --test-views 1"]


def test_suite_bench_tabulates_two_tiny_scenes_and_reuses_its_runs(tmp_path):
    work, results = tmp_path / "work", tmp_path / "results"
    assert bench_suite.main([*TINY, "--work", str(work), "--results", str(results)]) == 0
    rows = json.loads((results / "suite_table.json").read_text())
    assert [r["scene"] for r in rows] == ["cup", "rings"] and {r["set"] for r in rows} == {"report"}
    for r in rows:
        assert r["bicubic"]["psnr_hr"] > 10 and r["bicubic"]["psnr_hr_masked"] > 5
        run = r["variants"]["gaussian"]
        assert run["iterations"] == 5 and run["parameters"] > 0 and run["psnr_hr"] > 10
        assert {"normal_mae_deg", "albedo_psnr", "relit_psnr", "train_psnr", "peak_rss_gib"} <= set(run)
    table = (results / "suite_table.md").read_text()
    assert "| cup | report | 24x18 |" in table and "**report mean** (2 scenes)" in table
    assert (results / "suite_psnr.png").stat().st_size > 0
    # a second call finds the scenes and runs in --work and trains nothing
    summaries = sorted((work / "runs").glob("*/train_summary.json"))
    stamps = [p.stat().st_mtime_ns for p in summaries]
    assert bench_suite.main([*TINY, "--work", str(work), "--results", str(results)]) == 0
    assert [p.stat().st_mtime_ns for p in summaries] == stamps
    assert json.loads((results / "suite_table.json").read_text()) == rows


def test_a_timed_run_starts_after_an_untimed_warm_up_of_the_same_flags(tmp_path, monkeypatch):
    """torch.compile's cache is warmed by 40 steps of the same scene, SR model and flags in a throwaway
    folder, so the 600 s run does not spend its budget compiling; --no-warm-up and --iters runs skip it."""
    import argparse

    calls = []
    monkeypatch.setattr(bench_suite, "_run", lambda cmd: calls.append(cmd) or (0.0, 0.0))
    run = tmp_path / "runs" / "cup_auto_gaussian_600s_x0.5"
    args = argparse.Namespace(iters=0, budget=600.0, warm_up=True, collect=False)
    row = bench_suite.train_and_eval(tmp_path / "scenes" / "cup", run, "gaussian", args, ("--capacity", "0.5"))
    assert row["missing"]  # the fake trained nothing
    warm, timed = calls
    assert warm[warm.index("--out") + 1] == str(tmp_path / "warm-up" / run.name)
    assert warm[warm.index("--iters") + 1] == "40" and warm[warm.index("--compile") + 1] == "on"
    assert warm[warm.index("--sr") + 1] == "gaussian" and warm[warm.index("--capacity") + 1] == "0.5"
    assert timed[timed.index("--out") + 1] == str(run) and timed[timed.index("--time-budget") + 1] == "600"
    calls.clear()
    bench_suite.train_and_eval(tmp_path / "scenes" / "cup", run, "gaussian",
                               argparse.Namespace(iters=0, budget=600.0, warm_up=False, collect=False))
    assert len(calls) == 1 and "--time-budget" in calls[0]


def test_stage2_swing_is_the_largest_distance_from_the_running_median(tmp_path):
    """Stage-2 PSNRs 30, 31, 30, 36 (stage 1 ignored): after the first 10 % (none of 4 lines), the running
    medians are 30, 30.5, 30, 30.5, so the distances are 0, 0.5, 0, 5.5 -> 5.5 dB."""
    import json

    from bench.bench_suite import stage2_swing_db

    lines = [{"stage": 1, "psnr": 10.0, "probe_psnr": 10.0}] + [
        {"stage": 2, "psnr": p, "probe_psnr": q} for p, q in ((30.0, 31.0), (31.0, 31.5), (30.0, 31.5), (36.0, 31.5))]
    (tmp_path / "log.jsonl").write_text("\n".join(json.dumps(r) for r in lines) + "\n")
    assert stage2_swing_db(tmp_path, "psnr") == 5.5
    assert stage2_swing_db(tmp_path) == 0.25  # the probe: medians 31, 31.25, 31.5, 31.5


def test_collect_carries_over_committed_rows_whose_runs_are_not_here(tmp_path):
    """Runs live in the ignored work folder: a --collect on another machine keeps the committed
    table's rows for the runs it lacks (their rules marked), and its not-run rows; a run it never
    had stays out."""
    results = tmp_path / "results"
    results.mkdir()
    old = {"scene": "cup", "set": "report", "lr": "160x120", "psf_sigma": 0.45, "views": "40+6",
           "bicubic": {"psnr_hr": 42.3, "psnr_hr_masked": 36.4},
           "variants": {"gaussian": {"command": "srvol train ...", "psnr_hr": 35.3, "psnr_hr_masked": 29.6,
                                        "iterations": 4889, "train_seconds": 596.5, "parameters": 4892718,
                                        "rules": "beta cap 0.0038"},
                        "box": {"command": "srvol train ... --sr box", "missing": True}}}
    (results / "suite_table.json").write_text(json.dumps([old]))
    args = ["--collect", "--scenes", "cup,die", "--variants", "none,gaussian,box",
            "--work", str(tmp_path / "work"), "--results", str(results)]
    assert bench_suite.main(args) == 0
    rows = {r["scene"]: r for r in json.loads((results / "suite_table.json").read_text())}
    cup = rows["cup"]["variants"]
    assert cup["gaussian"]["psnr_hr"] == 35.3 and cup["gaussian"]["rules"] == "beta cap 0.0038 (earlier run)"
    assert "none" not in cup and rows["cup"]["bicubic"]["psnr_hr"] == 42.3
    # a run the table listed as not run stays listed, with its command
    assert cup["box"] == {"command": "srvol train ... --sr box", "missing": True}
    assert rows["die"]["variants"] == {}
    # collected again, the mark is not doubled
    assert bench_suite.main(args) == 0
    again = json.loads((results / "suite_table.json").read_text())[0]["variants"]["gaussian"]["rules"]
    assert again == "beta cap 0.0038 (earlier run)"


def test_vol_sr_on_a_subset_does_not_narrow_the_other_means():
    """Vol-SR (box) runs on one of two report scenes: bicubic, noSR and SR are still averaged over
    both scenes, Vol-SR over the one it ran on, and the table says how many that is."""
    from bench.bench_suite import set_means, summary_lines

    def row(scene, bic, none, sr, box=None):
        variants = {"none": {"psnr_hr": none, "psnr_hr_masked": none - 8},
                    "gaussian": {"psnr_hr": sr, "psnr_hr_masked": sr - 8}}
        if box is not None:
            variants["box"] = {"psnr_hr": box, "psnr_hr_masked": box - 8}
        return {"scene": scene, "set": "report", "bicubic": {"psnr_hr": bic, "psnr_hr_masked": bic - 8},
                "variants": variants}

    rows = [row("die", 36.0, 36.5, 37.5, box=37.0), row("cup", 42.0, 37.0, 37.0)]
    columns = ["bicubic", "none", "gaussian", "box"]
    means = set_means(rows, columns, "psnr_hr")["report"]
    assert means["scenes"] == 2 and means["gaussian"] == 37.25 and means["bicubic"] == 39.0
    assert means["box"] == 37.0 and means["scenes_box"] == 1
    lines = summary_lines(rows, columns)
    assert lines[0].endswith("| SR - bicubic | SR - noSR | SR - Vol-SR |")
    assert lines[2].endswith("| +1.50 | +1.00 | +0.50 |")  # die: SR over bicubic, noSR, Vol-SR
    assert "37.00 / 29.00 (on 1)" in lines[-1] and lines[-1].endswith("| -1.75 | +0.50 | +0.50 |")


def test_sr_over_nosr_from_two_collections_is_marked_mixed():
    """SR rerun here, noSR carried over from an earlier collection (another machine, an older auto):
    their difference is printed, marked, and so is the set mean it enters; a pair collected together
    is not marked."""
    from bench.bench_suite import summary_lines

    def row(scene, sr_rules, none_rules):
        return {"scene": scene, "set": "tuning", "bicubic": {"psnr_hr": 30.0, "psnr_hr_masked": 22.0},
                "variants": {"none": {"psnr_hr": 31.0, "psnr_hr_masked": 23.0, "rules": none_rules},
                             "gaussian": {"psnr_hr": 32.0, "psnr_hr_masked": 24.0, "rules": sr_rules}}}

    together = summary_lines([row("bumpy", "beta cap 0.005", "beta cap 0.005")], ["bicubic", "none", "gaussian"])
    assert together[2].endswith("| +2.00 | +1.00 |") and together[3].endswith("| +2.00 | +1.00 |")
    apart = summary_lines([row("shiny", "beta cap 0.005", "beta cap 0.005 (earlier run)")],
                          ["bicubic", "none", "gaussian"])
    assert apart[2].endswith("| +2.00 | +1.00 (mixed) |") and apart[3].endswith("| +1.00 (mixed) |")
