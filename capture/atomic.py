"""Writing files and folders so that a reader never sees half of one.

Everything is assembled under a hidden name beside its target (``.NAME.partial`` for files,
``.NAME.partial-XXXX`` for folders), flushed to disk, and renamed into place; on error the partial is
removed. A device or a pipe, such as ``/dev/null``, is written into, not replaced (``written_into``):
``atomic_write`` writes straight into it, and a file that must be finished first (an ONNX file checked
before it is given, a checkpoint) is assembled in a private temporary folder, not beside it (``/dev``
takes no new files from a normal user). So is the process's own standard output, even a file
(``-o /dev/stdout > out.csv``). Every stage writes through these.
"""

from __future__ import annotations

import atexit
import ctypes
import errno
import functools
import json
import os
import re
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager, nullcontext
from contextvars import ContextVar
from pathlib import Path
from typing import IO, Any

from .command import output_on_stdout, stops_at_once, stops_deferred
from .errors import InputError
from .file_lock import fcntl, try_lock


def partial_path(path: Path, suffix: str = "") -> Path:
    """The hidden name a file is assembled under beside ``path`` before it is renamed into place
    (``.NAME.partial``, then ``suffix``: readers and ``find_takes`` skip hidden files). For a ``path``
    that is written into (``written_into``: ``/dev/null``, a FIFO), the same name in this process's
    private temporary folder: the device's folder need not take new files."""
    name = f".{path.name}.partial{suffix}"
    return _private_folder() / name if written_into(path) else path.with_name(name)


def written_into(path: Path) -> bool:
    """Whether ``path`` is a character device or a FIFO (``/dev/null``, ``/dev/stdout`` to a pipe), or
    this process's standard output or error whatever it is (``/dev/stdout`` to a file): an output
    written into, never replaced by a renamed file (root may replace a device, or the link
    ``/dev/stdout`` itself; another user cannot even make a partial file beside it)."""
    try:
        found = os.stat(path)
    except OSError:
        return False
    return stat.S_ISCHR(found.st_mode) or stat.S_ISFIFO(found.st_mode) or _standard_stream(found) is not None


def _standard_stream(found: os.stat_result) -> int | None:
    """The descriptor, 1 or 2, of this process's standard output or error that is the file ``found``
    (``os.stat``), or None."""
    for fd in (1, 2):
        try:
            stream = os.fstat(fd)
        except OSError:
            continue
        if (stream.st_dev, stream.st_ino) == (found.st_dev, found.st_ino):
            return fd
    return None


def _opened_into(path: Path, mode: str, **open_kwargs: Any) -> IO:
    """``path``, written into (``written_into``), opened for writing. This process's standard output or
    error is written through a copy of its descriptor: opened again by name, a file was written from
    its start, over what the process prints there, and a socket cannot be opened by name at all."""
    fd = _standard_stream(os.stat(path))
    if fd is None:
        with stops_at_once():  # a FIFO opens once a reader opens it: a stop a render only noted waited
            return open(path, mode, **open_kwargs)
    sys.stdout.flush()
    sys.stderr.flush()
    if fd == 1:
        output_on_stdout()
    return open(os.dup(fd), mode, **open_kwargs)


_PRIVATE_PREFIX = "s2a-partial-"


@functools.cache
def _private_folder() -> Path:
    """A temporary folder of this process's own (mode 700), removed when it exits. It is held locked
    (``flock``) while the process lives: the folders of processes killed outright (SIGKILL, which runs
    no exit handler) are the unlocked ones, removed here by the next process making one."""
    temp = Path(tempfile.gettempdir())
    for leftover in temp.glob(f"{_PRIVATE_PREFIX}*") if fcntl is not None else []:
        lock = _hold(leftover)  # None: a live process's, another user's, or gone already
        if lock is not None:
            shutil.rmtree(leftover, ignore_errors=True)
            _release(lock)
    while True:
        folder = Path(tempfile.mkdtemp(prefix=_PRIVATE_PREFIX, dir=temp))
        held = os.open(folder, os.O_RDONLY)  # left open, so locked, until the process exits
        try:
            mine = try_lock(held)
        except OSError:
            mine = True  # a file system without locks: nothing is cleared there either
        if mine:
            atexit.register(shutil.rmtree, folder, ignore_errors=True)
            return folder
        os.close(held)  # locked first by another process clearing leftovers, which removes it


@contextmanager
def atomic_write(
    path: str | Path, mode: str = "wb", *, name_failures: bool = False, **open_kwargs: Any
) -> Iterator[IO]:
    """Open ``.NAME.partial`` beside ``path`` for writing; on success fsync it and rename it over
    ``path``. A ``path`` that is a device or a pipe (``written_into``) is opened and written straight
    into: there is nothing to replace. ``name_failures``: a failure to write is an ``InputError`` naming
    ``path`` (``naming_failures``), not an ``OSError``."""
    path = Path(path)
    with naming_failures(path) if name_failures else nullcontext():
        if written_into(path):
            with _opened_into(path, mode, **open_kwargs) as into:
                yield into
            return
        tmp = partial_path(path)
        try:
            with open(tmp, mode, **open_kwargs) as f:
                yield f
                f.flush()
                os.fsync(f.fileno())
            put_in_place(tmp, path)
        except BaseException:
            with stops_deferred():  # a second Ctrl-C cuts no removal short
                tmp.unlink(missing_ok=True)
            raise


def put_in_place(tmp: Path, path: Path) -> None:
    """Rename the finished ``tmp`` over ``path``; a ``path`` that is a device or a pipe (``/dev/null``,
    ``/dev/full``, a FIFO) is written into instead and ``tmp`` (``partial_path``'s, in a private folder)
    removed: renaming replaced the device itself with a file (root may), and a full ``/dev/full`` said
    nothing. A block device (a disk or a partition) is refused: an output written over it would destroy
    what it holds."""
    try:
        found = os.stat(path)
    except OSError:
        found = None  # no such file yet, or one that cannot be looked at: the rename says what is wrong
    if found is not None and stat.S_ISBLK(found.st_mode):
        raise OSError(errno.EEXIST, "a disk or partition (a block device): not written over", str(path))
    # a file or folder is replaced, unless it is this process's standard output or error (``written_into``)
    if found is None or (
        (stat.S_ISREG(found.st_mode) or stat.S_ISDIR(found.st_mode)) and _standard_stream(found) is None
    ):
        os.replace(tmp, path)
        return
    with open(tmp, "rb") as finished, _opened_into(path, "wb") as into:
        shutil.copyfileobj(finished, into)
    tmp.unlink()


def write_json_atomic(
    path: str | Path, data: Any, compact: bool = False, allow_nan: bool = False, name_failures: bool = False
) -> None:
    """JSON written with ``atomic_write``: indented with a final newline, or ``compact`` on one line."""
    with atomic_write(path, "w", encoding="utf-8", name_failures=name_failures) as f:
        if compact:
            json.dump(data, f, separators=(",", ":"), allow_nan=allow_nan)
        else:
            json.dump(data, f, indent=2, allow_nan=allow_nan)
            f.write("\n")


@contextmanager
def naming_failures(path: str | Path) -> Iterator[Path]:
    """Make a failure to write ``path`` one line naming it, "PATH: cannot be written: REASON" (an
    ``InputError``): ``write()``, ``fsync()`` and ``close()`` fail (a full disk, a file too large) naming
    no file, and ``open()`` names the hidden ``.NAME.partial`` the file is assembled under. An error
    naming another file (one read while ``path`` is written) is left as it is: it names that file.
    For writers other than ``atomic_write`` (its ``name_failures`` option applies this)."""
    path = Path(path)
    try:
        yield path
    except OSError as exc:
        if exc.filename not in (None, str(path), str(partial_path(path))):
            raise
        raise InputError(f"cannot be written: {exc.strerror or exc}", path) from None


@contextmanager
def folder_in_place(target: Path) -> Iterator[Path]:
    """Yield a hidden temporary folder beside ``target``; on success it replaces ``target`` (inside
    ``all_or_none``: when that block ends), on error it is removed.

    The new folder is swapped in in one step where the system can (Linux's ``RENAME_EXCHANGE``), so the
    old ``target`` stays visible until the new one is in place; elsewhere it is moved aside to
    ``.NAME.old-XXXX/take`` for the moment between two renames. The folder being written is locked
    (``flock``) while it is; leftovers of earlier writes that were killed are removed first, and an old
    ``target`` that such a write left aside is put back when ``target`` is missing
    (``clear_leftovers``)."""
    renames = _together.get()
    if renames is None:
        with _folder_in_place(target) as tmp:
            yield tmp
        return
    with ExitStack() as this:
        yield this.enter_context(_folder_in_place(target))  # an error here removes this folder at once
        renames.push(this.pop_all())  # renamed into place with the others at the end of all_or_none


_together: ContextVar[ExitStack | None] = ContextVar("_together", default=None)


@contextmanager
def all_or_none() -> Iterator[None]:
    """Inside, the folders written with ``folder_in_place`` (takes written with ``write_take``) wait
    and are renamed into place when the block ends, one right after another; if it ends in an error,
    none is (their hidden folders are removed). Only a kill between those renames can leave some of
    them in place and not the others."""
    if _together.get() is not None:  # within an outer all_or_none: that one renames
        yield
        return
    with ExitStack() as renames:
        token = _together.set(renames)
        try:
            yield
        finally:
            _together.reset(token)


@contextmanager
def _folder_in_place(target: Path) -> Iterator[Path]:
    clear_leftovers(target)
    tmp = lock = None
    try:
        # Ctrl-C and SIGTERM wait until the folder is noted here, locked: met as it was made, a stop left it
        with stops_deferred():
            tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))
            lock = _hold(tmp)
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
        if tmp is not None:
            with stops_deferred():  # a second Ctrl-C cuts no removal short
                shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        _release(lock)


# A leftover of a write of ``NAME``: what ``tempfile.mkdtemp`` adds to ``.NAME.partial-`` and ``.NAME.old-``
# (the suffix's length is fixed, so ``.T.old-1.old-XXXXXXXX`` is one of the take ``T.old-1``, not of ``T``).
_LEFTOVER = re.compile(r"\.(?P<target>.+)\.(partial|old)-[a-z0-9_]{8}")

# The leftovers listed on entering a ``batch_of_writes``: {folder: {NAME: [leftover names]}}
_listed: dict[Path, dict[str, list[str]]] = {}


@contextmanager
def batch_of_writes(folder: str | Path) -> Iterator[None]:
    """Inside, the writes of folders in ``folder`` (``folder_in_place``) find the leftovers of killed
    writes in one listing of ``folder`` made on entering, not in one listing each: N takes written cost
    O(N), not O(N²). A leftover that appears meanwhile (of another process's write killed during the
    batch) is cleared by the next write of its take after the batch. Worker processes forked inside
    inherit the listing."""
    key = Path(os.path.abspath(folder))
    if key in _listed or fcntl is None:  # an outer batch's listing serves; or no leftovers to clear
        yield
        return
    _listed[key] = _leftovers_in(key)
    try:
        yield
    finally:
        del _listed[key]


def _leftovers_in(folder: Path) -> dict[str, list[str]]:
    """The leftovers in ``folder`` by the name of the target written, each list sorted."""
    found: dict[str, list[str]] = {}
    try:
        with os.scandir(folder) as entries:
            for name in sorted(e.name for e in entries if e.name.startswith(".")):
                if m := _LEFTOVER.fullmatch(name):
                    found.setdefault(m["target"], []).append(name)
    except OSError:
        pass
    return found


def clear_leftovers(target: Path) -> None:
    """Remove the hidden folders that writes of ``target`` killed mid-way left beside it
    (``.NAME.partial-XXXX``, ``.NAME.old-XXXX``); those a live writer holds locked are left alone. When
    ``target`` is missing, the old folder such a write had moved aside is put back first. The folder
    is listed for this, or once for a whole ``batch_of_writes``."""
    if fcntl is None:  # pragma: no cover - without flock a live writer cannot be told from a dead one
        return
    listed = _listed.get(Path(os.path.abspath(target.parent)))
    if listed is None:
        listed = _leftovers_in(target.parent)
    for folder in [target.parent / n for n in listed.get(target.name, [])]:
        lock = _hold(folder)
        if lock is None:  # held by a live writer, gone already, or no locks to tell
            continue
        try:
            moved_aside = folder / "take"
            if folder.name.startswith(f".{target.name}.old-") and os.path.lexists(moved_aside):
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
