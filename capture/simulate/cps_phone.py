"""A simulated phone of Live Link Face's newer realtime stream (formats doc §5.6): the control server of the
Capture Protocol Stack (TCP, ``capture.cps_control``) and, once a receiver asks for it, the UDP sender of
a take's frames as realtime packets (``capture.realtime_packet``) of an ARKit subject.

``behaviour`` makes it a phone that misbehaves: ``refuse`` answers every request with an error,
``silent`` never answers, ``no_subjects`` lists none, ``mha`` lists only a MetaHuman Animator subject
(``MHA_CONTROLS``: the first eight of the take's values, streamed under those names),
``garbage`` answers with bytes that are no control message, ``drop_once`` closes the first control
connection after ``drop_after`` frames (and goes on streaming on the next one), ``drop_then_silent`` too but
never answers on the next ones (a phone that went away mid-stream). ``extra_datagrams`` are
sent to the receiver's UDP port before the frames (bad input for its relay).
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from capture import cps_control as cps
from capture.channels import LIVELINK_ORDER, udp_index
from capture.csv_take import start_seconds_of_day
from capture.realtime_packet import HEAD_CHANNELS, encode_realtime_packet
from capture.replay import frame_times, rate_of, values_in_engine_order
from capture.take import FrameStatus, Take

BEHAVIOURS = ("normal", "refuse", "silent", "no_subjects", "mha", "garbage", "drop_once", "drop_then_silent")
DROPPING = ("drop_once", "drop_then_silent")
ARKIT_CONTROLS = list(LIVELINK_ORDER[:52])  # the 52 blendshapes; the head pose travels apart
MHA_CONTROLS = [f"CTRL_expressions_{i}" for i in range(8)]
SUBJECT_ID = "00000000-5EA1-71DE-0000-00000000A1C1"
DEVICE_ID = "5E1F0000-0000-4000-8000-0000CAFEF00D"


@dataclass
class RealtimeFrames:
    """A take's frames as the phone streams them: frame times, 52 controls and the head pose."""

    frame_number: np.ndarray
    sub_frame: np.ndarray
    rate: tuple[int, int]
    controls: np.ndarray  # frames x 52, 0..1 before quantizing
    head_pose: np.ndarray  # frames x 6: roll, pitch, yaw, x, y, z

    @classmethod
    def of_take(cls, take: Take) -> RealtimeFrames:
        """The take's TRACKED frames (the others are not sent) at its rate from its start timecode."""
        num, den = rate_of(take.meta.fps)
        keep = take.frame_status == FrameStatus.TRACKED
        fn, sub = frame_times(start_seconds_of_day(take) + take.time[keep], num, den)
        values = values_in_engine_order(take)[keep]
        head = np.zeros((fn.size, 6), dtype=np.float32)
        for name, k in HEAD_CHANNELS.items():  # the pose's roll, pitch, yaw
            head[:, k] = values[:, udp_index(name)]
        return cls(fn, sub, (num, den), values[:, :52], head)

    def packet(self, k: int, subject_id: str = SUBJECT_ID, controls: int | None = None) -> bytes:
        """Frame ``k``'s packet; ``controls``: only the first this many of its controls."""
        num, den = self.rate
        return encode_realtime_packet(
            subject_id,
            int(self.frame_number[k]),
            float(self.sub_frame[k]),
            num,
            den,
            self.controls[k, :controls],
            self.head_pose[k],
        )


@dataclass
class SimulatedPhone:
    """The control server on ``host`` (any free port) and the frame sender; ``start()`` → (host, port)."""

    frames: RealtimeFrames
    behaviour: str = "normal"
    host: str = "127.0.0.1"
    port: int = 0
    device: str = DEVICE_ID
    subject: str = "iPhone"
    speed: float = 1.0
    drop_after: int = 60
    extra_datagrams: list[bytes] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)  # the address paths received, in order
    sent: int = 0  # realtime packets sent
    connections: int = 0
    _stop: threading.Event = field(default_factory=threading.Event)
    _threads: list[threading.Thread] = field(default_factory=list)
    _next_frame: int = 0

    def __post_init__(self) -> None:
        if self.behaviour not in BEHAVIOURS:
            raise ValueError(f"behaviour must be one of {BEHAVIOURS}, not {self.behaviour!r}")
        self._lock = threading.Lock()

    def start(self) -> tuple[str, int]:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        self.server = socket.create_server((self.host, self.port), family=family)
        self.server.settimeout(0.1)
        self._spawn(self._serve)
        return self.server.getsockname()[:2]

    def stop(self) -> None:
        self._stop.set()
        for thread in list(self._threads):
            thread.join()
        self.server.close()

    def __enter__(self) -> SimulatedPhone:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def _spawn(self, target, *args) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, peer = self.server.accept()
            except TimeoutError:
                continue
            self.connections += 1
            self._spawn(self._connection, conn, peer[0], self.connections)

    def _subjects(self) -> dict[str, Any]:
        if self.behaviour == "no_subjects":
            return {"subjects": []}
        kind, controls = ("mha", MHA_CONTROLS) if self.behaviour == "mha" else ("arkit", ARKIT_CONTROLS)
        meta = {"type": kind, "version": 1, "controls": controls}
        return {"subjects": [{"id": SUBJECT_ID, "name": self.subject, "animationMetadata": meta}]}

    def _connection(self, conn: socket.socket, peer: str, number: int) -> None:
        session = f"session-{number}"
        streaming = threading.Event()
        with conn:
            while not self._stop.is_set():
                try:
                    message = cps.read_frame(conn, time.monotonic() + 0.2)
                except TimeoutError:
                    continue
                except cps.ControlError:
                    break
                path = message.get("addressPath")
                self.requests.append(path)
                if self.behaviour == "silent" or (self.behaviour == "drop_then_silent" and number > 1):
                    continue
                if self.behaviour == "garbage":
                    conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")
                    continue
                answer = {
                    "sessionId": message.get("sessionId"),
                    "addressPath": path,
                    "transactionId": message.get("transactionId"),
                    "timestamp": int(time.time() * 1000),
                    "type": "response",
                }
                if self.behaviour == "refuse":
                    answer["error"] = {"name": "requestFailed", "description": "the app is recording"}
                elif path == cps.START_SESSION:
                    answer["body"] = {"sessionId": session}
                elif path == cps.SERVER_INFORMATION:
                    answer["body"] = {
                        "id": self.device,
                        "name": "Simulated iPhone",
                        "model": "iPhone13,3",
                        "platformName": "iOS",
                        "platformVersion": "18.5",
                        "softwareName": "Live Link Face",
                        "softwareVersion": "1.5.0",
                        "exportPort": 14785,
                    }
                elif path == cps.STREAMING_SUBJECTS:
                    answer["body"] = self._subjects()
                elif path == cps.START_STREAMING:
                    port = message.get("body", {}).get("streamPort")
                    streaming.set()
                    self._spawn(self._send, (peer, port), streaming, conn, number)
                elif path == cps.STOP_STREAMING:
                    streaming.clear()
                with contextlib.suppress(OSError):
                    conn.sendall(cps.encode_frame(answer))
            streaming.clear()

    def _send(
        self, to: tuple[str, int], streaming: threading.Event, conn: socket.socket, number: int
    ) -> None:
        udp = socket.socket(socket.AF_INET6 if ":" in to[0] else socket.AF_INET, socket.SOCK_DGRAM)
        with udp:
            for datagram in self.extra_datagrams:
                udp.sendto(datagram, to)
            period = self.frames.rate[1] / self.frames.rate[0] / self.speed
            began = time.monotonic()
            first = self._next_frame
            while streaming.is_set() and not self._stop.is_set():
                with self._lock:
                    k = self._next_frame
                    if k >= self.frames.frame_number.size:
                        return
                    self._next_frame += 1
                wait = began + (k - first) * period - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                packet = self.frames.packet(
                    k, controls=len(MHA_CONTROLS) if self.behaviour == "mha" else None
                )
                udp.sendto(packet, to)
                self.sent += 1
                if self.behaviour in DROPPING and number == 1 and k + 1 >= self.drop_after:
                    conn.shutdown(socket.SHUT_RDWR)  # the phone goes away mid-stream
                    return

    def finished(self) -> bool:
        """Whether every frame was sent."""
        return self.sent >= self.frames.frame_number.size
