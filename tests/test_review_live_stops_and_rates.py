"""Stopping ``listen`` and reading declared rates, attacked: a stop while ``listen`` sets up, run in this
process as a library runs it (``run_here``, signalled from another thread), must leave no thread or open
file behind; a short steady run of one rate at the END of a stream is a change of setting as one at its
start is (tests/test_live_leftovers.py), while a sender declaring its measured rate on every packet stays
one jittering take (real UDP on loopback, real session logs)."""

from __future__ import annotations

import os
import signal
import socket
import sys
import threading
import time

import numpy as np
import pytest
from conftest import run_here
from live_helpers import record_packets
from test_live_leftovers import _packet
from test_review_listen_setup import _sparse_wav

from capture import build_takes, read_take
from capture.cli import build_parser
from capture.live_cli import cmd_listen
from capture.session_takes import RATE_HOLD_PACKETS, _rate_stretches


def _open_files() -> dict[str, str]:
    """This process's open descriptors: number -> what they are (a file's path, socket:[inode], ...)."""
    found = {}
    for fd in os.listdir("/proc/self/fd"):
        try:
            found[fd] = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:  # the descriptor listdir itself used, closed since
            pass
    return found


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="open files are read from /proc")
def test_a_stop_while_listen_reads_its_audio_file_in_process_leaves_no_thread_or_file(tmp_path):
    # Before, the set-up thread read on (ten minutes of WAV, then the hour a user gives) after listen had
    # returned to its caller, holding the audio file open (and a copy of stderr: sys.stderr was replaced).
    wav = _sparse_wav(tmp_path / "ten-minutes.wav", 600)
    out = tmp_path / "out"
    threads, files, stderr = set(threading.enumerate()), _open_files(), os.fstat(2)

    def stop_in_set_up() -> None:
        """SIGINT to this process once listen reads --audio-file (its set-up thread runs)."""
        until = time.monotonic() + 20
        while time.monotonic() < until:
            if any(t.name == "listen-set-up" for t in threading.enumerate()):
                os.kill(os.getpid(), signal.SIGINT)
                return
            time.sleep(0.001)

    poker = threading.Thread(target=stop_in_set_up)
    poker.start()
    try:
        done = run_here("capture", "listen", "-o", out, "--port", 0, "--duration", 20, "--audio-file", wav)
    finally:
        poker.join()
    assert done.returncode == 130 and done.stderr.strip() == "s2a-capture: interrupted", done.stderr
    assert not out.exists()  # the half-made session and the output folder it made: gone
    left = [t.name for t in set(threading.enumerate()) - threads]
    assert left == []
    assert {fd: what for fd, what in _open_files().items() if fd not in files} == {}
    assert (os.fstat(2).st_ino, os.fstat(2).st_dev) == (stderr.st_ino, stderr.st_dev)


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="open files are read from /proc")
def test_two_quick_stops_while_listen_opens_its_log_leave_no_thread_or_file(tmp_path):
    # Two Ctrl-Cs in quick succession while listen made its session log: before, the second raised at once
    # wherever it came, here as the log's writer wrote its first bytes, and left its file open (in other
    # places a writer thread too: 22 stops in 200 left one or the other, sent at random moments).
    out = tmp_path / "out"
    threads, files = set(threading.enumerate()), _open_files()

    def two_stops_at_the_log(frame, event, arg) -> None:
        """A profile of this thread: two SIGINTs as the log writer writes the log's magic bytes."""
        if event == "c_call" and arg is os.write and frame.f_code.co_name == "__init__":
            sys.setprofile(None)
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)

    sys.setprofile(two_stops_at_the_log)
    try:
        done = run_here("capture", "listen", "-o", out, "--port", 0, "--duration", 20)
    finally:
        sys.setprofile(None)
    assert done.returncode == 130 and done.stderr.strip() == "s2a-capture: interrupted", done.stderr
    assert not out.exists()
    assert [t.name for t in set(threading.enumerate()) - threads] == []
    assert {fd: what for fd, what in _open_files().items() if fd not in files} == {}


def test_a_stop_while_listen_reports_its_takes_neither_cuts_the_report_nor_ends_it_interrupted(tmp_path):
    # Before, listen gave the stop signals back to their old handlers before it said what it wrote: two
    # Ctrl-Cs then ended it as interrupted (exit 130, a SIGTERM or SIGHUP killed it) with the takes written
    # and their report cut short.
    def two_stops_at_the_report(frame, event, arg) -> None:
        if event == "call" and frame.f_code.co_name == "_report":
            sys.setprofile(None)
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)

    sys.setprofile(two_stops_at_the_report)
    try:
        done = run_here("capture", "listen", "-o", tmp_path / "out", "--port", 0, "--duration", 0.2)
    finally:
        sys.setprofile(None)
    assert done.returncode == 0, done.stderr
    assert "no take recorded; rejected datagrams" in done.stderr
    (session,) = (tmp_path / "out").glob("*.recording")
    assert (session / "complete.json").is_file()


def _listen_in_a_thread(out, stop: threading.Event, *extra) -> tuple[threading.Thread, list, int]:
    """``cmd_listen`` run by a library in a thread of its own with ``stop``: (the thread, what it returned
    or raised, the UDP port it listens on)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:  # a port free a moment ago
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    args = build_parser().parse_args(
        ["listen", "-o", str(out), "--port", str(port), "--duration", "20", *extra]
    )
    ended: list = []

    def listen() -> None:
        try:
            ended.append(cmd_listen(args, stop=stop))
        except BaseException as exc:  # what the library gets
            ended.append(exc)

    thread = threading.Thread(target=listen)
    thread.start()
    return thread, ended, port


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="open files are read from /proc")
def test_a_library_stops_listen_in_its_thread_while_it_reads_its_audio_file(tmp_path):
    # Before, a listen run in a thread of its own could not be stopped at all but by --duration.
    wav = _sparse_wav(tmp_path / "ten-minutes.wav", 600)
    threads, files = set(threading.enumerate()), _open_files()
    stop = threading.Event()
    thread, ended, _ = _listen_in_a_thread(tmp_path / "out", stop, "--audio-file", str(wav))
    until = time.monotonic() + 20
    while not any(t.name == "listen-set-up" for t in threading.enumerate()) and time.monotonic() < until:
        time.sleep(0.001)
    stop.set()
    thread.join(5)
    assert not thread.is_alive() and len(ended) == 1 and type(ended[0]) is KeyboardInterrupt, ended
    assert not (tmp_path / "out").exists()
    assert [t.name for t in set(threading.enumerate()) - threads] == []
    assert {fd: what for fd, what in _open_files().items() if fd not in files} == {}


def test_a_library_stops_listen_in_its_thread_while_it_records(tmp_path):
    stop = threading.Event()
    thread, ended, port = _listen_in_a_thread(tmp_path / "out", stop, "--json")
    until = time.monotonic() + 20
    while not list((tmp_path / "out").glob("*.recording/frames.log")) and time.monotonic() < until:
        time.sleep(0.005)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as phone:
        for i in range(30):
            phone.sendto(_packet(60 * 36000 + i, 60, i), ("127.0.0.1", port))
            time.sleep(0.002)
    time.sleep(0.2)
    stop.set()
    thread.join(10)
    assert not thread.is_alive() and ended == [0]
    (take,) = (p for p in (tmp_path / "out").iterdir() if not p.name.endswith(".recording"))
    assert np.array_equal(read_take(take).values[:, 0], np.arange(30))


def test_a_rate_declared_as_measured_on_every_packet_is_one_take_at_the_median(tmp_path):
    # A PC sender declaring its measured rate, 58-62 on every packet to the last: one take at 60 fps.
    rng = np.random.default_rng(3)
    rates = rng.integers(58, 63, 240)
    packets = [_packet(60 * 36000 + i, int(rate), i) for i, rate in enumerate(rates)]
    (line,) = build_takes(record_packets(tmp_path, "measured", packets).session_dir, tmp_path / "takes")
    assert line["frames"] == 240 and line["rate_changes"] == 0 and line["rate_jitter_packets"] == 240
    take = read_take(line["path"])
    assert take.meta.fps == int(np.median(rates)) == 60
    assert take.meta.csv["start_seconds_of_day"] == pytest.approx(36000.0)
    (note,) = [r for r in take.meta.repairs if r["kind"] == "rate_jitter"]
    assert "58 to 62 fps" in note["message"] and "median declared rate, 60 fps" in note["message"]


def _stretches(*runs: tuple[int, int]) -> list[tuple[tuple[int, int], tuple[int, int] | None]]:
    num = np.concatenate([np.full(n, rate, np.int64) for rate, n in runs])
    return [((s.start, s.stop), rate) for s, rate in _rate_stretches(num, np.ones_like(num))]


def test_a_change_of_setting_with_each_packet_sent_twice_keeps_both_settings_apart(tmp_path):
    # A sender that sends each packet twice, the copy after the next packet: at the change from 25 to 24
    # fps the copy of the last 25 fps packet comes after the first 24 fps one. Before, those two packets
    # made both settings one jittering rate read at 25 fps: the 24 fps frames sat 24 minutes early.
    frames = [_packet(25 * 36000 + i, 25, i) for i in range(60)]
    frames += [_packet(24 * 36002 + 10 + i, 24, 60 + i) for i in range(60)]
    packets = [frames[0]] + [p for pair in zip(frames[1:], frames[:-1]) for p in pair] + [frames[-1]]
    lines = build_takes(record_packets(tmp_path, "twice", packets).session_dir, tmp_path / "takes")
    assert [(line["frames"], "rate_jitter_packets" in line) for line in lines] == [(60, False), (60, False)]
    first, second = (read_take(line["path"]) for line in lines)
    assert (first.meta.fps, second.meta.fps) == (25, 24)
    assert second.meta.csv["start_seconds_of_day"] == pytest.approx(36002 + 10 / 24)
    assert np.array_equal(second.values[:, 0], 60 + np.arange(60))


def test_a_late_packet_of_the_old_setting_at_a_change_of_rate_costs_no_frame(tmp_path):
    # 30 fps, then the app restarts at 60: the last 30 fps packet arrives after the first 60 fps one. Before,
    # it was taken for the old rate coming back, and the 60 fps packet held back was rejected (rate_changed).
    old = [_packet(30 * 36000 + i, 30, i) for i in range(60)]
    new = [_packet(60 * 36002 + i, 60, 60 + i) for i in range(60)]
    lines = build_takes(
        record_packets(tmp_path, "late", old[:-1] + [new[0], old[-1]] + new[1:]).session_dir, tmp_path / "t"
    )
    assert [(line["frames"], line["rejected"]) for line in lines] == [(60, {}), (60, {})]
    assert [read_take(line["path"]).meta.fps for line in lines] == [30, 60]
    assert np.array_equal(read_take(lines[1]["path"]).values[:, 0], 60 + np.arange(60))


def test_which_short_runs_at_the_end_are_a_change_of_setting():
    hold = RATE_HOLD_PACKETS
    # steady for 3 packets or more after a run that holds: its own stretch, as at the start
    assert _stretches((25, 200), (24, 12)) == [((0, 200), None), ((200, 212), None)]
    assert _stretches((25, hold), (24, 3)) == [((0, hold), None), ((hold, hold + 3), None)]
    assert _stretches((24, 12), (25, 200), (24, 12)) == [
        ((0, 12), None),
        ((12, 212), None),
        ((212, 224), None),
    ]
    # a packet or two at the end, or an end that wavers on: jitter, read at the median
    assert _stretches((25, 200), (24, 2)) == [((0, 202), (25, 1))]
    assert _stretches((25, 200), (24, 1), (25, 12)) == [((0, 213), (25, 1))]
    assert _stretches((60, 150), (62, 1), (59, 1), (61, 1)) == [((0, 153), (60, 1))]
    # mid-stream a short run between two that hold stays jitter
    assert _stretches((25, 200), (24, 12), (25, 200)) == [((0, 412), (25, 1))]
    # two settings that hold with a packet or two of both mixed at the change: apart, the mixed ones too
    assert _stretches((25, 60), (24, 1), (25, 1), (24, 60)) == [
        ((0, 60), None),
        ((60, 62), None),
        ((62, 122), None),
    ]
    assert _stretches((25, 60), (24, 1), (25, 2), (24, 1), (25, 1), (24, hold - 1)) == [
        ((0, 64 + hold), (25, 1))
    ]
