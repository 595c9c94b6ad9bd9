"""Probe findings mended: align --jobs starts no idle workers, remove_rumble on nothing, and the serial
sync box's long lines (one event, flagged through the log), CR-only line ends and line noise."""

from __future__ import annotations

import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np
import serial
from live_helpers import listen_with_sync_box, synthetic_take

import align.batch as batch
from align.resample import remove_rumble
from capture import read_take
from capture.record_log import RECORD_HEADER
from capture.serial_sync import MAX_LINE_BYTES, SerialSync, SyncEvent, decode_sync_record, sync_record
from capture.session_clock import SessionClock
from capture.take import write_take

# -- align --------------------------------------------------------------------------------------------


def _stub_align_folder(folder, out_dir, opts, force, skip_without_audio, listed=None):
    return {"id": folder.name, "path": str(folder)}


def test_jobs_start_no_more_workers_than_takes(tmp_path, monkeypatch):
    for i in range(2):
        take = synthetic_take(30, seed=i)
        take.meta.id = f"take{i}"
        write_take(take, tmp_path / "in" / f"take{i}")
    started = []

    @contextmanager
    def pool(jobs, context):
        started.append(jobs)
        with ThreadPoolExecutor(jobs) as executor:
            yield executor

    monkeypatch.setattr(batch, "worker_pool", pool)
    monkeypatch.setattr(batch, "align_folder", _stub_align_folder)
    reports = batch.align_takes([tmp_path / "in"], tmp_path / "out", jobs=40)
    assert [r["id"] for r in reports] == ["take0", "take1"]
    assert started == [2]


def test_remove_rumble_of_no_samples_warns_nothing():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        y = remove_rumble(np.zeros(0, np.float32))
    assert y.size == 0 and y.dtype == np.float32


# -- serial sync box ----------------------------------------------------------------------------------


def _read(chunks, pause=0.15):
    """Events SerialSync makes of ``chunks`` written to loop:// one after another."""
    port = serial.serial_for_url("loop://", timeout=0.05)
    events = []
    sync = SerialSync(port, SessionClock(), events.append)
    sync.start()
    for chunk in chunks:
        port.write(chunk)
        time.sleep(pause)
    sync.stop()
    return events, sync


def test_a_long_line_is_one_truncated_event():
    events, _ = _read([b"B" * 5000 + b"\nCLAP\n"])
    assert [e.kind for e in events] == ["B" * MAX_LINE_BYTES, "CLAP"]
    assert events[0].truncated and not events[1].truncated


def test_a_long_line_sent_in_pieces_is_one_event():
    events, _ = _read([b"MARK " + b"x" * 600, b"y" * 600, b"z\nBUTTON 1\n"])
    assert [e.kind for e in events] == ["MARK", "BUTTON"]
    assert events[0].truncated and len(events[0].text) == MAX_LINE_BYTES


def test_lone_cr_ends_a_line_and_stamps_it_on_arrival():
    events, _ = _read([b"CLAP\rMARK x\r", b"BUTTON 2\n", b"TC 1\r\nTC 2\r", b"\n"])
    assert [e.text for e in events] == ["CLAP", "MARK x", "BUTTON 2", "TC 1", "TC 2"]
    assert events[1].arrival_ns < events[2].arrival_ns  # not held until the \n after it


def test_line_noise_is_dropped_with_one_warning(capsys):
    noise = bytes(np.random.default_rng(1).integers(0, 256, 4000, dtype=np.uint8))
    events, sync = _read([noise, b"\nCLAP\nMARK a\tb\n\x00\x00\n\xff\xfeXY\n"])
    assert [e.text for e in events] == ["CLAP", "MARK a\tb"]
    assert sync.dropped >= 3
    assert capsys.readouterr().err.count("warning: the serial sync box sent a line that is not text") == 1


def test_truncated_flag_survives_the_log_and_old_records_decode():
    for flag in (False, True):
        event = SyncEvent(123, "B" * MAX_LINE_BYTES, [], "B" * MAX_LINE_BYTES, truncated=flag)
        back = decode_sync_record(sync_record(event)[RECORD_HEADER.size :])
        assert (back.arrival_ns, back.text, back.truncated) == (123, event.text, flag)
    old = b"\x05" + (7).to_bytes(8, "little", signed=True) + b"BUTTON 2"  # a SYNC payload before the flag
    back = decode_sync_record(old)
    assert (back.kind, back.args, back.truncated) == ("BUTTON", ["2"], False)


def test_listen_takes_keep_one_truncated_event_for_a_long_line(tmp_path):
    lines, err, code = listen_with_sync_box(
        tmp_path, [b"CLAP\r", b"B" * 5000 + b"\n", b"\x00\x01\x02\n", b"BUTTON 2\n"]
    )
    assert code == 0, err
    assert err.count("not text") == 1
    events = read_take(lines[0]["path"]).meta.extra["sync_events"]
    assert [e["kind"] for e in events] == ["CLAP", "B" * MAX_LINE_BYTES, "BUTTON"]
    assert [e.get("truncated", False) for e in events] == [False, True, False]
