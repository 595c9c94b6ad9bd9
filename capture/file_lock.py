"""Advisory locks on files (``flock``) that say a folder is being written: ``listen``'s session, a
dataset build's output, a training run. The kernel drops a lock when its process ends, however it ends,
so a killed writer never blocks the next one. Where the platform has no ``flock`` (Windows) every lock
is granted and nothing is ever held.
"""

from __future__ import annotations

import errno
import itertools
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from .command import stops_deferred
from .errors import InputError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # Windows has none
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


PID_WAIT_S = 0.5  # how long a refused command waits for the lock's holder to have written its pid


def lock_holder(path: str | Path, wait_s: float = PID_WAIT_S) -> str:
    """`` (pid N)``: the process that wrote its pid into the lock file ``path``, or ``""`` when unknown.
    A holder writes its pid right after taking the lock: one refused in that moment waits ``wait_s``."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            pid = Path(path).read_text().strip()
        except (OSError, UnicodeDecodeError):
            pid = ""
        if pid.isdigit() or time.monotonic() >= deadline:
            return f" (pid {pid})" if pid.isdigit() else ""
        time.sleep(0.02)


def another_writer(command: str, folder: Path) -> Callable[[str], Exception]:
    """The ``refused`` of ``holding`` for a command that writes into an output folder: "another
    COMMAND (pid N) is writing into FOLDER: wait for it or choose another -o"."""

    def refused(holder: str) -> Exception:
        return InputError(
            f"another {command}{holder} is writing into {folder}: wait for it or choose another -o"
        )

    return refused


@contextmanager
def holding(
    path: Path,
    refused: Callable[[str], Exception],
    remove: Callable[[bool], bool] = lambda created: True,
    optional: bool = False,
) -> Iterator[bool]:
    """Hold an exclusive lock on the lock file ``path`` (created if needed, this process's pid written
    into it) while the block runs: the one writer of a folder (an import's output, an align's, a
    dataset build's, a training run). Another process holding it: ``refused(lock_holder(path))`` is
    raised at once. ``remove(created)`` (``created``: this lock made the file) says whether the file is
    removed at the end, while still held (one that opened it meanwhile finds it gone and locks the
    file at that path anew). A lock
    file that cannot be opened or locked raises its ``OSError``, or with ``optional`` the block runs
    without a lock (a read-only folder, a file system without locks: the writes then fail themselves).
    The block is given whether it holds the lock."""
    taken = None
    try:
        # Ctrl-C and SIGTERM wait until the lock is noted here: met between its taking and the ``try``,
        # or as the pid is written, a stop left the lock held and its file behind
        with stops_deferred():
            taken = _lock(path, refused, optional) if fcntl is not None else None
            if taken is not None:
                with suppress(OSError):  # the pid is for others' messages only: a full disk stops nothing
                    os.ftruncate(taken[0], 0)
                    os.pwrite(taken[0], f"{os.getpid()}\n".encode(), 0)
        yield taken is not None
    finally:
        if taken is not None:
            fd, created = taken
            with stops_deferred():  # a second Ctrl-C cuts neither the file's removal nor the lock's release
                if remove(created):
                    with suppress(OSError):
                        path.unlink()
                os.close(fd)  # releases the lock


def _lock(path: Path, refused: Callable[[str], Exception], optional: bool) -> tuple[int, bool] | None:
    try:
        taken = lock_in_place(path, os.O_RDWR | os.O_CREAT | NOFOLLOW)
    except OSError:  # not opened, or a file system without locks
        if optional:
            return None
        raise
    if taken is None:
        raise refused(lock_holder(path))
    return taken


class NoLocks(OSError):
    """The file system takes no locks (``flock`` refused for another reason than a holder)."""


def lock_in_place(path: Path, flags: int, attempts: int | None = None) -> tuple[int, bool] | None:
    """The file at ``path`` opened (``os.open`` with ``flags``, created with mode 0o644 by ``O_CREAT``) and
    locked exclusively without waiting: its descriptor and whether this call created the file; None when
    another process holds the lock. Opening and locking are two steps: the one who held it may have
    removed or renamed the file between them (its work done), leaving the lock on a file no longer at
    ``path``; the file now there is then opened and locked instead, up to ``attempts`` times (None: until
    one holds; then None). The open's ``OSError`` is raised, as ``NoLocks`` is on a file system without
    locks; the descriptor is never left open, also when a stop signal raises on the way."""
    tries = itertools.count() if attempts is None else range(attempts)
    for _ in tries:
        created = not os.path.lexists(path)
        fd = os.open(path, flags, 0o644)
        try:
            try:
                locked = try_lock(fd)
            except OSError as exc:
                raise NoLocks(exc.errno, exc.strerror) from exc
            if locked and _is_at(fd, path, follow_symlinks=not flags & NOFOLLOW):
                return fd, created
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)
        if not locked:
            return None
    return None


def _is_at(fd: int, path: Path, follow_symlinks: bool) -> bool:
    """Whether the open file ``fd`` is the file at ``path`` (none there: False)."""
    try:
        at = os.stat(path, follow_symlinks=follow_symlinks)
    except FileNotFoundError:
        return False
    opened = os.fstat(fd)
    return (opened.st_ino, opened.st_dev) == (at.st_ino, at.st_dev)
