"""Writing files and folders so that a reader never sees half of one.

Everything is assembled under a hidden name beside its target (``.NAME.partial`` for files,
``.NAME.partial-XXXX`` for folders), flushed to disk, and renamed into place; on error the partial
is removed. Every stage writes through these.
"""

from __future__ import annotations

import ctypes
import errno
import functools
import json
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from .file_lock import fcntl, try_lock


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
    """Yield a hidden temporary folder beside ``target``; on success it replaces ``target``, on error it
    is removed.

    The new folder is swapped in in one step where the system can (Linux's ``RENAME_EXCHANGE``), so the
    old ``target`` stays visible until the new one is in place; elsewhere it is moved aside to
    ``.NAME.old-XXXX/take`` for the moment between two renames. The folder being written is locked
    (``flock``) while it is; leftovers of earlier writes that were killed are removed first, and an old
    ``target`` that such a write left aside is put back when ``target`` is missing
    (``clear_leftovers``)."""
    clear_leftovers(target)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
    lock = _hold(tmp)
    try:
        yield tmp
        os.chmod(tmp, 0o755)
        if os.path.lexists(target) and _exchange(tmp, target):
            shutil.rmtree(tmp, ignore_errors=True)  # now the old target
        elif os.path.lexists(target):
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
            old_lock = _hold(old)
            try:
                os.replace(target, old / "take")
                try:
                    os.replace(tmp, target)
                except BaseException:
                    os.replace(old / "take", target)  # the old take back where it was
                    raise
                shutil.rmtree(old, ignore_errors=True)
            finally:
                _release(old_lock)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        _release(lock)


# What ``tempfile.mkdtemp`` adds to ``.NAME.partial-`` and ``.NAME.old-``: the leftovers of a write of
# ``NAME`` (and not of a take named ``NAME.old-1``, whose own would be ``.NAME.old-1.old-XXXX``).
_LEFTOVER = re.compile(r"(partial|old)-[a-z0-9_]{8}")


def clear_leftovers(target: Path) -> None:
    """Remove the hidden folders that writes of ``target`` killed mid-way left beside it
    (``.NAME.partial-XXXX``, ``.NAME.old-XXXX``); those a live writer holds locked are left alone. When
    ``target`` is missing, the old folder such a write had moved aside is put back first."""
    if fcntl is None:  # pragma: no cover - without flock a live writer cannot be told from a dead one
        return
    prefix = f".{target.name}."
    try:
        with os.scandir(target.parent) as entries:
            names = sorted(e.name for e in entries if e.name.startswith(prefix))
    except OSError:
        return
    for folder in [target.parent / n for n in names if _LEFTOVER.fullmatch(n[len(prefix) :])]:
        lock = _hold(folder)
        if lock is None:  # held by a live writer, gone already, or no locks to tell
            continue
        try:
            moved_aside = folder / "take"
            if folder.name.startswith(prefix + "old-") and os.path.lexists(moved_aside):
                if not os.path.lexists(target):
                    os.replace(moved_aside, target)
            shutil.rmtree(folder, ignore_errors=True)
        except OSError:
            pass  # left for a later write
        finally:
            _release(lock)


def _hold(folder: Path) -> int | None:
    """An exclusive lock on ``folder`` (its open descriptor, to close), or None when another process
    holds one, the folder cannot be opened or its file system has no locks."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return None
    try:
        if try_lock(fd):
            return fd
    except OSError:
        pass
    os.close(fd)
    return None


def _release(lock: int | None) -> None:
    if lock is not None:
        os.close(lock)


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


@functools.cache
def _renameat2() -> Any:
    """libc's ``renameat2`` (Linux, glibc 2.28 and later), or None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        func = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    func.restype = ctypes.c_int
    return func


def _exchange(a: Path, b: Path) -> bool:
    """Swap the paths ``a`` and ``b`` in one step; False where the system or file system cannot."""
    func = _renameat2()
    if func is None:
        return False
    if func(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP, errno.EPERM):
        return False  # an old kernel, a file system without exchange, a sandbox that forbids the call
    raise OSError(err, os.strerror(err), str(b))
