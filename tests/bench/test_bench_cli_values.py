"""The benchmarks' number options take values that start with a minus sign in the plain
``--opt VALUE`` form (``python -m bench.bench_train --budget -1e2``: the value -100, which the
benchmark then refuses on its own terms, not "expected one argument")."""
from __future__ import annotations

import pytest

from bench import bench_export, bench_stage2, bench_study, bench_train


@pytest.mark.parametrize("module, argv, dest, value", [
    (bench_train, ["--budget", "-1e2"], "budget", -100.0),
    (bench_train, ["--eval-views", "-1"], "eval_views", -1),
    (bench_train, ["--snapshots", "-3"], "snapshots", -3),
    (bench_stage2, ["--seconds", "-9e1"], "seconds", -90.0),
    (bench_stage2, ["--views", "-2"], "views", -2),
    (bench_study, ["--budget", "-1.2e2"], "budget", -120.0),
])
def test_options_take_negative_values(module, argv, dest, value):
    assert getattr(module.build_parser().parse_args(argv), dest) == value


def test_mistakes_end_in_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        bench_export.build_parser().parse_args(["--run"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "argument --run: expected one argument" in err
