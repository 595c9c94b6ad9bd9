"""Review of per-take counts (8dbc35b): a take's metadata as before reading its audio was put off until it
is written (keys and repairs in their order), counts by hand at take boundaries, and ``remote --json``
on Ctrl-C."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys

import numpy as np
from live_helpers import run_cli
from test_live_leftovers_s22 import FPS, write_frames_log
from test_live_take_audio_span import ramp

from capture import read_take
from capture.audio_capture import CHUNK_S, AudioLog
from capture.recorder import AUDIO_LOG

VALUES = np.linspace(-0.5, 1.0, 61).astype(np.float32)
STRAY = 9_000_000  # a frame number far from the stream's


def _session(folder) -> None:
    """One phone, two takes 20 s apart, and 5 s of audio at the session's start (the first take's). Take 1
    (60 frames): a copy of a packet, and a copy of its last packet 1 s after it; a stray packet among
    them. Take 2 (240 frames): a repeat of its first frame time with other values (dropped), and the
    phone's clock stepping back 30 frames halfway."""
    first = [(1000 + i, 1.0 + i / FPS, VALUES) for i in range(60)]
    first.insert(21, first[20])
    first.insert(31, (STRAY, first[30][1], VALUES))
    first.append((first[-1][0], first[-1][1] + 1.0, first[-1][2]))
    second = [(2500 + i - 30 * (i >= 120), 26.0 + i / FPS, VALUES + i / 1000) for i in range(240)]
    second.insert(1, (second[0][0], second[0][1], VALUES + 0.3))
    write_frames_log(folder, first + second)
    audio = AudioLog(folder / AUDIO_LOG, fsync=False)
    rate = 8000
    audio.start(rate, 2, "PCM_16", "test")
    chunk = int(rate * CHUNK_S)
    for sample in range(0, 5 * rate, chunk):
        audio.add_chunk(sample, round(sample / rate * 1e9), ramp(sample, chunk, 2))
    audio.close()


def _recover(tmp_path) -> tuple[list[dict], str]:
    session = tmp_path / "live-1.recording"
    _session(session)
    r = run_cli("recover", str(session), "--json")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    return [json.loads(x) for x in r.stdout.splitlines()], r.stderr


def test_a_takes_metadata_keeps_its_order_with_the_audio_read_at_writing(tmp_path):
    """Reading a take's audio just before writing it moved its ``session_audio`` after the stream's counts
    in meta.json and its ``audio_outside_take`` repair after the clock's notes: meta.json was no longer the
    same bytes as before 8dbc35b. Its keys and repairs are in their old order again."""
    lines, _ = _recover(tmp_path)
    extras = [read_take(s["path"]).meta.extra for s in lines]
    keys = list(extras[0])
    assert keys.index("source") + 1 == keys.index("session_audio") < keys.index("rejected")
    counted = [k for k in keys if k in ("packets", "out_of_order", "restarts", "same_time_frames", "senders")]
    assert counted == ["packets", "out_of_order", "restarts", "same_time_frames"]  # as before
    assert [r["kind"] for r in read_take(lines[1]["path"]).meta.repairs] == [
        "audio_outside_take",
        "clock_step_back",
    ]


def test_counts_at_the_boundaries_of_takes_add_up_to_the_streams(tmp_path):
    """Counted by hand: a copy that comes after its take's last frame is that take's, a frame dropped for
    repeating the first frame time of the next take is the next take's, a step back of the clock is the
    take's it happened in; the stray packet is in no take. The takes' counts and the stray packet add up
    to ``stream_counts``."""
    lines, stderr = _recover(tmp_path)
    own = [{k: s[k] for k in s["stream_counts"]} for s in lines]
    assert own == [
        {
            "packets": 62,
            "duplicates": 2,
            "out_of_order": 0,
            "same_time_frames": 0,
            "same_time_dropped": 0,
            "clock_steps_back": 0,
        },
        {
            "packets": 241,
            "duplicates": 0,
            "out_of_order": 0,
            "same_time_frames": 1,
            "same_time_dropped": 1,
            "clock_steps_back": 1,
        },
    ]
    assert [s["frames"] for s in lines] == [60, 240] and lines[0]["stray_packets"] == 1
    totals = {k: own[0][k] + own[1][k] for k in own[0]}
    assert lines[0]["stream_counts"] == lines[1]["stream_counts"] == totals | {"packets": 62 + 241 + 1}
    assert stderr.count("stepped back 1 time(s)") == 1, stderr


def test_remote_json_line_on_ctrl_c():
    """Ctrl-C while ``remote --json`` waits for the phone (a real UDP socket on loopback that never
    replies) was exit code 130 with no JSON line: a script reading one line per call got none."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        silent.settimeout(30)
        phone = f"127.0.0.1:{silent.getsockname()[1]}"
        cmd = [sys.executable, "-m", "capture", "remote", phone, "--json", "--timeout", "60", "battery"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            silent.recvfrom(4096)  # its /OSCSetSendTarget: it waits for the confirmation now
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=30)
        finally:
            proc.kill()
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert [json.loads(line) for line in out.splitlines()] == [
        {"phone": phone, "action": "battery", "error": "interrupted"}
    ]
