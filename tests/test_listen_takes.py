"""The recorder in process: several phones, segments at frame-time jumps, bad values, rate changes,
no-face packets inside and between takes."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
from live_helpers import record_packets

from capture import FrameStatus, LiveRecorder, build_takes, read_take
from capture.livelink import frame_block, header_bytes, no_face_packet


def test_streams_segments_and_rejections(tmp_path):
    rec = LiveRecorder(tmp_path, port=0, session_id="s1")
    _, port = rec.open()
    runner = threading.Thread(target=rec.run, kwargs={"duration_s": 30})
    runner.start()
    vals = np.linspace(-0.5, 1.0, 61).astype(np.float32)
    bad = vals.copy()
    bad[17] = np.nan
    a, b = header_bytes("PHONE-A", "Alice"), header_bytes("PHONE-B", "Bob")
    packets = []
    for i in range(40):  # two phones interleaved
        packets.append(a + frame_block(100 + i, 0.25, 60, 1, bad if i == 5 else vals))
        packets.append(b + frame_block(7000 + i, 0.5, 60, 1, vals))
    packets += [a + frame_block(100 + 60 * 60 + i, 0.25, 60, 1, vals) for i in range(20)]  # 1 min later
    packets.append(a + frame_block(10**9, 0.0, 60, 1, vals))  # a corrupt frame number: stray
    packets.append(b + frame_block(7040, 0.5, 30, 1, vals))  # rate switch
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for p in packets:
            s.sendto(p, ("127.0.0.1", port))
    time.sleep(0.5)
    rec.request_stop()
    runner.join()
    rec.close()
    lines = build_takes(rec.session_dir, tmp_path)
    by_id = {line["path"].rsplit("/", 1)[1]: line for line in lines}
    assert sorted(by_id) == ["s1_Alice_PHONE-A_1", "s1_Alice_PHONE-A_2", "s1_Bob_PHONE-B"]
    first = read_take(by_id["s1_Alice_PHONE-A_1"]["path"])
    assert first.time.size == 40 and first.frame_status[5] == FrameStatus.BAD_VALUE
    assert np.isnan(first.values[5, 17]) and first.meta.repairs[0]["kind"] == "bad_value"
    assert read_take(by_id["s1_Alice_PHONE-A_2"]["path"]).time.size == 20
    assert by_id["s1_Alice_PHONE-A_1"]["stray_frames"] == 1
    assert lines[0]["rejected"] == {"rate_changed": 1}
    assert lines[0]["datagrams"] == len(packets) and lines[0]["accepted"] == len(packets) - 1
    bob = read_take(by_id["s1_Bob_PHONE-B"]["path"])
    assert bob.meta.device == "PHONE-B" and bob.meta.subject == "Bob" and bob.meta.fps == 60
    assert bob.meta.extra["first_frame_number"] == 7000


def test_no_face_packets_inside_and_between_takes(tmp_path):
    vals = np.linspace(-0.5, 1.0, 61).astype(np.float32)
    face = header_bytes("PHONE-A", "Alice")
    kinds = "n" * 20 + "f" * 30 + "n" * 10 + "f" * 30 + "n" * 400 + "f" * 30 + "n" * 5  # 400 = 6.7 s
    kinds += "n" * 400 + "f" * 5 + "n" * 50  # a glimpse of a face, alone: too short for a take
    packets = [
        face + frame_block(100 + i, 0.5, 60, 1, vals)
        if k == "f"
        else no_face_packet("PHONE-A", "Alice", 100 + i, 0.5, 60, 1)
        for i, k in enumerate(kinds)
    ]
    packets += [no_face_packet("PHONE-B", "Bob", 7000 + i, 0.0, 60, 1) for i in range(30)]  # never a face
    rec = record_packets(tmp_path, "nf", packets)
    assert rec.accepted == len(packets) and sum(rec.rejected.values()) == 0
    lines = build_takes(rec.session_dir, tmp_path)
    assert [line["path"].rsplit("/", 1)[1] for line in lines] == ["nf_Alice_PHONE-A_1", "nf_Alice_PHONE-A_2"]
    first, second = (read_take(line["path"]) for line in lines)
    # The first take: face, a sixth of a second without one, face again.
    assert first.time.size == 70 and first.meta.extra["first_frame_number"] == 120
    want = np.array([FrameStatus.TRACKED] * 30 + [FrameStatus.FACE_LOST] * 10 + [FrameStatus.TRACKED] * 30)
    assert np.array_equal(first.frame_status, want) and first.meta.repairs == []
    assert np.allclose(first.time, np.arange(70) / 60) and np.all(np.isfinite(first.arrival_s))
    assert np.isnan(first.values[30:40]).all() and np.array_equal(first.values[40], vals)
    # More than 5 s without a face splits; no-face packets before, between and after are outside.
    assert second.time.size == 30 and second.count(FrameStatus.FACE_LOST) == 0
    assert second.meta.extra["first_frame_number"] == 100 + 490
    assert lines[0]["face_lost_outside_takes"] == 20 + 400 + 5 + 400 + 50
    assert lines[0]["face_lost_frames"] == 10 and lines[0]["stray_frames"] == 5
    assert lines[0]["stray_streams"] == 1  # Bob's phone never saw a face


def test_rows_spilled_to_disk_give_the_same_takes(tmp_path, monkeypatch):
    import capture.session_takes as st

    vals = np.linspace(-0.5, 1.0, 61).astype(np.float32)
    packets = [
        no_face_packet(f"P{i % 3}", "iPhone", i, 0.0, 60, 1)
        if i % 7 == 0 and i > 3
        else header_bytes(f"P{i % 3}", "iPhone") + frame_block(i, 0.0, 60, 1, vals + i)
        for i in range(300)
    ]
    rec = record_packets(tmp_path, "s2", packets)
    in_memory = build_takes(rec.session_dir, tmp_path / "a")
    monkeypatch.setattr(st, "SPILL_BYTES", 1000)
    spilled = build_takes(rec.session_dir, tmp_path / "b")
    assert [x["frames"] for x in spilled] == [x["frames"] for x in in_memory] == [100, 100, 100]
    for x, y in zip(in_memory, spilled):
        a, b = read_take(x["path"]), read_take(y["path"])
        assert np.array_equal(a.values, b.values, equal_nan=True)
        assert np.array_equal(a.frame_status, b.frame_status) and a.count(FrameStatus.FACE_LOST) > 10
    assert not list(rec.session_dir.glob(".build-*"))
