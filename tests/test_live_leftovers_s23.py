"""Live capture leftovers: a take's warnings named on the take they happened in, the packets in no take
said in the listen summary, a take's audio written a block at a time from the session's audio log, and
``/Thermals`` replies outside the thermal states refused. Real UDP on loopback throughout."""

from __future__ import annotations

import json
import os
import socket
import time

import numpy as np
import pytest
from live_helpers import Listener, run_cli
from test_live_leftovers_s22 import built_with_peak, take_span_kb
from test_live_take_audio_span import write_session
from test_osc_remote import FakePhone

from capture import read_take
from capture.livelink import frame_block, header_bytes, no_face_packet

FPS = 60
HEADER = header_bytes("PHONE-1", "Ann")
SAME_TIME = "1 frames repeat the frame time of another frame"


def _face(number: int, values: np.ndarray) -> bytes:
    return HEADER + frame_block(number, 0.0, FPS, 1, values)


def _send(port: int, packets: list[bytes]) -> None:
    """Send ``packets`` to a listener on loopback, paced so that its receive queue never overflows."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i, packet in enumerate(packets):
            if i % 100 == 99:
                time.sleep(0.005)
            s.sendto(packet, ("127.0.0.1", port))
    time.sleep(0.5)


def _two_takes_with_leftovers() -> list[bytes]:
    """One phone, two takes of 60 frames 25 s apart in frame time, each with a frame that repeats the frame
    time of the one before with other values (dropped, a warning of its take); 3 no-face packets before
    the first take, a stray frame number and a burst of 5 frames too short for a take: 9 packets in no
    take."""
    values = np.linspace(-0.5, 1.0, 61).astype(np.float32)
    packets = [no_face_packet("PHONE-1", "Ann", 900 + i, 0.0, FPS, 1) for i in range(3)]
    for first in (1000, 1000 + 25 * FPS):
        take = [_face(first + i, values + i / 1000) for i in range(60)]
        take.insert(31, _face(first + 30, values + 0.5))
        packets += take
    packets.insert(40, _face(9_000_000, values))
    packets += [_face(1000 + 50 * FPS + i, values) for i in range(5)]
    return packets


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """``listen --json`` of ``_two_takes_with_leftovers``: its JSON lines, stderr and output folder."""
    out = tmp_path_factory.mktemp("s23") / "out"
    listener = Listener(out)
    _send(listener.port, _two_takes_with_leftovers())
    lines, err, code = listener.stop()
    assert code == 0 and "Traceback" not in err, err
    return lines, err, out


def test_a_takes_warning_names_the_take_it_happened_in(session):
    """Each take dropped a frame repeating a frame time. Before, the stream's total was said once, on the
    first take's path ("2 frames repeat ..."): the second take's was named on the first. Now each take's
    own count is said on its own path, in listen's JSON mode and in recover's text summary."""
    lines, err, out = session
    assert [s["frames"] for s in lines] == [60, 60]
    assert [s["same_time_dropped"] for s in lines] == [1, 1]
    said = [line for line in err.splitlines() if "repeat the frame time" in line]
    assert [line.partition("warning: ")[2].partition(" with")[0] for line in said] == [
        f"{s['path']}: {SAME_TIME}" for s in lines
    ], err
    r = run_cli("recover", "--all", str(out), "-o", str(out.parent / "again"))
    assert r.returncode == 0, r.stderr
    text = r.stderr.splitlines()
    takes = [i for i, line in enumerate(text) if " -> " in line and "frames," in line]
    repeats = [i for i, line in enumerate(text) if SAME_TIME in line]
    assert len(takes) == 2 and len(repeats) == 2, r.stderr
    assert takes[0] < repeats[0] < takes[1] < repeats[1], r.stderr  # each under its own take's line


def test_packets_in_no_take_are_said_in_the_summary(session):
    """3 no-face packets before the first take, a stray frame number and 5 frames too few for a take were
    counted only in meta's ``stream_counts`` (its packets less the takes'): now every take line of the
    stream says ``packets_outside_takes``, and stderr says it once."""
    lines, err, _ = session
    assert [s["packets_outside_takes"] for s in lines] == [9, 9]
    assert lines[0]["stream_counts"]["packets"] - sum(s["packets"] for s in lines) == 9
    assert err.count("9 packets of device PHONE-1 / subject Ann are in no take") == 1, err


@pytest.mark.parametrize("state", [7, -1, 4.0])
def test_thermal_states_outside_0_to_3_are_refused(state):
    """The app's ``/Thermals <i>`` is a thermal state, 0 nominal .. 3 critical: 7, -1 (or 4.0) were
    printed as the phone's thermal state. Now, as a reply of the wrong type, a one-line error and with
    --json one JSON line holding it; 3 is still a state."""
    phone = FakePhone(thermals=state)
    try:
        where = f"127.0.0.1:{phone.port}"
        r = run_cli("remote", where, "--json", "--timeout", "5", "thermals")
        assert r.returncode == 1 and "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr
        error = json.loads(r.stdout)["error"]
        assert f"/Thermals {state!r}" in error and "3 critical" in error and error in r.stderr
        phone.thermals = 3
        r = run_cli("remote", where, "--json", "--timeout", "5", "thermals")
        assert r.returncode == 0 and json.loads(r.stdout)["thermals"] == 3, r.stderr
    finally:
        phone.close()


# (getrusage's ru_maxrss is no use here: Linux carries a parent's resident set over fork and exec into it)
@pytest.mark.skipif(not os.access("/proc/self/clear_refs", os.W_OK), reason="needs Linux's clear_refs")
def test_a_takes_audio_is_written_without_holding_its_span(tmp_path):
    """Three 40 s takes of one phone with 48 kHz stereo audio (7971 kB per take's span): building them
    peaked at twice a span above the memory before (15548 kB: the take's audio read whole, and the stream's
    rows copied twice to order them, every take's frames built before the first was written); now the span
    goes from the audio log to the take's WAV a block at a time, the rows are ordered by index and each
    take's frames are built just before it is written (6048 kB alone, 8400 kB once in a loaded full suite, the
    modules it imports on first use counted too): under 1.5 spans, where the old way needed 1.95."""
    rate, seconds, takes = 48000, 40, 3
    starts = [2.0 + k * (seconds + 6.0) for k in range(takes)]
    session = tmp_path / "s.recording"
    write_session(session, [(s, seconds * FPS) for s in starts], (0.0, starts[-1] + seconds + 2), rate)
    built, added_kb = built_with_peak(session, tmp_path / "out")
    span_kb = take_span_kb(seconds, rate)
    assert built == takes and added_kb < 1.5 * span_kb, (added_kb, span_kb)
    take = read_take(tmp_path / "out" / "s_Ann_PHONE_2")  # its audio as before: its own span
    assert take.audio.frames == take.meta.audio.samples and take.audio.samples.dtype == np.int16
