"""Live Link Face's newer realtime stream (Unreal Engine 5.6+ "Live Link Face" source): the CPS control
session (``capture.cps_control``), the realtime packet (``capture.realtime_packet``) and ``listen --phone``
against the simulated phone (``capture.simulate.cps_phone``), over real loopback sockets."""

from __future__ import annotations

import json
import re
import socket
import struct
import subprocess
import sys
import time

import numpy as np
import pytest
from live_helpers import Listener, run_cli, synthetic_take, wait_until

from capture import cps_control as cps
from capture.realtime_packet import (
    MAX_REALTIME_PACKET_BYTES,
    ArkitMapping,
    decode_realtime_packet,
    encode_realtime_packet,
)
from capture.record_log import LogReader, RecordType
from capture.simulate.cps_phone import DEVICE_ID, RealtimeFrames, SimulatedPhone
from capture.take import FrameStatus, read_take, write_take


def test_realtime_packet_layout_and_bad_input():
    packet = encode_realtime_packet(
        "subj", 216001, 0.5, 60, 1, [0.0, 1.0, 0.5], (1, 2, 3, 4, 5, 6), version=7
    )
    # u16 version | u16 len + id | i32 frame | f32 sub-frame | i32 num | i32 den | u16 count | u16s | 6 f32
    assert packet[:8] == struct.pack("<HH", 7, 4) + b"subj"
    assert packet[8:24] == struct.pack("<ifii", 216001, 0.5, 60, 1)
    assert packet[24:32] == struct.pack("<HHHH", 3, 0, 65535, 32768)
    assert packet[32:] == struct.pack("<6f", 1, 2, 3, 4, 5, 6)
    decoded = decode_realtime_packet(packet)
    assert (decoded.version, decoded.subject_id, decoded.frame_number) == (7, "subj", 216001)
    np.testing.assert_allclose(decoded.controls, [0.0, 1.0, 32768 / 65535], rtol=1e-6)
    assert decode_realtime_packet(packet[:-1]) == "short"
    assert decode_realtime_packet(b"\1") == "short"
    assert decode_realtime_packet(b"\0" * (MAX_REALTIME_PACKET_BYTES + 1)) == "oversized"
    assert decode_realtime_packet(struct.pack("<HH", 1, 2) + b"\xff\xfe" + packet[8:]) == "bad_text"
    rng = np.random.default_rng(0)
    for size in rng.integers(0, 200, 3000):  # random bytes: a reason or a packet, never an exception
        decode_realtime_packet(rng.bytes(int(size)))


def test_arkit_mapping_puts_controls_and_head_pose_in_engine_order():
    mapping = ArkitMapping(["jawOpen", "EyeBlinkLeft", "CTRL_not_a_channel"])
    packet = decode_realtime_packet(
        encode_realtime_packet("s", 0, 0.0, 60, 1, [1.0, 0.25, 0.5], (0.1, 0.2, 0.3, 9, 9, 9))
    )
    values = mapping.values(packet)
    assert values[17] == 1.0 and values[0] == pytest.approx(0.25, abs=1 / 65535)  # JawOpen, EyeBlinkLeft
    np.testing.assert_allclose(values[52:55], [0.3, 0.2, 0.1], rtol=1e-6)  # HeadYaw, HeadPitch, HeadRoll
    assert mapping.unmatched == ["CTRL_not_a_channel"] and "LeftEyeYaw" in mapping.missing


def test_control_frames_are_framed_as_unreal_frames_them():
    message = {"sessionId": "handshake", "addressPath": "/session/start", "type": "request"}
    frame = cps.encode_frame(message)
    payload = frame[17:]
    assert frame[:17] == b"CPSCONTROL\0" + struct.pack("<HI", 1, len(payload))
    a, b = socket.socketpair()
    with a, b:
        a.sendall(frame)
        assert cps.read_frame(b, time.monotonic() + 5) == message
        for bad, why in (
            (b"HTTP/1.1 200 OK\r\n\r\n", "not a Capture Protocol Stack control stream"),
            (b"CPSCONTROL\0" + struct.pack("<HI", 1, 1 << 30), "bytes (at most"),
            (b"CPSCONTROL\0" + struct.pack("<HI", 2, 2) + b"{}", "control protocol version 2"),
            (b"CPSCONTROL\0" + struct.pack("<HI", 1, 2) + b"[]", "not a JSON object"),
        ):
            a.sendall(bad)
            with pytest.raises(cps.ControlError, match=re.escape(why)):
                cps.read_frame(b, time.monotonic() + 5)
            b.setblocking(False)  # what is left of a refused frame
            try:
                while b.recv(65536):
                    pass
            except BlockingIOError:
                pass
        with pytest.raises(TimeoutError):
            cps.read_frame(b, time.monotonic() + 0.2)


def _expected_values(frames: RealtimeFrames) -> np.ndarray:
    """The 61 values listen records of the simulated phone's frames: controls quantized to u16, head pose
    in HeadYaw/HeadPitch/HeadRoll, the eyes' rotations 0."""
    out = np.zeros((frames.controls.shape[0], 61), dtype=np.float32)
    out[:, :52] = (
        np.rint(np.clip(frames.controls.astype(np.float64), 0, 1) * 65535).astype(np.float32) / 65535
    )
    out[:, 52:55] = frames.head_pose[:, [2, 1, 0]]
    return out


def _phone_notes(listener: Listener, kind: str) -> list[dict]:
    """The ``kind`` notes (``phone_session``, ``phone_streaming``) in the listener's session log: each line
    ``PhoneStream`` says is noted as it is said. (Read there rather than in the listener's stderr: a line
    said within milliseconds of the address line can come in the same read as it, into the buffer that
    ``Listener`` reads the address line from and ``communicate`` does not.)"""
    records = LogReader(listener.session_dir / "frames.log")
    notes = [json.loads(bytes(p[1:])) for p in records if p[0] == RecordType.NOTE]
    return [note for note in notes if note.get("kind") == kind]


def _listen_to(phone: SimulatedPhone, out, *extra: str) -> Listener:
    host, port = phone.start()
    return Listener(out, "--phone", f"{host}:{port}", *extra)


def test_listen_phone_records_an_arkit_subject_as_the_classic_stream_does(tmp_path):
    frames = RealtimeFrames.of_take(synthetic_take(180))
    garbage = [
        b"",
        b"\1\0",
        b"\0" * (MAX_REALTIME_PACKET_BYTES + 10),
        encode_realtime_packet("other", 1, 0, 60, 1, []),
    ]
    with SimulatedPhone(frames, extra_datagrams=garbage) as phone:
        listener = _listen_to(phone, tmp_path / "out")
        try:
            wait_until(phone.finished, "all frames sent")
            wait_until(lambda: "/session/keep-alive" in phone.requests, "a keep-alive")
        finally:
            summaries, err, code = listener.stop()
    assert code == 0, err
    assert "Traceback" not in err
    (streaming,) = _phone_notes(listener, "phone_streaming")
    assert len(streaming["controls"]) == 52 and streaming["message"] == "subject iPhone of Simulated iPhone"
    assert phone.requests[:4] == ["/session/start", "/information", "/stream/subjects", "/stream/start"]
    assert phone.requests[-2:] == ["/stream/stop", "/session/stop"]  # the session ended as Unreal ends it
    (take_summary,) = summaries
    assert take_summary["device"] == DEVICE_ID and take_summary["subject"] == "iPhone"
    assert take_summary["valid_frames"] == 180 and take_summary["dropped_frames"] == 0
    assert take_summary["rejected"] == {
        "realtime_short": 2,
        "realtime_oversized": 1,
        "realtime_unknown_subject": 1,
    }
    take = read_take(take_summary["path"])
    assert take.meta.fps == 60 and take.meta.source_kind == "livelink_udp"
    np.testing.assert_allclose(take.values, _expected_values(frames), atol=1e-6)
    # recover rebuilds the same take from the session log
    rebuilt = run_cli("recover", str(listener.session_dir.parent), "--all", "-o", str(tmp_path / "again"))
    assert rebuilt.returncode == 0, rebuilt.stderr
    (again,) = (tmp_path / "again").iterdir()
    np.testing.assert_array_equal(read_take(again).values, take.values)


@pytest.mark.parametrize(
    ("behaviour", "line"),
    [
        ("refuse", "the phone refused /session/start: requestFailed: the app is recording"),
        ("silent", "the phone did not answer /session/start within 3 s"),
        ("no_subjects", "the phone lists no subject to stream"),
        ("garbage", "not a Capture Protocol Stack control stream (it began b'HTTP/1.1 40')"),
    ],
)
def test_listen_phone_that_misbehaves_gets_one_clear_line(tmp_path, behaviour, line):
    with SimulatedPhone(RealtimeFrames.of_take(synthetic_take(10)), behaviour=behaviour) as phone:
        listener = _listen_to(phone, tmp_path / "out")
        try:
            log = listener.session_dir / "frames.log"  # the line is said before it is noted in the log
            wait_until(lambda: log.exists() and b"phone_session" in log.read_bytes(), "phone_session note")
        finally:
            summaries, err, code = listener.stop()
    assert code == 0 and "Traceback" not in err, err
    # said (and noted) once, not once per retry; the line, when it came after the address line, with it
    assert [note["message"] for note in _phone_notes(listener, "phone_session")] == [line]
    assert err.count(line) <= 1 and (line not in err or f"{line}; trying again every 5 s" in err)
    assert summaries[0]["path"] is None  # no take, and the session's "no take recorded" line


def test_listen_phone_no_phone_there_and_bad_option(tmp_path):
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    listener = Listener(tmp_path / "out", "--phone", f"127.0.0.1:{port}")
    log = listener.session_dir / "frames.log"  # the failure is kept in the session log as it is said
    wait_until(lambda: log.exists() and b"phone_session" in log.read_bytes(), "phone_session note")
    _, err, code = listener.stop()
    # the line may come before the listener's address line (which Listener reads): the log holds it too
    assert code == 0 and "Traceback" not in err and b"cannot connect (Connection refused)" in log.read_bytes()
    bad = run_cli("listen", "-o", str(tmp_path / "o2"), "--phone", "nowhere", "--duration", "1")
    assert bad.returncode == 1 and "destination must be HOST:PORT" in bad.stderr
    assert "Traceback" not in bad.stderr and not (tmp_path / "o2").exists()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:  # the UDP port asked for is in use
        taken.bind(("127.0.0.1", 0))
        used = str(taken.getsockname()[1])
        busy = run_cli(
            "listen",
            "-o",
            str(tmp_path / "o3"),
            "--phone",
            "127.0.0.1:9",
            "--bind",
            "127.0.0.1",
            "--port",
            used,
        )
    assert busy.returncode == 1 and f"cannot listen on UDP 127.0.0.1:{used}" in busy.stderr, busy.stderr
    assert "Traceback" not in busy.stderr and not (tmp_path / "o3").exists()


def test_listen_phone_keeps_what_came_and_reconnects_after_the_phone_drops(tmp_path):
    frames = RealtimeFrames.of_take(synthetic_take(120))
    with SimulatedPhone(frames, behaviour="drop_once", drop_after=50) as phone:
        listener = _listen_to(phone, tmp_path / "out")
        try:
            wait_until(phone.finished, "all frames sent (over two control sessions)")
        finally:
            summaries, err, code = listener.stop()
    assert code == 0 and "Traceback" not in err, err
    assert [n["message"] for n in _phone_notes(listener, "phone_session")] == [
        "the phone closed the connection"
    ]
    assert phone.connections == 2 and phone.requests.count("/stream/start") == 2
    valid = sum(s["valid_frames"] for s in summaries)
    assert valid == 120  # the 50 before the drop and the 70 after, none lost
    recorded = np.concatenate(
        [
            read_take(s["path"]).values[read_take(s["path"]).frame_status == FrameStatus.TRACKED]
            for s in summaries
        ]
    )
    np.testing.assert_allclose(recorded, _expected_values(frames), atol=1e-6)


def test_replay_protocol_realtime_is_the_phone_for_listen_phone(tmp_path):
    take = synthetic_take(90)
    folder = write_take(take, tmp_path / "takes")
    with socket.socket() as probe:  # a port free a moment ago
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    replay = subprocess.Popen(
        [sys.executable, "-m", "capture", "replay", str(folder), "--protocol", "realtime"]
        + ["--to", f"127.0.0.1:{port}", "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_until(lambda: _accepts(port) or replay.poll() is not None, "the phone's control server")
        listener = Listener(tmp_path / "out", "--phone", f"127.0.0.1:{port}")
        try:
            out, err = replay.communicate(timeout=120)
        finally:
            summaries, listen_err, code = listener.stop()
    finally:
        if replay.poll() is None:
            replay.kill()
            replay.communicate()
    assert replay.returncode == 0 and '"packets_sent": 90' in out, err
    assert code == 0, listen_err
    assert sum(s["valid_frames"] for s in summaries if s.get("path")) == 90
    refused = run_cli(
        "replay", str(folder), "--protocol", "realtime", "--to", f"127.0.0.1:{port}", "--loss", "0.1"
    )
    assert refused.returncode == 1 and "--loss: for the classic stream only" in refused.stderr


def _accepts(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_classic_listen_is_unchanged_by_the_phone_option(tmp_path):
    """Without --phone the address line and the defaults (127.0.0.1, port 11111) are the classic ones."""
    proc = subprocess.run(
        [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "o"), "--duration", "0.3"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if "Address already in use" in proc.stderr:  # another listen on this machine holds 11111
        pytest.skip("port 11111 is in use")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.startswith("listening on udp://127.0.0.1:11111 -> ")
