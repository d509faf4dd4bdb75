"""A file written whole or not at all: a temporary file beside the target, then ``os.replace``."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO

__all__ = ["atomic_write_file"]


def atomic_write_file(target: str | os.PathLike, write: Callable[[IO], None], *, text: bool = False) -> Path:
    """Call ``write(fh)`` on a temporary file in ``target``'s folder, then move it onto ``target``.

    A failure (or an interrupt) leaves ``target`` as it was and removes the
    temporary file.  ``text``: the file is opened for UTF-8 text, else binary.
    """
    target = Path(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with (os.fdopen(fd, "w", encoding="utf-8") if text else os.fdopen(fd, "wb")) as fh:
            write(fh)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
