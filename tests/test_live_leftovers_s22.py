"""Live capture leftovers: ``remote --json`` failures as a JSON line, per-take counts of a listen session,
a take's audio span built one take at a time."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from live_helpers import run_cli
from test_live_take_audio_span import write_session

from capture import read_take
from capture.livelink import frame_block
from capture.record_log import LogWriter, RecordType, encode_record, json_record
from capture.recorder import FRAME_PREFIX, FRAMES_LOG
from capture.session_takes import AUDIO_MARGIN_S, AUDIO_SPAN_GRID_S

FPS = 60
# the counts a take now has of its own (they were its stream's)
OWN_COUNTS = (
    "packets",
    "duplicates",
    "out_of_order",
    "same_time_frames",
    "same_time_dropped",
    "clock_steps_back",
)


def test_remote_json_failure_is_one_json_line():
    """A phone that does not answer (a real UDP socket on loopback that never replies), a bad argument, a
    bad phone address: the script still reads one JSON line, with the error, besides the one-line error on
    stderr and exit code 1."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        phone = f"127.0.0.1:{silent.getsockname()[1]}"
        lines = []
        for args in (
            [phone, "battery", "--json", "--timeout", "0.2"],
            [phone, "--json", "record-start", "Slate", "-1"],  # checked before anything is sent
            ["127.0.0.1:x", "--json", "thermals"],
        ):
            r = run_cli("remote", *args, timeout=30)
            assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
            assert len(r.stdout.splitlines()) == 1, r.stdout
            lines.append(json.loads(r.stdout))
            assert lines[-1]["error"] in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
    assert [(s["phone"], s["action"]) for s in lines] == [
        (phone, "battery"),
        (phone, "record-start"),
        ("127.0.0.1:x", "thermals"),  # not an address: as given
    ]
    assert len(lines[0]) == 3 and "no /OSCSetSendTargetConfirm from the phone" in lines[0]["error"]
    assert "take number" in lines[1]["error"] and "HOST:PORT" in lines[2]["error"]


def write_frames_log(folder, packets: list[tuple[int, float, np.ndarray]]) -> None:
    """A session folder whose frames log holds one 60 fps stream's ``packets`` (frame number, arrival s,
    values) in the order given, as the recorder logs them."""
    folder.mkdir(parents=True)
    log = LogWriter(folder / FRAMES_LOG, fsync=False)
    log.put(json_record(RecordType.SESSION, {"session": folder.stem, "clock": {"origin_ns": 0}}))
    stream = {"stream": 0, "device": "PHONE", "subject": "Ann", "rate_numerator": FPS, "rate_denominator": 1}
    log.put(json_record(RecordType.STREAM, stream))
    for number, arrival_s, values in packets:
        prefix = FRAME_PREFIX.pack(RecordType.FRAME, 0, round(arrival_s * 1e9))
        log.put(encode_record(prefix + frame_block(number, 0.0, FPS, 1, values)))
    log.close()


def test_counts_are_per_take_with_the_streams_totals_beside(tmp_path):
    """One phone, two takes (a 20 s pause): the first got 3 copies of packets and a frame that repeats a
    frame time with other values, the second 2 packets out of order and one copy. Each take's line and
    meta count its own packets; ``stream_counts`` keeps the stream's totals (they were on both before)."""
    values = np.linspace(-0.5, 1.0, 61).astype(np.float32)
    packets = []
    for first, arrival in ((1000, 1.0), (1000 + 60 * 25, 26.0)):
        take = [(first + i, arrival + i / FPS, values) for i in range(60)]
        packets += take
    first_take, second_take = packets[:60], packets[60:]
    for i in (10, 20, 30):  # copies right after their original: duplicates, not out of order
        first_take.insert(first_take.index(packets[i]) + 1, packets[i])
    first_take.insert(first_take.index(packets[40]) + 1, (packets[40][0], packets[40][1], values + 0.1))
    for i in (10, 30):  # a packet overtaken by the next one
        second_take[i], second_take[i + 1] = second_take[i + 1], second_take[i]
    second_take.insert(50, second_take[49])
    session = tmp_path / "live-1.recording"
    write_frames_log(session, first_take + second_take)

    r = run_cli("recover", str(session), "--json")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [s["frames"] for s in lines] == [60, 60]
    own = [{k: s[k] for k in OWN_COUNTS} for s in lines]
    assert own == [
        {
            "packets": 64,
            "duplicates": 3,
            "out_of_order": 0,
            "same_time_frames": 1,
            "same_time_dropped": 1,
            "clock_steps_back": 0,
        },
        {
            "packets": 61,
            "duplicates": 1,
            "out_of_order": 2,
            "same_time_frames": 0,
            "same_time_dropped": 0,
            "clock_steps_back": 0,
        },
    ]
    totals = {k: a + b for (k, a), b in zip(own[0].items(), own[1].values(), strict=True)}
    assert all(s["stream_counts"] == totals for s in lines)
    assert all(s["restarts"] == 0 and s["stray_packets"] == 0 for s in lines)  # stream-wide, as before
    for s, counts in zip(lines, own, strict=True):
        extra = read_take(s["path"]).meta.extra
        assert {k: extra[k] for k in counts} == counts and extra["stream_counts"] == totals
    # the stream's warning is said once, with its total
    assert r.stderr.count("1 frames repeat the frame time") == 1, r.stderr


# A fresh process's peak memory while it builds a session's takes: its high-water mark reset after the
# imports (Linux: /proc/self/clear_refs), in kB.
BUILD_PEAK = (
    "import sys; from capture import build_takes\n"
    "def peak():\n"
    "    with open('/proc/self/status') as f:\n"
    "        return int(next(line for line in f if line.startswith('VmHWM')).split()[1])\n"
    "with open('/proc/self/clear_refs', 'w') as f:\n"
    "    f.write('5')\n"
    "before = peak()\n"
    "print(len(build_takes(sys.argv[1], sys.argv[2])), peak() - before)\n"
)


def built_with_peak(session: Path, out: Path) -> tuple[int, int]:
    """The takes ``build_takes`` writes of ``session`` in a fresh process, and the kB it adds to its peak."""
    proc = subprocess.run(
        [sys.executable, "-c", BUILD_PEAK, str(session), str(out)], capture_output=True, text=True, check=True
    )
    built, added_kb = map(int, proc.stdout.split())
    return built, added_kb


def take_span_kb(seconds: float, rate: int) -> float:
    """The kB of a ``seconds`` take's audio span (its margins and grid too) of 16-bit stereo at ``rate``."""
    return (seconds + 2 * (AUDIO_MARGIN_S + 1 / FPS) + float(AUDIO_SPAN_GRID_S)) * rate * 4 / 1024


@pytest.mark.skipif(not os.access("/proc/self/clear_refs", os.W_OK), reason="needs Linux's clear_refs")
def test_one_takes_span_of_the_session_audio_in_memory_at_a_time(tmp_path):
    """Five 30 s takes of one phone and 48 kHz stereo audio (6.2 MB per take's span): every span was read
    before the first take was written (39 MB added to the peak); now one at a time (16 MB)."""
    rate, seconds, takes = 48000, 30, 5
    starts = [10.0 + k * (seconds + 10.0) for k in range(takes)]
    write_session(
        tmp_path / "s.recording", [(s, seconds * FPS) for s in starts], (0.0, starts[-1] + 40), rate
    )
    built, added_kb = built_with_peak(tmp_path / "s.recording", tmp_path / "out")
    span_kb = take_span_kb(seconds, rate)
    assert built == takes and added_kb < 4 * span_kb, (added_kb, span_kb)
