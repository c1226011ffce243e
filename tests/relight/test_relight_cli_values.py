"""`relight` / `srvol relight` with values that start with a minus sign, in the plain form:
``relight --builtin bumpy --light-pos -1.5,-0.2,2`` puts the light at x = -1.5 (no ``--light-pos=``
needed); ``--force`` and ``-h`` stay options (tests/core/test_cli_negative_values.py)."""
from __future__ import annotations

import numpy as np
import pytest

from srvol.cli import build_parser, relight_main
from srvol.images import read_exr
from srvol.relight.cli import parse_light


def parse(*argv: str):
    return build_parser().parse_args(["relight", "--builtin", "bumpy", *argv, "--out", "x.png"])


@pytest.mark.parametrize("option, value, parsed", [
    ("--light-pos", "-1.5,-0.2,2", "-1.5,-0.2,2"),
    ("--light-pos", "-1e-3,2,3", "-1e-3,2,3"),
    ("--intensity", "-1,2,3", "-1,2,3"),
    ("--orbit", "-3", -3),
    ("--ss", "-2", -2),
])
def test_options_take_negative_values(option, value, parsed):
    args = parse("--light-pos", "1,1,2", option, value)
    assert getattr(args, option[2:].replace("-", "_")) == parsed


def test_negative_light_position_reads_as_numbers():
    light = parse_light(parse("--light-pos", "-0.53,2.9,0.4").light_pos, None, (10.0, 10.0, 10.0))
    np.testing.assert_allclose(light.position.tolist(), [-0.53, 2.9, 0.4])


def test_negative_resolution_is_the_resolution_error(capsys):
    with pytest.raises(SystemExit) as e:
        parse("--light-pos", "1,1,2", "--resolution", "-64x48")
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert "argument --resolution: size -64x48: sides must be 1..16384" in err


def test_relight_command_with_a_light_at_negative_x(capsys, tmp_path):
    """``relight --builtin bumpy --light-pos -1.5,-0.2,2``, as typed: the image is lit from the other
    side than with the light at x = +1.5."""
    brightness = {}
    for x in ("-1.5", "1.5"):
        out = tmp_path / f"x{x}.exr"
        assert relight_main(["--builtin", "bumpy", "--light-pos", f"{x},-0.2,2", "--resolution", "32x24",
                             "--out", str(out)]) == 0
        img = read_exr(out).mean(-1)
        brightness[x] = img[:, :16].sum() - img[:, 16:].sum()  # left half minus right half
    assert capsys.readouterr().err == ""
    assert brightness["-1.5"] > 0 > brightness["1.5"]
