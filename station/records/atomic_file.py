"""Write a file whole or not at all: a temporary file in the same folder, synced, renamed."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, TextIO


def write_atomic(path: str | os.PathLike, write: Callable[[TextIO], None], *, newline: str | None = None) -> Path:
    """Call ``write(f)`` on a temporary text file beside ``path`` and rename it into place.

    The folder must exist. Raises OSError (disk full, read-only folder, ...) after removing the temporary file, so a
    failed write never leaves a half file nor touches an existing ``path``.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline=newline) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """:func:`write_atomic` for a string."""
    return write_atomic(path, lambda f: f.write(text))
