"""Worker processes that never outlive the command that started them, shared by ``s2a-align`` and the
dataset build: each exits as soon as its parent is gone, leaves Ctrl-C to the parent, and starts with
Ctrl-C and SIGTERM held; a system refusing to start them is one error."""

from __future__ import annotations

import errno
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager

from .errors import S2AError

STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}  # what a worker leaves to the process that started it
# File descriptors this process opens at once to start one worker through a fork server (CPython 3.11's
# forkserver.connect_to_new_process): the socket to the server and two pipes. The first start also leaves
# two open first (the fork server's and the resource tracker's pipes); each worker then holds two.
WORKER_START_FDS = 5
FIRST_START_FDS = WORKER_START_FDS + 2


def exit_with_parent(parent_pid: int) -> None:
    """Worker initializer: a watcher thread ends this worker as soon as the process that started it is
    gone (SIGKILL, a crash), instead of computing on for nobody, writing outputs and holding its stdout
    and stderr open. A pidfd (Linux 5.3) says so at once; elsewhere the pid is polled. Ctrl-C is left
    to that process (which stops its workers) and SIGTERM ends the worker at once, whatever handlers
    a forked worker inherited."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)  # held while the worker started
    try:
        pidfd = os.pidfd_open(parent_pid)
    except ProcessLookupError:
        os._exit(1)
    except (AttributeError, OSError):
        pidfd = None

    def watch() -> None:
        if pidfd is not None:
            import select

            select.select([pidfd], [], [])
        else:
            while True:
                time.sleep(0.5)
                if not process_runs(parent_pid):
                    break
        os._exit(1)

    threading.Thread(target=watch, name="s2a-exit-with-parent", daemon=True).start()


def process_runs(pid: int) -> bool:
    """Whether process ``pid`` exists (signal 0 only asks); another user's process does."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: another user's process
        return True
    return True


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """End a pool's workers now: pending calls cancelled, running ones terminated. A command that stops
    (an error, Ctrl-C, SIGTERM) leaves no worker computing on and holding its output open."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        if p.is_alive():
            p.terminate()
    for p in processes:
        p.join(5)
        if p.is_alive():  # pragma: no cover - SIGTERM ignored
            p.kill()
            p.join(1)


@contextmanager
def worker_pool(jobs: int, context) -> Iterator[ProcessPoolExecutor]:
    """``jobs`` worker processes (started by ``submit_all``) that never outlive this process: each
    exits as soon as this one is gone (``exit_with_parent``), and an exception inside (an error, Ctrl-C,
    SIGTERM) ends them at once (``stop_pool``) rather than waiting for their calls to finish."""
    pool = ProcessPoolExecutor(
        max_workers=jobs, mp_context=context, initializer=exit_with_parent, initargs=(os.getpid(),)
    )
    try:
        yield pool
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown()


@contextmanager
def _stop_signals_held() -> Iterator[None]:
    """Ctrl-C and SIGTERM held (blocked in this thread) inside, while worker processes start: a forked
    worker, a fork server and the workers it forks inherit the block, so that neither signal lands
    in them before they are ready (``exit_with_parent`` then ignores Ctrl-C, which this process
    handles by stopping them, and lets SIGTERM end them); a signal that came meanwhile is raised
    here on leaving."""
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - Windows
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def _room_to_start_a_worker(first: bool) -> None:
    """``OSError`` (EMFILE) unless this process can open the descriptors that starting one more worker
    opens (``WORKER_START_FDS``, ``FIRST_START_FDS`` for a pool's first). Python 3.11's fork server dies
    with a traceback of its own (an EOFError in ``forkserver.main``) when a start fails after connecting
    to it, as at its ``os.pipe`` under a low ``ulimit -n``: the start is refused before it connects."""
    held: list[int] = []
    try:
        held.append(os.open(os.devnull, os.O_RDONLY))
        while len(held) < (FIRST_START_FDS if first else WORKER_START_FDS):
            held.append(os.dup(held[0]))
    finally:
        for fd in held:
            os.close(fd)


def submit_all(pool: ProcessPoolExecutor, fn: Callable, calls: Sequence[tuple]) -> list[Future]:
    """``fn(*args)`` for each of ``calls`` submitted to ``pool``; its worker processes start here,
    Ctrl-C and SIGTERM held meanwhile. A system refusing to start them (too many open files, too little
    memory) is one ``S2AError``."""
    # With a fork server (the build's), each of the first submits may start a worker; a forking pool
    # (align's) starts them all at the first and reports a start refused (EMFILE) itself.
    forks = getattr(getattr(pool, "_mp_context", None), "get_start_method", lambda: "")() == "fork"
    starts = 0 if forks else getattr(pool, "_max_workers", len(calls))
    futures = []
    try:
        with _stop_signals_held():
            for k, args in enumerate(calls):
                if k < starts:
                    _room_to_start_a_worker(first=k == 0)
                futures.append(pool.submit(fn, *args))
            return futures
    except OSError as exc:
        hint = "; or raise the open-file limit (ulimit -n)" if exc.errno == errno.EMFILE else ""
        raise S2AError(
            f"cannot start the worker processes ({exc.strerror or exc}): run with fewer --jobs{hint}"
        ) from None
