"""The argument parser of every srvol command line (``srvol``, ``relight``, the demo, the benchmarks).

Two things differ from plain argparse:

* a value may start with a minus sign in the plain ``--opt VALUE`` form when it reads as numbers:
  ``--light-pos -1.5,-0.2,2``, ``--psf-sigma -1e-3``, ``--resolution -64x48`` (the option's type
  then says what is wrong with it). Python 3.11's argparse only lets ``-1`` and ``-1.5`` through
  and reads ``-1.5,0,2`` as an unknown option, so ``--light-pos`` would "expect one argument";
* a command-line mistake is reported in one line ``PROG: error: ...``, exit status 2.
"""
from __future__ import annotations

import argparse
import re
from typing import NoReturn

EXIT_USER_ERROR = 2

_NUMBER = r"(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
NUMBERS_TOKEN = re.compile(rf"^-{_NUMBER}(?:[,xX][-+]?{_NUMBER})*$")
"""A token that is a value, not an option, although it starts with '-': numbers joined by ',' (a
vector, a list) or 'x' (a WxH size), the first one negative. ``-h`` and ``--force`` do not match."""


class OneLineParser(argparse.ArgumentParser):
    """argparse that takes negative number lists as values and reports a mistake in one line.

    Sub-command parsers inherit the class (argparse's ``add_subparsers`` uses the parent's type).
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # argparse's (private) test for "a negative number, hence a value": used by _parse_optional
        # for each token and by add_argument for option names. The one place srvol relies on
        # argparse internals; tests/core/test_cli_negative_values.py fails if Python renames it.
        self._negative_number_matcher = NUMBERS_TOKEN

    def error(self, message: str) -> NoReturn:
        root, *command = self.prog.split()
        where = f"{' '.join(command)}: " if command else ""
        self.exit(EXIT_USER_ERROR, f"{root}: error: {where}{message} (see {self.prog} --help)\n")


def image_size(text: str) -> tuple[int, int]:
    """An argparse type: ``WxH`` -> (W, H), each side 1..16384."""
    try:
        w, h = text.lower().split("x")
        size = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH (e.g. 640x480), got {text!r}") from None
    if min(size) < 1 or max(size) > 16384:
        raise argparse.ArgumentTypeError(f"size {text}: sides must be 1..16384")
    return size
