"""Review of the live take building of s23 (takes built and their audio copied from the session's audio log a
block at a time): a stop signal while ``recover`` copies a take's audio leaves no partial files. Real
session logs, a real ``recover`` subprocess, real signals."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from test_live_take_audio_span import FPS, write_session

from capture import read_take

SECONDS = 60  # one take of 48 kHz stereo audio: 11 MB, copied a block at a time


@pytest.fixture
def session(tmp_path):
    folder = tmp_path / "s.recording"
    write_session(folder, [(2.0, SECONDS * FPS)], (0.0, SECONDS + 4.0), 48000)
    return folder


def _size(path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def _stopped_in_the_audio_copy(proc: subprocess.Popen, out) -> bool:
    """Freeze ``proc`` (SIGSTOP) while it copies the take's audio into its hidden partial folder, 2 MB of
    its 11 MB written; False when the take was written, or recover ended, before that was seen."""
    while proc.poll() is None:
        partial = list(out.glob(".*.partial-*/.audio.wav.partial")) if out.is_dir() else []
        if partial and _size(partial[0]) >= 2 << 20:
            proc.send_signal(signal.SIGSTOP)
            if partial[0].exists():
                return True
            proc.send_signal(signal.SIGCONT)
        time.sleep(0.0005)
    return False


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_while_recover_copies_a_takes_audio_leaves_no_partial_files(session, tmp_path, stop):
    """SIGTERM while recover copied a take's audio from the session's log killed it at once (exit -15):
    the take's hidden partial folder stayed beside the takes, with its frames.npz and the half-written
    .audio.wav.partial, until that take was written again. Now recover stops as on Ctrl-C (exit 143),
    the partial folder removed; a recover afterwards writes the take whole."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "capture", "recover", "--all", str(session), "-o", str(out)]
    for _ in range(5):  # the copy is caught mid-way at once but on a very busy machine
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            caught = _stopped_in_the_audio_copy(proc, out)
            if caught:
                proc.send_signal(stop)
                proc.send_signal(signal.SIGCONT)
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        if caught:
            break
    assert caught, "recover was never seen writing the take's audio"
    assert proc.returncode == (130 if stop == signal.SIGINT else 143), err
    assert "Traceback" not in err and sorted(os.listdir(out)) == [], err  # nothing partial, nothing half
    assert not (session / "complete.json").exists()  # recover retries the take
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    take = read_take(out / "s_Ann_PHONE")
    assert take.audio.frames == take.meta.audio.samples > SECONDS * 48000
