"""Paths in the committed results: relative to the repository root, never a machine's own.

Every benchmark writes its tables through :func:`write_result`, the one place that rewrites the
absolute paths in them (the commands of each row, the folders an export wrote):

* inside the repository (this checkout, or another one's ``bench/work/``): relative to its root,
  so a recorded command runs as it reads from the root: ``srvol train bench/work/scene_bumpy ...``;
* under the temporary folder: ``<tmp>/...`` (``<tmp>/bench_export.r4ya42na/asset``);
* anywhere else: the last name only.
"""
from __future__ import annotations

import re
import tempfile
from pathlib import Path, PurePosixPath

REPO = Path(__file__).resolve().parent.parent
TMP = "<tmp>"
_TEMP_ROOTS = tuple(dict.fromkeys((tempfile.gettempdir(), "/tmp")))
_OTHER_CHECKOUT = "/bench/work/"
"""The benchmarks' work folder, in a checkout at another place (rows recorded there)."""

ABSOLUTE_PATH = re.compile(r"(?<![\w.>/~-])/[\w.+@-][\w.+@/-]*")
"""An absolute POSIX path inside a text; not ``bench/work`` (relative), ``W/sr``, ``1/5/15`` nor the
``<tmp>/x`` this module writes."""


def repo_relative(path: str) -> str:
    """An absolute ``path`` as the results record it (the module's docstring says how)."""
    p = PurePosixPath(path)
    if p.is_relative_to(REPO):
        return p.relative_to(REPO).as_posix()
    k = path.find(_OTHER_CHECKOUT)
    if k >= 0:
        return path[k + 1:]
    for root in _TEMP_ROOTS:
        if p.is_relative_to(root):
            return f"{TMP}/{p.relative_to(root).as_posix()}"
    return p.name


def without_machine_paths(text: str) -> str:
    """``text`` with each absolute path in it written by :func:`repo_relative`."""
    return ABSOLUTE_PATH.sub(lambda m: repo_relative(m.group()), text)


def write_result(path: Path, text: str) -> None:
    """Write a results file (markdown, JSON) with no absolute path of this machine in it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(without_machine_paths(text))
