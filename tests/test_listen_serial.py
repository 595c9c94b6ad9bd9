"""Serial sync markers: pyserial loop:// in process, socket:// end to end through ``listen``."""

from __future__ import annotations

import time

import serial
from live_helpers import listen_with_sync_box

from capture import read_take
from capture.serial_sync import MAX_LINE_BYTES, SerialSync, parse_sync_line
from capture.session_clock import SessionClock


def test_loop_url_delivers_events_with_arrival_times():
    port = serial.serial_for_url("loop://", timeout=0.05)
    events = []
    clock = SessionClock()
    sync = SerialSync(port, clock, events.append)
    sync.start()
    port.write(b"CLAP\nBUTTON 1\r\n\nTC 14:58:02:44\n" + b"X" * (MAX_LINE_BYTES + 10) + b"\n")
    for _ in range(100):
        if len(events) >= 4:
            break
        time.sleep(0.02)
    sync.stop()
    assert [e.kind for e in events] == ["CLAP", "BUTTON", "TC", "X" * MAX_LINE_BYTES]
    assert events[1].args == ["1"] and events[2].args == ["14:58:02:44"]
    assert events[3].truncated
    assert all(e.arrival_ns >= clock.origin_ns for e in events)
    assert parse_sync_line(b"   \r\n", 0) is None


def test_socket_url_sync_box_end_to_end(tmp_path):
    lines, err, code = listen_with_sync_box(tmp_path, [b"CLAP\n", b"BUTTON 2\n", b"MARK end of sentence\n"])
    assert code == 0, err
    assert lines[0]["sync_events"] == 3
    take = read_take(lines[0]["path"])
    events = take.meta.extra["sync_events"]
    assert [e["kind"] for e in events] == ["CLAP", "BUTTON", "MARK"]
    assert events[2]["args"] == ["end", "of", "sentence"]
    times = [e["t"] for e in events]
    assert times == sorted(times)  # on the take clock, in the order they happened
    assert all(e["arrival_s"] > 0 for e in events)
