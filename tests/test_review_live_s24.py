"""Second review of the live capture leftovers: a take whose span of the session's float audio holds NaN
says so in its ``take.json`` alike however ``recover`` was given the session; an audio log changed
after the build indexed it fails the take whatever its samples' format."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from live_helpers import synthetic_take
from test_live_take_audio_span import FPS, write_session

from capture import read_take, write_take
from capture.audio_capture import CHUNK_S, AudioLog, index_audio_log
from capture.errors import InputError
from capture.recorder import AUDIO_LOG
from capture.session_takes import _attach_audio_span
from capture.take import META_FILE

RATE = 8000


def _recover(session: str, out: str, cwd) -> None:
    """``s2a-capture recover --all`` run from ``cwd``, as a user types it."""
    cmd = [sys.executable, "-m", "capture", "recover", "--all", "-o", out, session]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=cwd)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr


def test_a_span_holding_nan_is_noted_alike_however_recover_was_given_the_session(tmp_path):
    """A 2 s take whose span of float audio holds one NaN: its ``audio_left_out`` repair named the audio
    log by the path ``recover`` was given (absolute here, relative there: two take.json of one take, and
    a path that is wrong once the session moves); now it names no path."""
    session = tmp_path / "s.recording"
    write_session(session, [(2.0, 120)], None)
    log = AudioLog(session / AUDIO_LOG, fsync=False)
    log.start(RATE, 2, "FLOAT", "test")
    chunk = int(RATE * CHUNK_S)
    for first in range(0, 6 * RATE, chunk):
        samples = np.full((chunk, 2), 0.1, np.float32)
        if first == 3 * RATE:
            samples[7, 1] = np.nan
        log.add_chunk(first, round(first / RATE * 1e9), samples)
    log.close()
    _recover(str(session), str(tmp_path / "absolute"), cwd=tmp_path.parent)
    _recover("s.recording", "relative", cwd=tmp_path)
    metas = [(tmp_path / out / "s_Ann_PHONE" / META_FILE).read_text() for out in ("absolute", "relative")]
    assert metas[0] == metas[1] and "s.recording" not in metas[0], metas
    take = read_take(tmp_path / "relative" / "s_Ann_PHONE")
    (note,) = [r for r in take.meta.repairs if r["kind"] == "audio_left_out"]
    assert note["message"].endswith("is left out: the span holds 1 NaN or infinite sample(s)"), note
    assert take.audio is None and take.time.size == 120


def _session_audio(folder, subtype: str) -> None:
    """6 s of stereo audio at ``RATE`` in ``subtype`` logged beside a 2 s take from session time 2 s."""
    write_session(folder, [(2.0, 120)], None)
    log = AudioLog(folder / AUDIO_LOG, fsync=False)
    log.start(RATE, 2, subtype, "test")
    chunk = int(RATE * CHUNK_S)
    dtype = np.float32 if subtype == "FLOAT" else np.int16
    for first in range(0, 6 * RATE, chunk):
        log.add_chunk(
            first, round(first / RATE * 1e9), np.full((chunk, 2), 0.1 * (dtype is np.float32), dtype)
        )
    log.close()


@pytest.mark.parametrize("subtype", ["FLOAT", "PCM_16"])
def test_an_audio_log_changed_after_it_was_indexed_fails_the_take_whatever_its_samples(tmp_path, subtype):
    """The log's records in a take's span rewritten after the build indexed it: a 16-bit span fails the
    take as it is copied (nothing written; ``recover`` reads the log again); a float span, checked for NaN
    first, was written without its audio instead (``audio_left_out``), for good. Now it fails alike."""
    session = tmp_path / "s.recording"
    _session_audio(session, subtype)
    audio, _ = index_audio_log(session / AUDIO_LOG)
    data = bytearray((session / AUDIO_LOG).read_bytes())
    data[len(data) // 4] ^= 0x40  # a byte 1.5 s into the audio, within the take's span
    (session / AUDIO_LOG).write_bytes(bytes(data))
    take = synthetic_take(120)
    out = tmp_path / "out"
    with pytest.raises(InputError, match="changed since it was indexed"):
        _attach_audio_span(take, audio, 0.0, 1 / FPS)
        write_take(take, out)
    assert not [r for r in take.meta.repairs if r["kind"] == "audio_left_out"], take.meta.repairs
    assert not out.exists() or not list(out.iterdir())  # no take folder, not even a half-written one
