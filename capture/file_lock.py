"""Advisory locks on files (``flock``) that say a folder is being written: ``listen``'s session, a
dataset build's output, a training run. The kernel drops a lock when its process ends, however it ends,
so a killed writer never blocks the next one. Where the platform has no ``flock`` (Windows) every lock
is granted and nothing is ever held.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

HELD = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)  # what flock says when another process holds it


def try_lock(fd: int, shared: bool = False) -> bool:
    """Take an exclusive (or ``shared``) lock on the open file ``fd`` without waiting: False when
    another process holds a lock that conflicts. Other failures (a file system without locks) raise
    ``OSError``."""
    if fcntl is None:  # pragma: no cover - Windows
        return True
    try:
        fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in HELD:
            return False
        raise
    return True


def held_elsewhere(path: str | Path) -> bool:
    """Whether another process holds an exclusive lock on the file ``path`` right now (False when the file
    cannot be opened, or locks cannot be taken on it)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        return not try_lock(fd, shared=True)
    except OSError:
        return False
    finally:
        os.close(fd)
