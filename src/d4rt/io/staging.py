"""The atomic output folder: everything is written into a hidden staging folder beside the destination
and moved into place only when every file is complete, so a failure leaves nothing half-written and a
replaced folder is swapped as a whole."""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager, suppress
from pathlib import Path


@contextmanager
def staged_folder(directory: Path):
    """A fresh hidden folder beside ``directory`` (same file system, so moves are renames). On success it
    becomes ``directory`` (whose old contents, if any, are removed after the swap); on any error it is
    removed and ``directory`` is untouched."""
    missing = [p for p in directory.absolute().parents if not p.exists()]  # deepest first
    directory.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{directory.name}.partial-", dir=directory.parent))
    try:
        yield stage
        old = None
        if directory.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{directory.name}.old-", dir=directory.parent))
            os.replace(directory, old / "contents")
        os.replace(stage, directory)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        for parent in missing:  # the parent folders this call made
            with suppress(OSError):
                parent.rmdir()
        raise
