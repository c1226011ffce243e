"""bench_error_map: windows of stage-2 draws scored as training logs them (worked examples)."""
from __future__ import annotations

import math

import numpy as np

from bench.bench_error_map import main, window_spread


def test_windows_of_an_even_error_read_the_truth():
    """Every patch holds the same error: any draw, uniform or not, reads the whole set's PSNR."""
    error, count = np.full(1000, 0.016), np.full(1000, 16.0)
    truth = -10 * math.log10(0.001)
    p = np.linspace(1, 3, 1000)
    for probs in (np.full(1000, 1e-3), p / p.sum()):
        med, p1, p99, worst = window_spread(error, count, probs, 6, np.random.default_rng(0))
        assert abs(med - truth) < 1e-9 and abs(p99 - p1) < 1e-9 and worst < 1e-9


def test_drawn_by_the_error_a_rare_hot_patch_stops_swinging_the_window():
    """10 of 10 000 patches hold 90 % of the error: uniform windows mostly miss them (their median sits
    high), windows drawn in proportion to the error and weighted back stay near the truth."""
    error, count = np.full(10_000, 1e-4), np.full(10_000, 16.0)
    error[:10] = 9 * error[10:].sum() / 10
    truth = -10 * math.log10(error.sum() / count.sum())
    rng = np.random.default_rng(1)
    med_u, p1_u, p99_u, _ = window_spread(error, count, np.full(10_000, 1e-4), 6, rng)
    mixed = 0.5 / 10_000 + 0.5 * error / error.sum()
    med_m, p1_m, p99_m, worst_m = window_spread(error, count, mixed, 6, rng)
    assert med_u > truth + 5 and p99_u - p1_u > 8
    assert abs(med_m - truth) < 0.5 and p99_m - p1_m < 3 and worst_m < 3  # the issue's +-3 dB


def test_a_folder_that_is_not_a_run_is_one_error_line(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
