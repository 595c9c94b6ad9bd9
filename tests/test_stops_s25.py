"""Stops (Ctrl-C, SIGTERM) met at the edges of the toolkit's clean-ups: as a lock, a partial file or folder
is made but not yet noted where its ``finally`` finds it, or as a ``finally`` removes it and a second
Ctrl-C comes. Each left its file, folder or lock behind (or a signal handler that swallowed its signal
from then on). A signal is raised inside the real call at that point, as a stop landing there would be
met."""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
from pathlib import Path

import pytest

import capture.atomic as atomic
from capture.command import Terminated, stops_deferred
from capture.file_lock import another_writer, holding


@pytest.fixture(autouse=True)
def _python_ctrl_c():
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def _stop_in(monkeypatch, owner, name: str, as_it: str = "starts") -> None:
    """The next call of ``owner.name`` (a real call, made all the same) meets Ctrl-C as it starts or as it
    returns."""
    real = getattr(owner, name)

    def met(*args, **kwargs):
        monkeypatch.setattr(owner, name, real)
        if as_it == "starts":
            signal.raise_signal(signal.SIGINT)
        done = real(*args, **kwargs)
        if as_it == "returns":
            signal.raise_signal(signal.SIGINT)
        return done

    monkeypatch.setattr(owner, name, met)


def _lock_free(lock: Path) -> bool:
    with holding(lock, another_writer("test", lock.parent)) as alone:
        return alone


def test_a_second_ctrl_c_as_a_lock_file_goes_leaves_neither_it_nor_the_lock(tmp_path, monkeypatch):
    lock = tmp_path / ".import.lock"
    _stop_in(monkeypatch, Path, "unlink")  # the second Ctrl-C, as the lock file is removed
    with pytest.raises(KeyboardInterrupt), holding(lock, another_writer("test", tmp_path)):
        signal.raise_signal(signal.SIGINT)
    assert not lock.exists()
    assert _lock_free(lock)  # no descriptor left open holding it


def test_a_stop_as_the_lock_holder_writes_its_pid_leaves_neither_file_nor_lock(tmp_path, monkeypatch):
    lock = tmp_path / ".build.lock"
    _stop_in(monkeypatch, os, "pwrite", "returns")
    with pytest.raises(KeyboardInterrupt), holding(lock, another_writer("test", tmp_path)):
        pytest.fail("the block ran after the stop")
    assert not lock.exists()
    assert _lock_free(lock)


def test_a_stop_as_a_partial_folder_is_made_leaves_no_partial_folder(tmp_path, monkeypatch):
    _stop_in(monkeypatch, tempfile, "mkdtemp", "returns")
    with pytest.raises(KeyboardInterrupt), atomic.folder_in_place(tmp_path / "take") as tmp:
        (tmp / "frames.npz").write_bytes(b"never")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_second_ctrl_c_as_a_partial_folder_goes_leaves_no_partial_folder(tmp_path, monkeypatch):
    with pytest.raises(KeyboardInterrupt), atomic.folder_in_place(tmp_path / "take") as tmp:
        (tmp / "frames.npz").write_bytes(b"never")
        _stop_in(monkeypatch, shutil, "rmtree")
        signal.raise_signal(signal.SIGINT)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_second_ctrl_c_as_a_partial_file_goes_leaves_no_partial_file(tmp_path, monkeypatch):
    with pytest.raises(KeyboardInterrupt), atomic.atomic_write(tmp_path / "stats.json") as f:
        f.write(b"never")
        _stop_in(monkeypatch, Path, "unlink")
        signal.raise_signal(signal.SIGINT)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "handler_set, stop",
    [(2, signal.SIGTERM), (4, signal.SIGINT)],
    ids=["sigterm-as-stops-are-held-back", "ctrl-c-as-handlers-come-back"],
)
def test_a_stop_as_stops_deferred_swaps_handlers_leaves_both_handlers_as_they_were(
    monkeypatch, handler_set, stop
):
    """``signal.signal`` runs the handler of a signal met just before it sets another's: a SIGTERM met as
    SIGINT's handler had been set aside (raised by its handler as SIGTERM's is), or a Ctrl-C met once
    SIGINT's own handler was back (as SIGTERM's comes back), left the other signal's noting handler in
    place, and that signal was lost from then on."""
    real = signal.signal
    calls = []

    def set_handler(sig, handler):
        calls.append(sig)
        if len(calls) == handler_set:
            signal.raise_signal(stop)  # met first, as by the C call
        return real(sig, handler)

    def terminated(_signum, _frame):  # as in a command (sigterm_stops)
        raise Terminated()

    term = real(signal.SIGTERM, terminated)
    try:
        before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        monkeypatch.setattr(signal, "signal", set_handler)
        with pytest.raises(KeyboardInterrupt) as stopped, stops_deferred():
            pass
        monkeypatch.setattr(signal, "signal", real)
        after = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    finally:
        real(signal.SIGTERM, term)
    assert isinstance(stopped.value, Terminated) == (stop == signal.SIGTERM)
    assert after == before
