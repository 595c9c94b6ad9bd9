"""Where ``s2a-view`` writes: an ``-o`` path checked before any work, write errors that name that path
and the file system's reason (never the hidden ``.NAME.partial`` file written first), and Ctrl-C or
SIGTERM that stop a command with that partial file removed."""

from __future__ import annotations

import errno
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from capture.command import Terminated
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
