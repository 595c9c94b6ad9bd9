"""Live capture leftovers: ``remote`` takes replies from the phone's address only (real sockets on
loopback, 127.0.0.2 the stranger); a step back of the phone's clock an hour after a step forward an hour
(recorded over real UDP in real time) is a recording of its own, placed where its frames arrived; a CSV
read splits its timecodes once."""

from __future__ import annotations

import socket
import sys

import numpy as np
import pytest
from live_helpers import record_packets
from pythonosc.osc_message_builder import OscMessageBuilder
from test_osc_remote import FakePhone

from capture import FrameStatus, InputError, build_takes, read_take
from capture.csv_take import read_livelink_csv
from capture.livelink import frame_block, header_bytes
from capture.osc_remote import PhoneRemote


def _osc(address: str, *args) -> bytes:
    b = OscMessageBuilder(address=address)
    for a in args:
        b.add_arg(a)
    return b.build().dgram


@pytest.fixture
def stranger():
    """A UDP socket on another loopback address than the phone's (127.0.0.1)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.2", 0))
        yield s


# -- 1. replies from the phone's address only ----------------------------------------------------------------
def test_a_reply_from_another_host_is_not_the_phones(stranger):
    # Another host (or a phone controlled earlier through this reply port) answers first, with a confirm
    # and a battery level of its own, queued on the reply port before the phone is asked: before, both
    # were taken for the phone's (battery 0.1).
    phone = FakePhone(battery=0.75)
    try:
        with PhoneRemote("127.0.0.1", phone.port, timeout_s=10) as remote:
            to = (remote.reply_host, remote.reply_port)
            stranger.sendto(_osc("/OSCSetSendTargetConfirm"), to)
            stranger.sendto(_osc("/Battery", 0.1), to)
            assert remote.battery() == 0.75
            assert remote.stranger_datagrams == 2
    finally:
        phone.close()
    assert [r[0] for r in phone.received] == ["/OSCSetSendTarget", "/BatteryQuery"]


def test_a_reply_that_never_comes_names_the_hosts_ignored(stranger):
    # The phone (a socket that never answers) is silent; only the stranger answers.
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        with PhoneRemote("127.0.0.1", silent.getsockname()[1], timeout_s=1) as remote:
            stranger.sendto(_osc("/OSCSetSendTargetConfirm"), (remote.reply_host, remote.reply_port))
            with pytest.raises(InputError) as err:
                remote.thermals()
    who = f"127.0.0.2:{stranger.getsockname()[1]}"
    assert f"1 datagram(s) from {who}, not the phone's address, were ignored" in str(err.value)
    assert "no /OSCSetSendTargetConfirm from the phone at 127.0.0.1:" in str(err.value)
    assert "\n" not in str(err.value)


# -- 2. the phone's clock stepped forward an hour, then back ----------------------------------------------
DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
START = 10 * 3600 * 60  # 10:00:00 at 60 fps
HOUR = 3600 * 60


def _packet(frame: int, marker: int) -> bytes:
    values = np.full(61, 0.25, np.float32)
    values[0] = marker
    return header_bytes(DEVICE, "iPhone") + frame_block(frame, 0.0, 60, 1, values)


def _forward_and_back(tmp_path, name: str, parts: list[int]) -> list[dict]:
    """The take lines of a session sent at 60 fps in real time: ``parts[0]`` frames, ``parts[1]`` frames an
    hour ahead, ``parts[2]`` frames back on the first clock (marker ``i`` in frame ``i``'s first value)."""
    frames = [START + i + (HOUR if parts[0] <= i < parts[0] + parts[1] else 0) for i in range(sum(parts))]
    rec = record_packets(tmp_path, name, [_packet(f, i) for i, f in enumerate(frames)], rate=60)
    assert rec.accepted == len(frames)
    return build_takes(rec.session_dir, tmp_path / "takes")


def test_a_step_back_after_a_step_forward_lands_where_the_frames_arrived(tmp_path):
    # 1.5 s, the timecode jumps an hour forward for 0.5 s, then back an hour (a clock corrected twice, a
    # timecode source switched and back), 1.5 s more, sent at 60 fps in real time. Before, the frames after
    # the step back were taken for late frames of the recording (its step forward left a gap that held
    # them): the hour-forward half second and the frames after it made one take with the last 60 frames
    # before the jump, cut from the rest where the clock did not jump.
    parts = [90, 30, 90]
    lines = _forward_and_back(tmp_path, "twice", parts)
    first = np.cumsum([0, *parts])
    assert [_markers(x).tolist() for x in lines] == [list(range(a, b)) for a, b in zip(first[:-1], first[1:])]
    assert all(x["restarts"] == 1 and x["clock_steps"] == 1 and x["dropped_frames"] == 0 for x in lines)
    for x in lines:  # each on its own clock: its frames arrive when its frame times say
        assert read_take(x["path"]).meta.extra["latency_s"]["median"] < 0.1
    (note,) = [
        r["message"] for r in read_take(lines[2]["path"]).meta.repairs if r["kind"] == "clock_returned"
    ]
    assert "stepped back 3600.0 s at the start of the take (its timecode went to 10:00:02:00.000)" in note
    assert not any(
        r["kind"] == "clock_returned" for x in lines[:2] for r in read_take(x["path"]).meta.repairs
    )


def test_a_few_frames_after_a_step_back_after_a_step_forward_are_stray(tmp_path):
    # Too few frames for a take after the step back (5): before, they joined the first take as late frames,
    # which got 30 DROPPED frames (the hour-forward half second) and them after its end.
    lines = _forward_and_back(tmp_path, "few", [90, 30, 5])
    assert [_markers(x).tolist() for x in lines] == [list(range(90)), list(range(90, 120))]
    assert all(x["stray_packets"] == 5 and x["dropped_frames"] == 0 for x in lines)


def _markers(line: dict) -> np.ndarray:
    take = read_take(line["path"])
    return take.values[take.frame_status == FrameStatus.TRACKED, 0].astype(int)


# -- 3. a CSV read splits its timecodes into seconds and FF once ---------------------------------------------
def _timecode_work(path) -> tuple[int, int]:
    """Reading the CSV ``path``: how often its times were split into whole seconds and FF
    (``timecode_frames`` given times, not fields already split) and its whole seconds counted."""
    import capture.timecode as tc

    splits = counts = 0

    def profile(frame, event, _arg):
        nonlocal splits, counts
        if event != "call" or frame.f_code.co_filename != tc.__file__:
            return
        if frame.f_code.co_name == "timecode_frames":
            splits += not isinstance(frame.f_locals["seconds_of_day"], getattr(tc, "TimecodeFields", ()))
        counts += frame.f_code.co_name == "whole_seconds"

    sys.setprofile(profile)
    try:
        read_livelink_csv(path)
    finally:
        sys.setprofile(None)
    return splits, counts


def test_a_csv_read_splits_its_timecodes_once(samples):
    # Before, the app's CSV's times were split 5 times (to look for milliseconds, for FF's top, to find the
    # rate, twice to count whole seconds) and its whole seconds counted twice (a sort of every row each).
    for name in ("alexdjulin_S07/S07-001.csv", "neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"):
        assert _timecode_work(samples / "livelinkface" / name) == (1, 1), name
