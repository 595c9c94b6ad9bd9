"""Where ``s2a-view`` writes: an ``-o`` path checked before any work, and write errors that name that
path and the file system's reason (never the hidden ``.NAME.partial`` file written first)."""

from __future__ import annotations

import errno
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from capture.errors import InputError
from capture.take import make_out_dir


def prepare_output(path: str | Path) -> Path:
    """``path`` ready to be written: not a folder, its folder created (``InputError`` otherwise)."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder: give the output's file name", path)
    make_out_dir(path.parent)
    return path


@contextmanager
def writing(path: str | Path, what: str) -> Iterator[None]:
    """Turn an ``OSError`` while writing ``what`` to ``path`` into an ``InputError`` naming ``path``."""
    path = Path(path)
    try:
        yield
    except OSError as exc:
        if exc.errno == errno.ENOENT and path.parent.is_dir():
            reason = f"{path.parent} does not take new files"  # e.g. /proc, where open() says ENOENT
        elif exc.errno == errno.EISDIR or path.is_dir():
            reason = "a folder of that name is in the way"
        else:
            reason = exc.strerror or str(exc).splitlines()[0]
        raise InputError(f"cannot write the {what}: {reason}", path) from None
