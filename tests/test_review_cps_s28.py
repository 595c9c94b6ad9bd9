"""Review of ``listen --phone`` (Live Link Face's realtime stream, ``capture.cps_control``): hostile control
servers and how a session that streamed and ended is started again, over real loopback sockets."""

from __future__ import annotations

import json
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from live_helpers import Listener, ipv6_loopback, synthetic_take, wait_for_logged_frames, wait_until

from capture import cps_control as cps
from capture.realtime_packet import decode_realtime_packet, encode_realtime_packet
from capture.simulate.cps_phone import RealtimeFrames, SimulatedPhone


class _HostileServer:
    """A control server on 127.0.0.1 that answers every connection's first request with ``answer`` (raw
    bytes) and keeps the connection open until it is stopped; ``connections`` counts them."""

    def __init__(self, answer: bytes):
        self.answer = answer
        self.connections = 0
        self._stop = threading.Event()
        self.server = socket.create_server(("127.0.0.1", 0))
        self.server.settimeout(0.1)
        self.port = self.server.getsockname()[1]
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        open_ones = []
        while not self._stop.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            self.connections += 1
            open_ones.append(conn)
            conn.settimeout(10)
            conn.recv(65536)  # the request
            conn.sendall(self.answer)
        for conn in open_ones:
            conn.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self.server.close()


def test_a_control_message_nested_too_deep_is_one_line_and_the_session_is_tried_again(tmp_path):
    # Old: json.loads raised RecursionError, which killed the control thread with a traceback: no line,
    # no note, never tried again (listen recorded nothing until stopped).
    payload = b"[" * 200_000
    server = _HostileServer(cps.FRAME_MAGIC + struct.pack("<HI", 1, len(payload)) + payload)
    try:
        listener = Listener(tmp_path / "out", "--phone", f"127.0.0.1:{server.port}")
        try:
            wait_until(lambda: server.connections >= 2, "the session tried again")
        finally:
            _, err, code = listener.stop()
    finally:
        server.stop()
    assert code == 0 and "Traceback" not in err and "RecursionError" not in err, err
    log = (listener.session_dir / "frames.log").read_bytes()
    assert b"a control message that is not JSON" in log


def test_a_session_that_streamed_and_dropped_is_started_again_at_once(tmp_path):
    # Unreal's control thread tries a session that did not start again after five seconds, but one that
    # streamed and then ended (OnDisconnect) at once. Old: after retry_s, every time (here 600 s: the frames
    # after the drop never came).
    frames = RealtimeFrames.of_take(synthetic_take(60))
    said: list[str] = []
    notes: list[dict] = []
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as recorder,
        SimulatedPhone(frames, behaviour="drop_once", drop_after=20) as phone,
    ):
        recorder.bind(("127.0.0.1", 0))
        host, port = phone.start()
        stream = cps.PhoneStream(
            host,
            port,
            recorder.getsockname(),
            say=said.append,
            rejected={},
            note=notes.append,
            bind="127.0.0.1",
            retry_s=600.0,
        )
        stream.open()
        stream.start()
        try:
            wait_until(lambda: phone.finished() and phone.connections == 2, "all frames, over two sessions")
            wait_until(lambda: stream.relayed == 60, "all frames relayed")
        finally:
            stream.stop()
        recorder.settimeout(5)
        packets = [recorder.recv(65536) for _ in range(60)]
    assert len(set(packets)) == 60
    assert any(line.endswith("the phone closed the connection; starting the session again") for line in said)
    assert [n["message"] for n in notes if n["kind"] == "phone_session"] == [
        "the phone closed the connection"
    ]


def test_a_session_that_never_starts_still_waits_retry_s(tmp_path):
    """The other half of Unreal's rule: a phone that refuses is not asked again before ``retry_s``."""
    with SimulatedPhone(RealtimeFrames.of_take(synthetic_take(5)), behaviour="refuse") as phone:
        host, port = phone.start()
        stream = cps.PhoneStream(
            host,
            port,
            ("127.0.0.1", 9),
            say=lambda line: None,
            rejected={},
            note=lambda n: None,
            bind="127.0.0.1",
            retry_s=600.0,
        )
        stream.open()
        stream.start()
        try:
            wait_until(lambda: phone.requests == ["/session/start"], "the first request")
            time.sleep(0.5)  # long enough for a wrong at-once retry to show (a second connection)
        finally:
            stream.stop()
    assert phone.connections == 1 and phone.requests == ["/session/start"]


def test_a_realtime_packet_with_bytes_after_the_head_pose_is_read_as_unreal_reads_it():
    # Unreal's FLiveLinkFacePacket::Read reads the fields and checks only that none ran past the end: bytes
    # after the head pose (a later packet version's fields) are read past. Old: every such packet was
    # rejected as "size_mismatch" (a phone whose packets grew would have recorded nothing).
    packet = encode_realtime_packet("subj", 7, 0.25, 60, 1, [0.5, 1.0], (1, 2, 3, 4, 5, 6), version=2)
    longer = decode_realtime_packet(packet + b"\x01\x02\x03\x04")
    plain = decode_realtime_packet(packet)
    assert not isinstance(longer, str), longer
    assert (longer.version, longer.subject_id, longer.frame_number) == (2, "subj", 7)
    np.testing.assert_array_equal(longer.controls, plain.controls)
    np.testing.assert_array_equal(longer.head_pose, plain.head_pose)
    assert decode_realtime_packet(packet[:-1]) == "short"  # one that ends early is still refused


def test_updates_and_answers_to_other_transactions_before_the_answer_are_passed_over():
    """Unreal's messenger hands updates to their handlers and drops a response whose transaction id is no
    pending request's: the request still gets its own answer (not tested by the change's tests)."""
    update = {"sessionId": "x", "addressPath": "/state/recording", "transactionId": 0, "timestamp": 1}
    listening = socket.create_server(("127.0.0.1", 0))
    listening.settimeout(30)

    def phone() -> None:
        conn, _ = listening.accept()
        with conn:
            request = cps.read_frame(conn, time.monotonic() + 30)
            answer = {key: request[key] for key in ("sessionId", "addressPath", "transactionId")}
            answer |= {"timestamp": 1, "type": "response"}
            conn.sendall(cps.encode_frame(update | {"type": "update", "body": {}}) * 50)
            stale = answer | {"transactionId": request["transactionId"] + 7, "body": {"sessionId": "stale"}}
            conn.sendall(cps.encode_frame(stale))
            conn.sendall(cps.encode_frame(answer | {"body": {"sessionId": "S1"}}))
            conn.recv(1)  # until the client closes

    thread = threading.Thread(target=phone, daemon=True)
    thread.start()
    with listening:
        client = cps.ControlClient("127.0.0.1", listening.getsockname()[1], wait_s=30)
        try:
            client.start_session()
        finally:
            client.close()
        thread.join()
    assert client.session_id == "S1"


@pytest.mark.skipif(not ipv6_loopback(), reason="no IPv6 loopback here")
def test_a_phone_given_by_its_ipv6_address_is_recorded_without_bind(tmp_path):
    # The phone streams to this computer's address as its control connection sees it: for a phone given by
    # an IPv6 address, an IPv6 one. Old: --bind defaulted to 0.0.0.0 (IPv4 only), so none of its packets
    # came in (no take, nothing rejected); and the lines named it "phone ::1:PORT".
    with SimulatedPhone(RealtimeFrames.of_take(synthetic_take(60)), host="::1") as phone:
        host, port = phone.start()
        cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "out"), "--json"]
        listen = subprocess.Popen(
            [*cmd, "--duration", "60", "--phone", f"[{host}]:{port}"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            wait_until(phone.finished, "all frames sent")
            (session,) = (tmp_path / "out").glob("*.recording")
            wait_for_logged_frames(session, 60)
        finally:
            listen.send_signal(signal.SIGINT)
            out, err = listen.communicate(timeout=60)
    assert listen.returncode == 0 and "Traceback" not in err, err
    assert f"phone [::1]:{port} (Simulated iPhone) streams subject iPhone" in err
    assert [json.loads(line)["valid_frames"] for line in out.splitlines()] == [60]
