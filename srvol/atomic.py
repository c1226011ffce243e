"""Atomic writes: a file or a folder is built under a temporary name beside its target and renamed
into place only when complete, so that a killed or failed command never leaves a half-written output.

* :func:`atomic_path` -- a temporary path to write a file to, then ``os.replace`` onto the target
  (the image writers of :mod:`srvol.images` and the checkpoints use it);
* :func:`atomic_write_text` -- a text file (JSON metadata, reports);
* :class:`AtomicFolder` -- a whole output folder (a synthetic scene, an exported asset, relit images).
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from srvol.errors import SrvolError


def atomic_path(path: Path):
    """A temporary path in ``path``'s folder; rename it onto ``path`` when written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    return Path(tmp)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    tmp = atomic_path(Path(path))
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


class AtomicFolder:
    """Build a folder under a temporary name and rename it into place on success.

    ``with AtomicFolder(dest, force) as tmp: ...`` -- on an exception the
    temporary folder is removed and ``dest`` is untouched.
    """

    def __init__(self, dest: str | os.PathLike, force: bool = False):
        self.dest = Path(dest)
        self.force = force
        if self.dest.exists() and not force and (not self.dest.is_dir() or any(self.dest.iterdir())):
            raise SrvolError(f"{self.dest}: already exists (use --force to replace it)")

    def __enter__(self) -> Path:
        self.dest.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.dest.name}.", dir=self.dest.parent))
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return False
        if self.dest.exists():
            old = self.dest.with_name(f".{self.dest.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(self.dest, old)
            os.replace(self.tmp, self.dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(self.tmp, self.dest)
        return False
