"""Where ``s2a-view`` writes: an ``-o`` path checked before any work, write errors that name that path
and the file system's reason (never the hidden ``.NAME.partial`` file written first), and Ctrl-C or
SIGTERM that stop a command with that partial file removed."""

from __future__ import annotations

import errno
import os
import signal
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from capture.command import Terminated
from capture.errors import InputError
from capture.file_lock import NoLocks, lock_in_place
from capture.take import make_out_dir


def prepare_output(path: str | Path) -> Path:
    """``path`` ready to be written: not a folder, its folder created (``InputError`` otherwise)."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder: give the output's file name", path)
    make_out_dir(path.parent)
    return path


def refuse_writing_over_inputs(
    path: str | Path, inputs: Iterable[tuple[str | Path | None, str]]
) -> list[str]:
    """An ``InputError`` when the output ``path`` is a file this command reads (``inputs``: (file, what it
    is) pairs, None for none): ``render -o ref.mp4 --video ref.mp4`` would replace the user's video (or
    the speech given with ``--audio``) with the render, once the render is done. Compared as files
    (``os.path.samefile``), so that another spelling of the path or an input that links to it is seen
    too; an output that is itself a symbolic link is not checked: the render replaces the link, not the
    file it points to. Likewise an output that is a hard link to an input under another name: the render
    is a new file renamed over that name, and the input keeps its content under the name it was read by
    (unless that is the only name the file has: a bind mount shows one file at two paths). Returns a
    note for each such link."""
    path = Path(path)
    if path.is_symlink() or not path.is_file():
        return []
    notes = []
    for file, what in inputs:
        if file is None:
            continue
        try:
            if not os.path.samefile(path, file):
                continue
            read_as = Path(file).resolve()  # the name whose file the render would replace
            other_name = path.stat().st_nlink > 1 and not (
                os.path.samefile(path.parent, read_as.parent)
                and path.name.casefold() == read_as.name.casefold()
            )
        except OSError:  # not on disk (an archive's member, named as the archive shows it)
            continue
        if not other_name:
            raise InputError(f"is {what}, read by this command: give the output another name", path)
        notes.append(
            f"{path} is a hard link to {what} ({file}): the render replaces it with a new file, and {file} "
            "keeps its content"
        )
    return list(dict.fromkeys(notes))


def lock_partial(tmp: Path, path: Path, attempts: int = 10) -> int:
    """The partial file ``tmp`` of the video ``path`` opened (created if needed) and locked (``flock``)
    until the descriptor returned is closed: another command writing ``path`` at once is an
    ``InputError`` naming ``path``. A command that opened ``tmp`` just as the one before it renamed ``tmp``
    into place locks the file at ``tmp`` anew (``lock_in_place``), not the finished output. A file system
    without locks: the file is written unguarded."""
    flags = os.O_RDWR | os.O_CREAT
    with writing(path, "video"):
        try:
            taken = lock_in_place(tmp, flags, attempts)
        except NoLocks:
            return os.open(tmp, flags, 0o644)
    if taken is None:
        raise InputError(
            f"another command is writing this video right now (its {tmp.name} is locked): let it finish or "
            "give another name",
            path,
        )
    return taken[0]


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
        elif exc.errno == errno.ENAMETOOLONG and (size := len(os.fsencode(path.name))) <= (
            limit := _name_max(path.parent)
        ):
            # The name fits; the hidden partial file's, which adds ".partial" and a dot, does not.
            reason = (
                f"its name of {size} bytes leaves no room for the hidden .NAME.partial file it is written as "
                f"first (names here take at most {limit} bytes): give a shorter name"
            )
        else:
            reason = exc.strerror or str(exc).splitlines()[0]
        raise InputError(f"cannot write the {what}: {reason}", path) from None


def _name_max(folder: Path) -> int:
    """The longest file name (bytes) ``folder``'s file system takes (255 where it does not say)."""
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):  # no such folder, or no pathconf (Windows)
        return 255


_stopped_by: list[int] = []  # the signal that stopped the command, once one has
_between_frames = False  # while rendering: a signal is raised at the next raise_if_stopped


def _stop(signum: int, frame: object) -> None:
    _stopped_by.append(signum)
    if not _between_frames:
        raise_if_stopped()


def raise_if_stopped() -> None:
    """Raise the stop a signal asked for: ``Terminated`` for SIGTERM, else ``KeyboardInterrupt``."""
    if _stopped_by:
        raise Terminated() if _stopped_by[0] == signal.SIGTERM else KeyboardInterrupt()


@contextmanager
def stops_between_frames() -> Iterator[None]:
    """Inside, a signal only asks to stop, and ``raise_if_stopped`` (between frames, and on leaving)
    stops: VTK calls back into Python while it renders and swallows an exception raised there (it logs
    "Failure when calling method: ProcessRequest" over many lines and renders on)."""
    global _between_frames
    _between_frames = True
    try:
        yield
    finally:
        _between_frames = False
    raise_if_stopped()


@contextmanager
def stopped_by_signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise their stop (``raise_if_stopped``) while the block runs, so that the
    ``.partial`` file being written is removed on the way out. A signal the caller handles itself is
    left alone, as are threads other than the main one (which cannot set handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _stopped_by.clear()
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(sig) in (signal.SIG_DFL, signal.default_int_handler):
            previous[sig] = signal.signal(sig, _stop)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        _stopped_by.clear()  # a signal of this block is not one of a later block (tests run many)
