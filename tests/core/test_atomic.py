"""Atomic writes: a folder or file appears whole, or not at all."""
from __future__ import annotations

import pytest

from srvol.atomic import AtomicFolder, atomic_write_text
from srvol.errors import SrvolError


def test_atomic_folder_appears_only_when_complete(tmp_path):
    dest = tmp_path / "out"
    with AtomicFolder(dest) as tmp:
        (tmp / "a.txt").write_text("1")
        assert not dest.exists()  # built beside it, under a temporary name
    assert (dest / "a.txt").read_text() == "1"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no temporary left behind


def test_atomic_folder_failure_leaves_the_old_folder_untouched(tmp_path):
    dest = tmp_path / "out"
    dest.mkdir()
    (dest / "old.txt").write_text("old")
    with pytest.raises(SrvolError, match="already exists"):
        AtomicFolder(dest)
    with pytest.raises(RuntimeError):
        with AtomicFolder(dest, force=True) as tmp:
            (tmp / "new.txt").write_text("new")
            raise RuntimeError("killed half-way")
    assert [p.name for p in dest.iterdir()] == ["old.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    with AtomicFolder(dest, force=True) as tmp:  # --force replaces it whole
        (tmp / "new.txt").write_text("new")
    assert [p.name for p in dest.iterdir()] == ["new.txt"]


def test_atomic_write_text_replaces_the_file(tmp_path):
    path = tmp_path / "sub" / "meta.json"
    atomic_write_text(path, "a")
    atomic_write_text(path, "b")
    assert path.read_text() == "b" and [p.name for p in path.parent.iterdir()] == ["meta.json"]
