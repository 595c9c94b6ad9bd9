"""Writing files and folders so that a reader never sees half of one.

Everything is assembled under a hidden name beside its target (``.NAME.partial`` for files,
``.NAME.partial-XXXX`` for folders), flushed to disk, and renamed into place; on error the partial
is removed. Every stage writes through these.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any


def partial_path(path: Path) -> Path:
    """The hidden name a file is assembled under beside ``path`` before it is renamed into place
    (``.NAME.partial``: readers and ``find_takes`` skip hidden files)."""
    return path.with_name(f".{path.name}.partial")


@contextmanager
def atomic_write(path: str | Path, mode: str = "wb", **open_kwargs: Any) -> Iterator[IO]:
    """Open ``.NAME.partial`` beside ``path`` for writing; on success fsync it and rename it over
    ``path``."""
    path = Path(path)
    tmp = partial_path(path)
    try:
        with open(tmp, mode, **open_kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json_atomic(path: str | Path, data: Any, compact: bool = False, allow_nan: bool = False) -> None:
    """JSON written with ``atomic_write``: indented with a final newline, or ``compact`` on one line."""
    with atomic_write(path, "w", encoding="utf-8") as f:
        if compact:
            json.dump(data, f, separators=(",", ":"), allow_nan=allow_nan)
        else:
            json.dump(data, f, indent=2, allow_nan=allow_nan)
            f.write("\n")


@contextmanager
def folder_in_place(target: Path) -> Iterator[Path]:
    """Yield a hidden temporary folder beside ``target``; on success it replaces ``target`` (renames,
    so readers never see half a folder), on error it is removed."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o755)
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
            os.replace(target, old / "take")
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
