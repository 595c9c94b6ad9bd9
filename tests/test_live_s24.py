"""Live capture leftovers: a take's span of the session's audio checked for NaN a block at a time, and
16-bit audio read from the log once (as it is copied into the take), measured in a fresh process; then
an adversarial phone and remote over real loopback sockets."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from live_helpers import listen_while_the_audio_file_changes, run_cli
from test_live_leftovers_s22 import built_with_peak, take_span_kb
from test_live_take_audio_span import FPS, write_session
from test_osc_remote import FakePhone

from capture import Audio, read_take, write_audio
from capture.audio_capture import CHUNK_S, AudioLog
from capture.recorder import AUDIO_LOG, FRAMES_LOG

RATE = 48000


@pytest.mark.skipif(not os.access("/proc/self/clear_refs", os.W_OK), reason="needs Linux's clear_refs")
def test_a_float_span_holding_nan_is_refused_without_reading_it_whole(tmp_path):
    """A 60 s take whose span of 48 kHz stereo float audio (24 MB) holds one NaN sample: it was read whole
    just to be refused (27.8 MB added to the peak); now it is checked a block at a time (4.6 MB), and the
    take is still written without its audio, saying why."""
    seconds = 60
    session = tmp_path / "s.recording"
    write_session(session, [(2.0, seconds * FPS)], None)
    log = AudioLog(session / AUDIO_LOG, fsync=False)
    log.start(RATE, 2, "FLOAT", "test")
    chunk = int(RATE * CHUNK_S)
    for first in range(0, RATE * (seconds + 6), chunk):
        samples = np.full((chunk, 2), 0.1, np.float32)
        if first == RATE * 30:
            samples[5, 0] = np.nan
        log.add_chunk(first, round(first / RATE * 1e9), samples)
    log.close()
    built, added_kb = built_with_peak(session, tmp_path / "out")
    span_kb = 2 * take_span_kb(seconds, RATE)  # float32: twice 16-bit's bytes
    assert built == 1 and added_kb < 0.5 * span_kb, (added_kb, span_kb)
    take = read_take(tmp_path / "out" / "s_Ann_PHONE")
    assert take.audio is None and take.time.size == seconds * FPS
    (note,) = [r for r in take.meta.repairs if r["kind"] == "audio_left_out"]
    assert "holds 1 NaN or infinite sample(s)" in note["message"], note


# A fresh process's bytes read (``rchar``: every read call, the page cache's too) while it builds a
# session's takes.
BUILD_READ = (
    "import sys; from capture import build_takes\n"
    "def rchar():\n"
    "    with open('/proc/self/io') as f:\n"
    "        return int(next(line for line in f if line.startswith('rchar')).split()[1])\n"
    "before = rchar()\n"
    "built = build_takes(sys.argv[1], sys.argv[2])\n"
    "print(len(built), rchar() - before)\n"
)


@pytest.mark.skipif(not os.access("/proc/self/io", os.R_OK), reason="needs Linux's /proc/self/io")
def test_a_16_bit_span_is_read_from_the_log_once(tmp_path):
    """A 60 s take with 48 kHz stereo 16-bit audio (12 MB span): its span was read twice, once to check
    it and once to copy it (39.9 MB read in all, the logs' indexing included); now it is read as it is
    copied (27.0 MB), each record's checksum checked then; its samples are those of the session's."""
    seconds = 60
    session = tmp_path / "s.recording"
    write_session(session, [(2.0, seconds * FPS)], (0.0, seconds + 6), RATE)
    proc = subprocess.run(
        [sys.executable, "-c", BUILD_READ, str(session), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        check=True,
    )
    built, read = map(int, proc.stdout.split())
    logs = (session / AUDIO_LOG).stat().st_size + (session / FRAMES_LOG).stat().st_size  # indexed once
    span = take_span_kb(seconds, RATE) * 1024
    assert built == 1 and read < logs + 1.4 * span, (read, logs, span)
    take = read_take(tmp_path / "out" / "s_Ann_PHONE")
    first = take.meta.extra["session_audio"]["first_sample"]
    k = np.arange(first, first + take.audio.frames)
    assert np.array_equal(take.audio.samples, np.stack([k % 30000, k // 30000], axis=1).astype(np.int16))


@pytest.mark.parametrize(
    ("option", "value", "said"),
    [("--audio-rate", "-48000", "1..4294967295"), ("--audio-channels", "99999999999", "1..65535")],
)
def test_a_sound_device_rate_or_channel_count_no_device_can_have_is_a_usage_error(
    tmp_path, option, value, said
):
    """``listen --audio-device 0 --audio-rate -48000``: the rate went to the sound library as it was (a
    negative buffer size; a channel count past a C int), whose binding raises OverflowError, no error
    ``listen`` reports (here, without PortAudio, the PortAudio hint came first). Now a usage error."""
    r = run_cli(
        "listen", "-o", str(tmp_path), "--port", "0", "--audio-device", "0", option, value, timeout=60
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"argument {option}: must be in {said}, not {int(value)}" in r.stderr.splitlines()[-1], r.stderr
    assert not list(tmp_path.iterdir())  # refused before any session folder


class StoppedPhone(FakePhone):
    """A phone that answers ``/RecordStart`` with ``/RecordStopConfirm`` (and the app's own
    ``/AppActivated``, and an address no app sends), never with ``/RecordStartConfirm``."""

    def _any(self, address, *args):
        if address == "/RecordStart" and self.reply is not None:
            self.received.append((address, *args))
            self.reply.send_message("/AppActivated", [])
            self.reply.send_message("/RecordStopConfirm", ["00:00:01.000", "/a.csv", "/a.mov"])
            self.reply.send_message("/x\n\x1b[2J", [])  # a line break and a terminal's clear screen
        else:
            super()._any(address, *args)


def test_a_phone_that_answers_another_message_is_said_to_have_answered():
    """The phone answers ``record-start`` out of order (a stop's confirmation). The error said only that
    no ``/RecordStartConfirm`` came, asking whether Live Link Face runs with OSC enabled; now it says what
    the phone sent instead (one line, and the JSON line)."""
    phone = StoppedPhone()
    try:
        # (3 s: the phone's confirmation of the target must come within it on a busy machine too; the
        # reply never comes, so the command always waits that long)
        r = run_cli("remote", f"127.0.0.1:{phone.port}", "--json", "--timeout", "3", "record-start", "S", "1")
    finally:
        phone.close()
    assert r.returncode == 1 and "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    error = json.loads(r.stdout)["error"]
    assert error.endswith(r"within 3 s: it sent /AppActivated, /RecordStopConfirm, /x\n\x1b[2J instead"), (
        error
    )
    assert error in r.stderr and "is Live Link Face running" not in error


def test_an_audio_file_cut_short_while_it_plays_keeps_what_played_and_says_so_once(tmp_path):
    """``listen --audio-file`` whose file is cut short (rewritten) after half a second of playing: the
    take keeps the audio played until then; but listen ended with ``no audio was recorded: ...`` and
    printed the take's warning twice (the failure is noted in both logs). Now it says how much audio the
    takes hold, once."""
    wav = tmp_path / "speech.wav"
    write_audio(wav, Audio((np.arange(16000 * 30) % 2000 - 1000).astype(np.int16), 16000, "PCM_16"))

    def cut_short() -> None:
        with open(wav, "r+b") as f:
            f.truncate(1000)

    (line,), err, code, _ = listen_while_the_audio_file_changes(tmp_path, wav, 5, cut_short)
    assert code == 1 and "Traceback" not in err, err
    assert line["frames"] == 120 and len(line["errors"]) == 1, line
    said = [x for x in err.splitlines() if x.startswith("s2a-capture: warning: ") and "changed since" in x]
    assert len(said) == 2, err  # when it happened, and once on the take's line
    last = err.splitlines()[-1]
    assert last.startswith("s2a-capture: error: ") and "no audio was recorded" not in last, err
    assert "the audio failed after " in last and "s of it (the takes hold those): " in last, err
    take = read_take(line["path"])
    assert take.audio.frames >= int(0.5 * 16000)
