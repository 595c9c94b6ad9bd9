"""Live takes from senders whose declared rate jitters or whose clock steps back while they send, and the
receive-queue drops a recover reports: real UDP on loopback, real session logs, a real ``recover``."""

from __future__ import annotations

import json

import numpy as np
from live_helpers import record_packets, run_cli

from capture import FrameStatus, build_takes, read_take
from capture import recorder as recorder_module
from capture.live_cli import _warnings
from capture.livelink import frame_block, header_bytes
from capture.session_takes import _undo_steps_back

DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
START = 10 * 3600 * 60  # 10:00:00 at 60 fps


def _packet(frame: int, num: int = 60, marker: float = 0.0) -> bytes:
    """A packet whose value 0 is ``marker`` (which packet a frame is) and whose others differ per frame."""
    values = np.linspace(0.1, 0.7, 61, dtype=np.float32)
    values[0] = marker
    return header_bytes(DEVICE, "PC-tracker") + frame_block(frame, 0.0, num, 1, values)


def _tracked(take) -> np.ndarray:
    return take.frame_status == FrameStatus.TRACKED


def test_a_sender_declaring_its_measured_rate_makes_one_take_at_the_median_rate(tmp_path):
    # A PC app that reports its measured fps (58-62) in every packet. Before, the recorder held back and
    # rejected 2 in 3 packets as rate_changed and the rest made broken takes.
    rates = np.random.default_rng(5).integers(58, 63, 120)
    rates[0] = 62  # the stream's first rate is an extreme one: the median still wins
    packets = [_packet(START + i, int(rate), marker=i) for i, rate in enumerate(rates)]
    rec = record_packets(tmp_path, "jitter", packets, rate=60)
    assert rec.rejected.get("rate_changed", 0) == 0 and rec.accepted == 120
    (line,) = build_takes(rec.session_dir, tmp_path / "takes")
    assert line["frames"] == 120 and line["dropped_frames"] == 0 and line["rate_changes"] == 0
    assert line["restarts"] == 0 and line["rate_jitter_packets"] == 120
    assert any("120 packets declared a frame rate that wavered" in w for w in _warnings(line))
    take = read_take(line["path"])
    assert take.meta.fps == 60 and take.meta.extra["rate"] == [60, 1]
    assert np.array_equal(take.values[_tracked(take), 0], np.arange(120))
    (note,) = [r["message"] for r in take.meta.repairs if r["kind"] == "rate_jitter"]
    assert "58 to 62 fps" in note and "median declared rate, 60 fps" in note


def test_a_change_of_setting_to_a_nearby_rate_is_still_a_new_recording(tmp_path):
    # 24 -> 25 fps is within the jitter a PC sender shows, but each rate holds: the app restarted.
    packets = [_packet(24 * 36000 + i, 24, marker=i) for i in range(100)]
    packets += [_packet(25 * 36010 + i, 25, marker=100 + i) for i in range(100)]
    lines = build_takes(record_packets(tmp_path, "setting", packets).session_dir, tmp_path / "takes")
    assert [line["frames"] for line in lines] == [100, 100]
    assert lines[0]["rate_changes"] == 1 and "rate_jitter_packets" not in lines[0]
    assert [read_take(line["path"]).meta.fps for line in lines] == [24, 25]


def test_a_small_step_back_of_the_phone_clock_keeps_every_frame_where_it_arrived(tmp_path):
    # The timecode steps back 0.5 s at packet 120 while the phone sends on (an NTP or Tentacle re-sync).
    # Before, the 30 overlapping frames were dropped and everything after sat 0.5 s early (audio off).
    frames = [START + i - (30 if i >= 120 else 0) for i in range(240)]
    rec = record_packets(tmp_path, "step", [_packet(f, marker=i) for i, f in enumerate(frames)], rate=60)
    (line,) = build_takes(rec.session_dir, tmp_path / "takes")
    assert line["frames"] == 240 and line["dropped_frames"] == 0 and line["same_time_dropped"] == 0
    assert line["clock_steps_back"] == 1 and line["restarts"] == 0 and line["clock_steps"] == 0
    assert any("clock stepped back 1 time(s)" in w for w in _warnings(line))  # said to who records
    take = read_take(line["path"])
    assert np.array_equal(take.values[:, 0], np.arange(240))  # every frame, in the order sent
    # placed where it arrived: arrival minus take time is as constant after the step as before it
    late = take.arrival_s - take.time
    assert abs(np.median(late[150:]) - np.median(late[:100])) < 0.05
    (note,) = [r["message"] for r in take.meta.repairs if r["kind"] == "clock_step_back"]
    assert "stepped back 0.50 s at 2.00 s into the take" in note


def test_steps_back_are_told_from_jitter_stalls_pauses_and_slow_replays():
    """Arrival jitter, Wi-Fi bursts, a network stall, a sender pausing with its clock and a replay at half
    speed move the arrivals against the frame times but are no step back; a 0.5 s step is one, sized."""
    rng = np.random.default_rng(11)

    def steps(back_s=0.0, bursts=False, stall_s=0.0, pause_s=0.0, speed=1.0):
        sent = np.arange(600) / 60.0
        frame_time = np.where(sent >= 3, sent - back_s, sent) * speed
        arrival = sent + rng.exponential(0.03, sent.size) + np.where(sent >= 3, pause_s, 0.0)
        arrival[(sent >= 3) & (sent < 3 + stall_s)] += 0.4
        if bursts:
            arrival = np.ceil(arrival / 0.3) * 0.3
        arrival[rng.random(sent.size) < 0.02] += rng.uniform(0.1, 0.3)
        order = np.argsort(arrival, kind="stable")
        return _undo_steps_back(frame_time[order], arrival[order], 1 / 60)[1]

    for case in ({}, {"bursts": True}, {"stall_s": 2.0}, {"pause_s": 2.0}, {"speed": 0.5}):
        assert not any(steps(**case) for _ in range(20)), case
    for bursts in (False, True):
        found = [steps(back_s=0.5, bursts=bursts) for _ in range(20)]
        assert all(len(f) == 1 and abs(f[0][1] - 0.5) < 0.05 for f in found), found


def test_recover_reports_the_receive_queue_drops_of_the_end_record(tmp_path, monkeypatch):
    # What the kernel dropped is counted only at the recorder's stop, in the END record: a recover reads
    # it back into every take's summary, as listen does (the count stands in for the kernel's here).
    monkeypatch.setattr(recorder_module, "receive_queue_drops", lambda sock: 1234)
    rec = record_packets(tmp_path, "drops", [_packet(START + i, marker=i) for i in range(60)])
    r = run_cli("recover", str(rec.session_dir), "-o", str(tmp_path / "takes"), "--json")
    assert r.returncode == 0, r.stderr
    (line,) = [json.loads(x) for x in r.stdout.splitlines() if x.strip()]
    assert line["receive_queue_drops"] == 1234 and line["frames"] == 60
    assert r.stderr.count("1234 datagrams reached this computer but were dropped") == 1
