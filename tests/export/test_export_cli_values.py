"""`srvol export` with values that start with a minus sign, in the plain ``--opt VALUE`` form: they reach
the option's own check (one line, exit 2) instead of reading as an unknown option."""
from __future__ import annotations

import pytest

from srvol.cli import build_parser


def parse(*argv: str):
    return build_parser().parse_args(["export", "--builtin", "bumpy", "--out", "asset", *argv])


def test_hr_pixel_size_takes_a_negative_value():
    assert parse("--hr-pixel-size", "-5e-3").hr_pixel_size == -5e-3


@pytest.mark.parametrize("option", ["--resolution", "--faces", "--texture-size"])
def test_negative_sizes_are_the_size_error(capsys, option):
    with pytest.raises(SystemExit) as e:
        parse(option, "-512")
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert err.startswith(f"srvol: error: export: argument {option}: expected a positive integer, got -512")
