"""How a stream's packets become takes when the network or the sender misbehaves: every packet twice,
sub-frames at twice the declared rate, a change of rate, late packets and heavy jitter, a stray frame
number, restarts among all that, and an IPv4 phone on a dual-stack socket with an allow-list. Real UDP
sockets on loopback, the recorder API and the take builder."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest
from live_helpers import Listener, record_packets, synthetic_take

from capture import FrameStatus, LiveRecorder, build_takes, read_take
from capture.livelink import frame_block, header_bytes
from capture.replay import Impairment, replay_take

DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
START = 10 * 3600 * 60  # 10:00:00 at 60 fps


def _packet(frame: int, sub: float = 0.0, num: int = 60, marker: float = 0.0) -> bytes:
    """A packet whose values carry ``marker`` (value 0), so a take shows which packet each frame is."""
    values = np.full(61, 0.25, np.float32)
    values[0] = marker
    return header_bytes(DEVICE, "iPhone") + frame_block(frame, sub, num, 1, values)


def _takes(tmp_path, session: str, packets: list[bytes]) -> list[dict]:
    rec = record_packets(tmp_path, session, packets)
    assert rec.accepted + sum(rec.rejected.values()) == rec.datagrams == len(packets)
    return build_takes(rec.session_dir, tmp_path)


def _markers(line: dict) -> np.ndarray:
    take = read_take(line["path"])
    return take.values[take.frame_status == FrameStatus.TRACKED, 0]


# -- F1: every packet arrives twice or three times (the phone lists this computer more than once) --------
@pytest.mark.parametrize("copies", [2, 3])
def test_every_packet_arriving_several_times_keeps_the_phone_clock(tmp_path, copies):
    packets = [_packet(START + i, 0.25, marker=i) for i in range(300) for _ in range(copies)]
    (line,) = _takes(tmp_path, f"dup{copies}", packets)
    assert "frame_clock" not in line, line["frame_clock"]
    assert line["frames"] == 300 and line["dropped_frames"] == 0
    assert line["duplicates"] == 300 * (copies - 1) and line["restarts"] == 0
    take = read_take(line["path"])
    assert np.allclose(take.time, np.arange(300) / 60)
    assert np.array_equal(_markers(line), np.arange(300))


# -- F3: 60 Hz tracking with a 30 fps timecode: frame numbers repeat, sub-frames tell the frames apart ----
def test_sub_frames_are_frames_of_their_own(tmp_path):
    packets = [_packet(30 * 3600 * 12 + i // 2, 0.5 * (i % 2), num=30, marker=i) for i in range(600)]
    (line,) = _takes(tmp_path, "sub", packets)
    assert line["frames"] == 600 and line["duplicates"] == 0 and line["dropped_frames"] == 0
    take = read_take(line["path"])
    assert take.meta.fps == 60 and take.meta.timecode_rate == 30  # the packets' rate, the declared rate
    assert np.allclose(take.time, np.arange(600) / 60)
    assert np.array_equal(_markers(line), np.arange(600))


# -- F4: the same phone switches its frame rate (the app restarted with another setting) -----------------
def test_a_change_of_rate_is_a_new_recording_and_a_lone_packet_at_another_rate_is_rejected(tmp_path):
    packets = [_packet(500_000 + i, 0.1, 60, marker=i) for i in range(300)]
    packets += [_packet(250_100 + i, 0.1, 30, marker=1000 + i) for i in range(600)]  # now at 30 fps
    packets.insert(150, _packet(250_000, 0.1, 30))  # one packet at another rate amid the 60 fps frames
    lines = _takes(tmp_path, "rate", packets)
    first, second = (read_take(x["path"]) for x in lines)
    assert [x["frames"] for x in lines] == [300, 600] and lines[0]["rejected"] == {"rate_changed": 1}
    assert first.meta.fps == 60 and second.meta.fps == 30 and second.meta.extra["rate"] == [30, 1]
    assert lines[0]["restarts"] == 1 and lines[0]["rate_changes"] == 1 and lines[0]["stray_packets"] == 0
    assert np.array_equal(_markers(lines[0]), np.arange(300))
    assert np.array_equal(_markers(lines[1]), 1000 + np.arange(600))


def test_a_rate_change_at_the_very_end_is_not_logged_half(tmp_path):
    """Packets held back at a new rate that never became three in a row are counted when listen stops."""
    packets = [_packet(START + i) for i in range(100)] + [_packet(START // 2 + 60, num=30)] * 2
    lines = _takes(tmp_path, "tail", packets)
    assert [x["frames"] for x in lines] == [100] and lines[0]["rejected"] == {"rate_changed": 2}


# -- F5: late packets and heavy jitter do not restart the clock -------------------------------------------
@pytest.mark.parametrize("late", [2, 12, 40])
def test_packets_more_than_a_second_late_stay_in_their_take(tmp_path, late):
    order = [f for f in range(600) if not 300 <= f < 300 + late]
    k = order.index(375)
    order[k + 1 : k + 1] = list(range(300, 300 + late))  # `late` packets 1.25 s (75 frames) late
    (line,) = _takes(tmp_path, f"late{late}", [_packet(START + f, marker=f) for f in order])
    assert line["frames"] == 600 and line["dropped_frames"] == 0 and line["restarts"] == 0
    assert line["out_of_order"] == late and "frame_clock" not in line
    assert np.array_equal(_markers(line), np.arange(600))


def test_heavily_jittered_packets_keep_the_phone_clock(tmp_path):
    """1.5 s of uniform jitter at 60 fps: most packets come after later ones, some 1.5 s late."""
    arrival = np.arange(1200) / 60 + np.random.default_rng(3).uniform(0, 1.5, 1200)
    order = np.argsort(arrival)
    (line,) = _takes(tmp_path, "jit", [_packet(START + int(f), marker=f) for f in order])
    assert "frame_clock" not in line and line["restarts"] == 0 and line["stray_packets"] == 0
    assert line["frames"] == 1200 and line["dropped_frames"] == 0 and line["out_of_order"] > 900
    assert np.array_equal(_markers(line), np.arange(1200))


def test_replay_with_jitter_through_listen(tmp_path):
    """The real sender and listener: 0.3 s of jitter at speed 4 is 1.2 s of phone frame time."""
    take = synthetic_take(480, seed=2)
    take.values[:, 0] = np.arange(480)
    listener = Listener(tmp_path / "out")
    report = replay_take(
        take, "127.0.0.1", listener.port, speed=4.0, impairment=Impairment(jitter_s=0.3, seed=1)
    )
    lines, err, code = listener.stop()
    assert code == 0, err
    assert report.reordered > 200 and len(lines) == 1, lines
    (line,) = lines
    assert "frame_clock" not in line and line["restarts"] == 0 and line["frames"] == 480
    assert np.array_equal(_markers(line), np.arange(480))


def test_restarts_are_still_found_among_late_packets(tmp_path):
    """A clock stepped back 1.5 s (an NTP correction) and a phone restart (a lower frame clock) are new
    recordings, with the stream jittered across them."""
    rng = np.random.default_rng(5)
    frames = [(START + i, 0.0, i) for i in range(600)]
    frames += [(START + 510 + i, 0.3, 1000 + i) for i in range(600)]  # 1.5 s back: the times of the last 90
    frames += [(9_000 + i, 0.0, 2000 + i) for i in range(600)]
    arrival = np.arange(len(frames)) / 60 + rng.uniform(0, 0.5, len(frames))
    packets = [_packet(frames[k][0], frames[k][1], marker=frames[k][2]) for k in np.argsort(arrival)]
    lines = _takes(tmp_path, "rs", packets)
    assert [x["frames"] for x in lines] == [600, 600, 600] and lines[0]["restarts"] == 2
    for n, line in enumerate(lines):
        assert np.array_equal(_markers(line), 1000 * n + np.arange(600))


# -- F8: one packet with a frame number an hour off ---------------------------------------------------------
@pytest.mark.parametrize("hours", [1, -1])
def test_a_stray_frame_number_is_dropped_and_the_take_stays_whole(tmp_path, hours):
    packets = [_packet(START + i, 0.3, marker=i) for i in range(300)]
    packets.insert(150, _packet(START + 150 + hours * 216_000, 0.3, marker=-1))
    (line,) = _takes(tmp_path, "stray", packets)
    assert line["frames"] == 300 and line["restarts"] == 0
    assert line["stray_packets"] == 1 and line["stray_frames"] == 1
    assert np.array_equal(_markers(line), np.arange(300))


# -- F7: an IPv4 phone and --allow on a dual-stack socket ---------------------------------------------------
def test_allow_list_matches_ipv4_mapped_senders_and_networks():
    from capture.recorder import AllowList

    allow = AllowList(["127.0.0.1", "10.1.0.0/16", "::ffff:192.168.1.7", "fe80::1"])
    for host in ["127.0.0.1", "::ffff:127.0.0.1", "::ffff:7f00:1", "10.1.2.3", "::ffff:10.1.200.9"]:
        assert host in allow, host
    for host in ["192.168.1.7", "::ffff:192.168.1.7", "fe80::1%eth0", "fe80::1"]:
        assert host in allow, host
    for host in ["127.0.0.2", "::ffff:127.0.0.2", "10.2.0.1", "::1", "fe80::2", "not an address"]:
        assert host not in allow, host
    assert allow.entries == ["127.0.0.1", "192.168.1.7", "fe80::1", "10.1.0.0/16"]


@pytest.mark.skipif(not socket.has_ipv6, reason="no IPv6")
@pytest.mark.parametrize("allow", [["127.0.0.1"], ["127.0.0.0/8"], ["::ffff:127.0.0.1"]])
def test_an_ipv4_phone_is_allowed_on_a_dual_stack_socket(tmp_path, allow):
    rec = LiveRecorder(tmp_path, bind="::", port=0, allow=allow, session_id="v6")
    try:
        _, port = rec.open()
    except Exception as exc:  # an IPv6-less machine
        pytest.skip(f"cannot bind ::: {exc}")
    runner = threading.Thread(target=rec.run, kwargs={"duration_s": 20})
    runner.start()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(30):
            s.sendto(_packet(START + i), ("127.0.0.1", port))
    with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:  # ::1 is not on the list
        s.sendto(_packet(START + 30), ("::1", port))
    time.sleep(0.3)
    rec.request_stop()
    runner.join()
    rec.close()
    assert rec.accepted == 30 and rec.rejected["not_allowed"] == 1
    (line,) = build_takes(rec.session_dir, tmp_path)
    assert line["frames"] == 30
