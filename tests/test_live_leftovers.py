"""Two leftovers of live capture: a stop in the first milliseconds of ``listen`` (real ``python -m capture
listen`` subprocesses signalled while they start and set up) and a short steady run of one rate at the start
of a stream before a run at a nearby rate (a change of setting right after the start, not jitter: real UDP
on loopback, real session logs, and ``_rate_stretches`` itself)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from live_helpers import record_packets
from test_review_listen_setup import _sparse_wav

from capture import build_takes, read_take
from capture.live_cli import SESSION_LOCK, _lock_session, _remove_unstarted_session, _session_record
from capture.livelink import frame_block, header_bytes
from capture.recorder import AUDIO_LOG, COMPLETE_FILE, FRAMES_LOG
from capture.session_takes import RATE_HOLD_PACKETS, _rate_stretches

DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
LINES = {signal.SIGINT: "s2a-capture: interrupted", signal.SIGTERM: "s2a-capture: terminated (SIGTERM)"}


class EarlyStop:
    """A ``listen`` subprocess into its own new output folder, signalled at ``when``: seconds after it
    started, or once the named file or folder of its session exists ("session": the session folder)."""

    def __init__(self, out: Path, sig: signal.Signals, when: float | str, *extra: str):
        self.out, self.sig, self.when = out, sig, when
        cmd = [sys.executable, "-m", "capture", "listen", "-o", str(out), "--port", "0", "--duration", "20"]
        self.proc = subprocess.Popen(
            [*cmd, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.started = time.monotonic()
        self.signalled = False

    def due(self) -> bool:
        if isinstance(self.when, float):
            return time.monotonic() - self.started >= self.when
        sessions = list(self.out.glob("*.recording")) if self.out.is_dir() else []
        return bool(sessions) and (self.when == "session" or (sessions[0] / self.when).exists())

    def poke(self) -> None:
        """Send the signal when it is due (or the process ended before: it went too fast to be caught)."""
        if not self.signalled and (self.due() or self.proc.poll() is not None):
            self.signalled = True
            if self.proc.poll() is None:
                self.proc.send_signal(self.sig)


def _outcome(trial: EarlyStop) -> str:
    """How a signalled ``listen`` ended; asserts that it left nothing, or a valid session when the signal
    came once it was recording. "set-up": stopped while it made its session, which is gone."""
    _, err = trial.proc.communicate(timeout=20)
    lines = err.strip().splitlines()
    code = trial.proc.returncode
    assert "Traceback" not in err, err
    if code == 0:  # the stop came once it recorded: a clean stop, a valid session
        assert lines[0].startswith("listening on udp://") and "no take recorded" in err, err
        (session,) = trial.out.glob("*.recording")
        assert _session_record(session)["pid"] == trial.proc.pid
        assert (session / COMPLETE_FILE).is_file()
        return "recording"
    left = sorted(p.name for p in trial.out.rglob("*")) if trial.out.exists() else []
    assert left == [], f"{trial.sig.name} at {trial.when}: {left} left behind ({err.strip()!r})"
    assert not trial.out.exists()  # nor the output folder it made
    if code == -trial.sig:  # before Python ran a line of the command: killed, nothing made
        assert err == ""
        return "start-up"
    assert code == EXIT_CODES[trial.sig] and lines == [LINES[trial.sig]], (code, err)
    return "set-up" if trial.signalled and isinstance(trial.when, str) else "start-up"


def test_a_stop_in_the_first_milliseconds_of_listen_leaves_no_empty_session(tmp_path):
    # Before, a SIGINT or SIGTERM between making the session folder and taking the stop signals left a
    # folder with the lock alone, or a frames log without its SESSION record, for recover to meet.
    # ten minutes of audio file (sparse: silence that costs no disk), read while listen sets up: a signal
    # sent once its audio log is there lands in the read on a fast machine too
    audio = _sparse_wav(tmp_path / "voice.wav", 600, channels=1)
    plan = [
        (signal.SIGTERM, 0.0, ()),
        (signal.SIGTERM, 0.05, ()),
        (signal.SIGINT, "session", ()),
        (signal.SIGTERM, FRAMES_LOG, ()),
        (signal.SIGINT, AUDIO_LOG, ("--audio-file", str(audio))),
        (signal.SIGTERM, AUDIO_LOG, ("--audio-file", str(audio))),
    ]
    trials = []
    for i, (sig, when, extra) in enumerate(plan):
        trials.append(EarlyStop(tmp_path / f"out{i}", sig, when, *extra))
        trials[-1].poke()
    deadline = time.monotonic() + 20
    while not all(trial.signalled for trial in trials) and time.monotonic() < deadline:
        for trial in trials:
            trial.poke()
        time.sleep(0.0002)
    outcomes = [_outcome(trial) for trial in trials]
    # Each signal that came once the session folder existed came before the recording began or after.
    assert all(o in ("set-up", "recording") for o in outcomes[2:]), outcomes
    # The audio file is read while listen sets up (a tenth of a second or more): a stop at its audio log
    # comes before the recording, so the set-up window is met whatever the load.
    assert "set-up" in outcomes[4:], outcomes


def test_a_stopped_start_removes_only_a_session_folder_it_made_and_only_its_own_files(tmp_path):
    made = tmp_path / "out" / "live-a.recording"
    locks: list[int | None] = []
    try:
        lock, new = _lock_session(made)
        locks.append(lock)
        assert new and (made / SESSION_LOCK).is_file()
        (made / FRAMES_LOG).write_bytes(b"S2ALOG1\n")
        _remove_unstarted_session(made, new)
        assert not made.exists() and (tmp_path / "out").is_dir()
        # one that holds another file keeps it, and a folder that was there before stays whole
        lock, new = _lock_session(made)
        locks.append(lock)
        (made / "notes.txt").write_text("mine")
        _remove_unstarted_session(made, new)
        assert sorted(p.name for p in made.iterdir()) == ["notes.txt"]
        lock, new = _lock_session(made)
        locks.append(lock)
        assert not new
        _remove_unstarted_session(made, new)
        assert sorted(p.name for p in made.iterdir()) == [SESSION_LOCK, "notes.txt"]
    finally:
        for fd in locks:
            if fd is not None:
                os.close(fd)


def _packet(frame: int, num: int, marker: int) -> bytes:
    values = np.linspace(0.1, 0.7, 61, dtype=np.float32)
    values[0] = marker
    return header_bytes(DEVICE, "iPhone") + frame_block(frame, 0.0, num, 1, values)


# The app streamed at 24 fps for half a second, then its setting went to 25 (a restart). Before, the 12
# frames at 24 fps were read as jitter at 25 fps: a take placed at 09:36:00 instead of 10:00:00. At a
# stream's END likewise: 25 fps, then 24 (a restart) and 12 packets later the stream stopped; before, a take
# of 212 frames at 25 fps whose last 12 sat 4 % of the day off (10:24 instead of 10:00), with a jitter note.
@pytest.mark.parametrize(
    "runs, second_starts, short",
    [
        (((24, 0, 12), (25, 13, 200)), 36000.52, 0),  # (rate, first frame after 10:00, frames) per run
        (((25, 0, 200), (24, 200, 12)), 36000 + 200 / 24, 1),
    ],
    ids=["start", "end"],
)
def test_a_steady_short_run_keeps_its_own_rate(tmp_path, runs, second_starts, short):
    packets, marker = [], 0
    for rate, first, frames in runs:
        packets += [_packet(rate * 36000 + first + i, rate, marker + i) for i in range(frames)]
        marker += frames
    lines = build_takes(record_packets(tmp_path, "steady", packets).session_dir, tmp_path / "takes")
    assert [line["frames"] for line in lines] == [frames for _, _, frames in runs]
    assert lines[0]["rate_changes"] == 1 and "rate_jitter_packets" not in lines[0]
    takes = [read_take(line["path"]) for line in lines]
    assert tuple(t.meta.fps for t in takes) == tuple(rate for rate, _, _ in runs)
    assert takes[0].meta.csv["start_seconds_of_day"] == pytest.approx(36000.0)
    assert takes[1].meta.csv["start_seconds_of_day"] == pytest.approx(second_starts)
    before = sum(frames for _, _, frames in runs[:short])  # the short run's first marker
    assert np.array_equal(takes[short].values[:, 0], before + np.arange(12))


def test_a_jittering_start_before_a_steady_run_is_still_jitter(tmp_path):
    # A PC sender that declares its measured rate: it wavers for its first packets, then settles on 60.
    start = [61, 59, 62, 58, 61, 61, 59, 60, 62, 58, 61, 59]
    packets = [_packet(60 * 36000 + i, rate, i) for i, rate in enumerate(start + [60] * 150)]
    (line,) = build_takes(record_packets(tmp_path, "jitter", packets).session_dir, tmp_path / "takes")
    assert line["frames"] == 162 and line["rate_changes"] == 0 and line["rate_jitter_packets"] == 162
    take = read_take(line["path"])
    assert take.meta.fps == 60 and take.meta.csv["start_seconds_of_day"] == pytest.approx(36000.0)
    assert np.array_equal(take.values[:, 0], np.arange(162))


def _stretches(*runs: tuple[int, int]) -> list[tuple[tuple[int, int], tuple[int, int] | None]]:
    num = np.concatenate([np.full(n, rate, np.int64) for rate, n in runs])
    return [((s.start, s.stop), rate) for s, rate in _rate_stretches(num, np.ones_like(num))]


def test_which_short_runs_at_the_start_are_a_change_of_setting():
    hold = RATE_HOLD_PACKETS
    # steady for 3 packets or more, as the recorder confirms a change: its own stretch
    assert _stretches((24, 12), (25, 200)) == [((0, 12), None), ((12, 212), None)]
    assert _stretches((24, 3), (25, hold)) == [((0, 3), None), ((3, 3 + hold), None)]
    # a packet or two at another rate, or a start that goes on wavering: jitter, read at the median
    assert _stretches((24, 2), (25, 200)) == [((0, 202), (25, 1))]
    assert _stretches((24, 12), (25, hold - 1), (24, 1), (25, 200)) == [((0, 12 + hold + 200), (25, 1))]
    assert _stretches((62, 1), (59, 1), (61, 1), (60, 150)) == [((0, 153), (60, 1))]
    # what follows a steady start is read as before: here a jittering stretch of its own
    assert _stretches((24, 12), (25, 200), (24, 1), (25, 50)) == [((0, 12), None), ((12, 263), (25, 1))]
    # mid-stream a short run between two that hold stays jitter
    assert _stretches((25, 200), (24, 12), (25, 200)) == [((0, 412), (25, 1))]
