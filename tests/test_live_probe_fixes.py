"""What a probe of the live recorder found, each fixed: frames that share a frame time, a short
PyLiveLinkFace stream, a forward step of the phone's clock, two senders with one device id and subject,
a take across midnight, the messages for a missing sound card and for whole streams rejected, an NTSC
rate, OSC replies in a bundle, ``recover`` with nothing to do and the battery level. Real UDP sockets on
loopback; every packet carries its own marker (value 0), so each frame of a take traces back to it."""

from __future__ import annotations

import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from live_helpers import record_packets, run_cli, start_recorder
from test_osc_remote import FakePhone

from capture import FrameStatus, build_takes, read_take
from capture.live_cli import _warnings
from capture.livelink import frame_block, header_bytes
from capture.osc_remote import PhoneRemote
from capture.session_takes import _clock_steps

DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
START = 10 * 3600 * 60  # 10:00:00 at 60 fps
DAY_FRAMES = 24 * 3600 * 60


def _packet(frame: int, sub: float = 0.0, num: int = 60, den: int = 1, marker: float = 0.0, subject="iPhone"):
    values = np.full(61, 0.25, np.float32)
    values[0] = marker
    return header_bytes(DEVICE, subject) + frame_block(frame, sub, num, den, values)


def _takes(tmp_path, session: str, packets: list[bytes]) -> list[dict]:
    rec = record_packets(tmp_path, session, packets)
    assert rec.accepted == len(packets), rec.rejected
    return build_takes(rec.session_dir, tmp_path)


def _markers(line: dict) -> np.ndarray:
    take = read_take(line["path"])
    return take.values[take.frame_status == FrameStatus.TRACKED, 0]


# -- 1. frames that share a frame time are not duplicates -------------------------------------------------
def test_a_sender_ticking_twice_per_frame_number_keeps_every_frame(tmp_path):
    # A 60 Hz sender declaring 30 fps without sub-frames (frame numbers i // 2), every packet arriving twice.
    packets = [_packet(START // 2 + i // 2, num=30, marker=i) for i in range(240) for _ in range(2)]
    (line,) = _takes(tmp_path, "halfdup", packets)
    assert line["frames"] == 240 and line["dropped_frames"] == 0 and "frame_clock" not in line
    assert line["duplicates"] == 240 and line["same_time_frames"] == 120 and line["same_time_dropped"] == 0
    take = read_take(line["path"])
    assert take.meta.fps == 60 and take.meta.timecode_rate == 30
    assert take.meta.extra["same_time_frames"] == 120
    np.testing.assert_allclose(take.time, np.arange(240) / 60, atol=1e-9)
    assert np.array_equal(_markers(line), np.arange(240))
    assert any("spread evenly" in w for w in _warnings(line))


def test_a_few_frames_repeating_a_frame_time_are_counted_and_said(tmp_path):
    packets = [_packet(START + i, marker=i) for i in range(300)]
    for k in (250, 150, 50):  # another frame with the frame time of the one before it
        packets.insert(k + 1, _packet(START + k, marker=1000 + k))
    (line,) = _takes(tmp_path, "glitch", packets)
    assert line["frames"] == 300 and line["duplicates"] == 0
    assert line["same_time_frames"] == 3 and line["same_time_dropped"] == 3
    assert np.array_equal(_markers(line), np.arange(300))  # the first of each frame time
    assert any("3 frames repeat the frame time" in w for w in _warnings(line))


# -- 2. PyLiveLinkFace's clock (milliseconds counted as frames) is told within a second ---------------------
def test_a_short_pylivelinkface_stream_is_placed_by_arrival(tmp_path):
    def frame(t: float) -> int:  # hours:minutes:seconds:milliseconds fed to a timecode at 60 fps, 1-based
        return int(t) * 60 + int(round((t - int(t)) * 1000)) + 1

    n = 90  # 1.5 s at 60 fps: the clock falls back once
    head = header_bytes("$" + "A" * 35, "Player")
    values = [np.full(61, i / 1000, np.float32) for i in range(n)]
    packets = [head + frame_block(frame(3600.25 + i / 60), 0.4730, 60, 1, v) for i, v in enumerate(values)]
    began = time.monotonic()
    rec = record_packets(tmp_path, "pyllf", packets, rate=60.0)
    sending = time.monotonic() - began  # 1.5 s and more: a loaded machine's sender falls behind
    assert rec.accepted == n
    (line,) = build_takes(rec.session_dir, tmp_path)
    assert line["frame_clock"]["placed_by"] == "arrival" and "milliseconds" in line["frame_clock"]["reason"]
    assert line["restarts"] == 0 and line["stray_packets"] == 0
    take = read_take(line["path"])
    tracked = take.frame_status == FrameStatus.TRACKED
    assert take.meta.fps == 60 and tracked.sum() == n
    np.testing.assert_allclose(take.values[tracked, 0], np.arange(n) / 1000, atol=1e-6)
    assert 1.2 < take.duration_s < sending  # real time (as the packets came), not 16x


# -- 3. a forward step of the phone's clock is no network loss ---------------------------------------------
def test_a_forward_clock_step_is_a_cut_and_real_loss_stays_dropped_frames(tmp_path):
    # 0.5 s, the clock steps 1 s forward (an NTP correction) with packets coming on, 0.5 s, then 0.5 s of
    # packets lost on the network, 0.5 s.
    frame = [START + i + (60 if i >= 30 else 0) for i in range(120)]
    packets = [None if 60 <= i < 90 else _packet(frame[i], marker=i) for i in range(120)]
    rec = record_packets(tmp_path, "step", packets, rate=60.0)
    lines = build_takes(rec.session_dir, tmp_path)
    assert [(x["frames"], x["dropped_frames"]) for x in lines] == [(30, 0), (90, 30)], lines
    assert all(x["clock_steps"] == 1 and x["restarts"] == 0 for x in lines)
    assert np.array_equal(_markers(lines[0]), np.arange(30))
    assert np.array_equal(_markers(lines[1]), [*range(30, 60), *range(90, 120)])
    for x in lines:  # each part on its own clock: its frames arrive when its frame times say
        assert read_take(x["path"]).meta.extra["latency_s"]["median"] < 0.1
    assert any("jumped forward 1 time(s)" in w for w in _warnings(lines[0]))


# -- 4. two senders with one device id and subject -----------------------------------------------------------
def _interleaved(tmp_path, session: str, streams: list[list[bytes]]) -> list[dict]:
    """Each list of packets sent from a socket of its own, the sockets taking turns."""
    rec, port, runner = start_recorder(tmp_path, session)
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in streams]
    try:
        for i, group in enumerate(zip(*streams)):
            for s, p in zip(socks, group):
                s.sendto(p, ("127.0.0.1", port))
            if i % 50 == 49:
                time.sleep(0.005)
        sources = [f"127.0.0.1:{s.getsockname()[1]}" for s in socks]
    finally:
        for s in socks:
            s.close()
    time.sleep(0.5)
    rec.request_stop()
    runner.join()
    rec.close()
    assert rec.accepted == sum(len(x) for x in streams)
    lines = build_takes(rec.session_dir, tmp_path)
    return [x | {"sources": sources} for x in lines]


def test_two_senders_with_one_device_and_subject_are_kept_apart(tmp_path):
    first = [_packet(START + i, 0.1, marker=i) for i in range(120)]
    second = [_packet(3 * START + i, 0.6, marker=500 + i) for i in range(120)]
    lines = _interleaved(tmp_path, "twins", [first, second])
    names = [x["path"].rsplit("/", 1)[1] for x in lines]
    assert names == ["twins_iPhone_5904AA4B", "twins_iPhone_5904AA4B-2"], names
    assert all(x["frames"] == 120 and "frame_clock" not in x and x["restarts"] == 0 for x in lines)
    assert np.array_equal(_markers(lines[0]), np.arange(120))
    assert np.array_equal(_markers(lines[1]), 500 + np.arange(120))
    assert lines[0]["senders"] == lines[1]["senders"] == lines[0]["sources"]
    assert any("2 senders" in w and lines[0]["sources"][1] in w for w in _warnings(lines[1]))


def test_the_phone_sending_here_twice_from_two_sockets_is_one_stream(tmp_path):
    # The app opens a socket per Live Link target: listed twice, its packets come from two ports.
    packets = [_packet(START + i, 0.1, marker=i) for i in range(120)]
    (line,) = _interleaved(tmp_path, "twice", [packets, packets])
    assert line["frames"] == 120 and line["duplicates"] == 120 and "senders" not in line
    assert np.array_equal(_markers(line), np.arange(120))


# -- 5. a take across midnight -----------------------------------------------------------------------------
def test_a_take_across_midnight_stays_one_take(tmp_path):
    order = list(range(180))
    order.insert(100, order.pop(85))  # a packet from before midnight arrives after the wrap
    packets = [_packet((DAY_FRAMES - 90 + i) % DAY_FRAMES, 0.25, marker=i) for i in order]
    (line,) = _takes(tmp_path, "midnight", packets)
    assert line["frames"] == 180 and line["restarts"] == 0 and line["dropped_frames"] == 0
    assert line["out_of_order"] == 1 and line["stray_packets"] == 0
    take = read_take(line["path"])
    np.testing.assert_allclose(take.time, np.arange(180) / 60, atol=1e-9)
    assert np.array_equal(_markers(line), np.arange(180))
    assert take.meta.start_timecode.startswith("23:59:58:30")


def test_a_take_across_midnight_with_packets_lost_over_it_stays_one_take(tmp_path):
    # 1.5 s lost across midnight: the clock falls back by a day less the loss
    kept = [i for i in range(240) if not 80 <= i < 170]
    packets = [_packet((DAY_FRAMES - 120 + i) % DAY_FRAMES, 0.25, marker=i) for i in kept]
    (line,) = _takes(tmp_path, "midnight-loss", packets)
    assert line["frames"] == 240 and line["restarts"] == 0 and line["dropped_frames"] == 90


def test_wifi_jitter_and_loss_bursts_are_no_clock_step():
    """Arrival jitter (and packets delivered in 0.3 s power-save bursts) make a side's pace uncertain by
    up to a quarter; that error must not turn a real loss of 2-4 s into a clock step, and a real step of
    0.6-1 s during continuous arrivals is still one."""
    rng = np.random.default_rng(7)

    def steps(loss_s: float, step_s: float, bursts: bool) -> bool:
        sent = np.arange(600) / 60.0
        sent = sent[~((sent >= 3) & (sent < 3 + loss_s))]
        frame_time = np.where(sent >= 3, sent + step_s, sent)
        arrival = sent + rng.exponential(0.05, sent.size)
        if bursts:
            arrival = np.ceil(arrival / 0.3) * 0.3
        arrival[rng.random(sent.size) < 0.02] += rng.uniform(0.1, 0.3)
        return bool(_clock_steps(frame_time, arrival))

    for loss_s, bursts in ((2, False), (4, False), (2, True), (4, True)):
        assert not any(steps(loss_s, 0.0, bursts) for _ in range(30)), (loss_s, bursts)
    for step_s, bursts in ((1.0, False), (0.6, False), (1.0, True)):
        assert sum(steps(0.0, step_s, bursts) for _ in range(30)) >= 27, (step_s, bursts)


# -- 6. messages ---------------------------------------------------------------------------------------------
def test_no_sound_card_says_how_to_list_the_devices(tmp_path):
    try:
        import sounddevice

        inputs = any(d["max_input_channels"] > 0 for d in sounddevice.query_devices())
    except OSError:  # no PortAudio: the command says so, below
        inputs = False
    if inputs:
        pytest.skip("this machine has a sound input device")
    for device in ("0", "default"):
        r = run_cli("listen", "-o", str(tmp_path), "--port", "0", "--audio-device", device, "--duration", "1")
        if "libportaudio2" in r.stderr:
            pytest.skip("PortAudio is not installed here")
        assert r.returncode == 1 and len(r.stderr.splitlines()) == 1, r.stderr
        assert "python -m sounddevice" in r.stderr and "Error querying" not in r.stderr, r.stderr


def test_streams_rejected_whole_get_a_hint_beside_a_take(tmp_path):
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path), "--port", "0", "--duration", "30"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = int(proc.stderr.readline().split("udp://127.0.0.1:")[1].split(" ")[0])
    # PyLiveLinkFace writes the subject's length in characters: 'Frédéric' is 8, its UTF-8 9 bytes.
    zeros = [0.0] * 61
    pyllf = struct.pack(">Bi4si", 6, 4, b"DEV3", 8) + "Frédéric".encode() + frame_block(1, 0.5, 60, 1, zeros)
    sub_one = header_bytes("DEV2", "ok") + frame_block(100, 1.0, 60, 1, zeros)  # sub-frame 1.0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(30):
            s.sendto(_packet(START + i), ("127.0.0.1", port))
            s.sendto(_packet(START + i, subject="S" * 800), ("127.0.0.1", port))  # oversized
            s.sendto(sub_one, ("127.0.0.1", port))
            s.sendto(pyllf, ("127.0.0.1", port))
    time.sleep(0.4)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "30 frames" in err
    for reason in ("oversized", "bad_frame_time", "count"):
        assert f"  {reason}: " in err, err
    assert "in characters, not UTF-8 bytes" in err and "sub-frame of 1.0" in err


def test_recover_with_nothing_left_to_do_is_no_failure(tmp_path):
    rec = record_packets(tmp_path, "done", [_packet(START + i) for i in range(30)])
    build_takes(rec.session_dir, tmp_path)  # as listen does: the session is complete
    r = run_cli("recover", str(tmp_path))
    assert r.returncode == 0 and "nothing to recover" in r.stderr, r.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    r = run_cli("recover", str(empty))  # no session at all: a wrong folder
    assert r.returncode == 1 and "no recording session here" in r.stderr, r.stderr


# -- 7. an NTSC rate -----------------------------------------------------------------------------------------
def test_a_stream_at_an_ntsc_rate_is_a_take_at_that_rate(tmp_path):
    (line,) = _takes(tmp_path, "ntsc", [_packet(i, num=30000, den=1001, marker=i) for i in range(120)])
    take = read_take(line["path"])
    assert take.meta.fps == pytest.approx(30000 / 1001, rel=1e-9) and take.meta.timecode_rate == take.meta.fps
    assert line["frames"] == 120 and line["dropped_frames"] == 0
    # a stream declaring 60/1 whose frames come at 59.94 per second of its clock (a replay of a take whose
    # rows came that way) is a 60 fps take: the declared rate names it, not the frames' own rate
    ticks = np.arange(120) * 60 / (60000 / 1001)
    packets = [_packet(int(f), f - int(f), marker=i) for i, f in enumerate(ticks)]
    (line,) = _takes(tmp_path / "60", "sixty", packets)
    assert read_take(line["path"]).meta.fps == 60.0 and line["frames"] == 120


# -- 8. OSC: replies in a bundle, the battery level ----------------------------------------------------------
class BundlePhone:
    """Answers /OSCSetSendTarget and /BatteryQuery like the app, each reply wrapped in an OSC bundle."""

    def __init__(self):
        from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
        from pythonosc.osc_message import OscMessage
        from pythonosc.osc_message_builder import OscMessageBuilder

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]

        def reply(target, address, *args):
            msg = OscMessageBuilder(address=address)
            for a in args:
                msg.add_arg(a)
            bundle = OscBundleBuilder(IMMEDIATELY)
            bundle.add_content(msg.build())
            self.sock.sendto(bundle.build().dgram, target)

        def serve():
            target = None
            while True:
                try:
                    data, _ = self.sock.recvfrom(4096)
                except OSError:
                    return
                msg = OscMessage(data)
                if msg.address == "/OSCSetSendTarget":
                    target = (msg.params[0], msg.params[1])
                    reply(target, "/OSCSetSendTargetConfirm")
                elif msg.address == "/BatteryQuery" and target:
                    reply(target, "/Battery", 0.8)

        threading.Thread(target=serve, daemon=True).start()

    def close(self):
        self.sock.close()


def test_replies_in_a_bundle_are_read_and_the_battery_has_its_float32_digits():
    phone = BundlePhone()
    try:
        with PhoneRemote("127.0.0.1", phone.port, timeout_s=5) as remote:
            assert remote.battery() == 0.8  # sent as a 32-bit float: 0.800000011920929
    finally:
        phone.close()
    plain = FakePhone(battery=0.8)
    try:
        r = run_cli("remote", f"127.0.0.1:{plain.port}", "battery")
        assert r.returncode == 0 and r.stderr.strip().endswith("battery=0.8"), r.stderr
    finally:
        plain.close()
