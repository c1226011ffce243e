"""Values that start with a minus sign, in the plain ``--opt VALUE`` form.

``srvol synth --psf-sigma -1e-3`` or ``relight RUN --light-pos -1.5,-0.2,2``: the token after an
option that takes a value is that value when it reads as numbers (a comma list, a WxH size,
scientific notation), while real options such as ``--force`` and ``-h`` stay options. Every case
parses through the real parser (``srvol.cli.build_parser``, the demo's ``build_parser``) without
running the command. The relight, export and benchmark options have their own cases beside their
tests (tests/relight, tests/export, tests/bench).
"""
from __future__ import annotations

import argparse

import pytest

from srvol import demo
from srvol.cli import build_parser
from srvol.cli_parser import NUMBERS_TOKEN, OneLineParser


@pytest.mark.parametrize("token", ["-1", "-1.5", "-.5", "-2.", "-1e-3", "-1E+3", "-1.5,-0.2,2", "-1e-3,2,3",
                                   "-0.53,2.9,0.4", "-64x48", "-64X48"])
def test_number_tokens_are_values(token):
    assert NUMBERS_TOKEN.match(token)


@pytest.mark.parametrize("token", ["-h", "--force", "--light-pos", "-x", "-", "--1", "-e3", "-1,", "-1,,2",
                                   "-1.5,a", "-1 2", "-1;2"])
def test_other_dash_tokens_are_not(token):
    assert not NUMBERS_TOKEN.match(token)


def test_the_argparse_hook_is_still_there():
    """srvol.cli_parser replaces argparse's private ``_negative_number_matcher``; this fails first
    if a Python release renames it or stops consulting it for each token."""
    assert hasattr(argparse.ArgumentParser(), "_negative_number_matcher")
    parser = OneLineParser()
    assert parser._negative_number_matcher is NUMBERS_TOKEN
    assert parser._parse_optional("-1.5,-0.2,2") is None  # None: a value, not an option
    assert parser._parse_optional("--force") is not None


@pytest.mark.parametrize("argv, dest, value", [
    (["synth", "--sr", "-4"], "sr", -4),
    (["synth", "--views", "-3"], "views", -3),
    (["synth", "--test-views", "-2"], "test_views", -2),
    (["synth", "--psf-sigma", "-1e-3"], "psf_sigma", -1e-3),
    (["synth", "--seed", "-7"], "seed", -7),
    (["eval", "RUN", "--views", "-040,041"], "views", "-040,041"),
    (["train", "SCENE", "--out", "RUN", "--psf-samples", "-4"], "psf_samples", -4),
    (["train", "SCENE", "--out", "RUN", "--stage2-fraction", "-.15"], "stage2_fraction", -0.15),
    (["train", "SCENE", "--out", "RUN", "--psf-warmup", "-5e-1"], "psf_warmup", -0.5),
    (["train", "SCENE", "--out", "RUN", "--capacity", "-2"], "capacity", -2.0),
    (["train", "SCENE", "--out", "RUN", "--time-budget", "-1e2"], "time_budget", -100.0),
    (["train", "SCENE", "--out", "RUN", "--iters", "-10"], "iters", -10),
    (["train", "SCENE", "--out", "RUN", "--seed", "-3"], "seed", -3),
    (["train", "SCENE", "--out", "RUN", "--checkpoint-every", "-200"], "checkpoint_every", -200),
    (["train", "SCENE", "--out", "RUN", "--snapshots", "-1"], "snapshots", -1),
])
def test_srvol_options_take_negative_values(argv, dest, value):
    assert getattr(build_parser().parse_args(argv), dest) == value


def test_a_negative_size_is_read_as_a_size_and_refused_as_one(capsys):
    """``--lr -64x48`` reaches the size parser (not "expected one argument") and fails there."""
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(["synth", "--lr", "-64x48"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "argument --lr: size -64x48: sides must be 1..16384" in err


@pytest.mark.parametrize("argv, dest, value", [
    (["--budget", "-1e-3"], "budget", -1e-3),
    (["--eval-views", "-2"], "eval_views", -2),
])
def test_demo_options_take_negative_values(argv, dest, value):
    assert getattr(demo.build_parser().parse_args(argv), dest) == value


@pytest.mark.parametrize("argv", [["synth", "--psf-sigma", "--force"], ["synth", "--lr", "-h"]])
def test_real_options_are_still_options(capsys, argv):
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert err.count("\n") == 1 and err.startswith("srvol: error: synth: argument ")
    assert "expected one argument" in err
