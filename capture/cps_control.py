"""The control session of Live Link Face's newer stream: Capture Manager's Capture Protocol Stack ("CPS")
over TCP, as the Unreal Engine 5.6+ "Live Link Face" source speaks it (formats doc §5.6).

The receiver connects to the phone (its address and port as the app shows them) and sends requests; the
phone answers each. A message travels in a frame::

    "CPSCONTROL\\0" (11 bytes) | u16 protocol version = 1 | u32 payload length | payload (UTF-8 JSON)

(lengths in the sender's byte order, little-endian on every platform Unreal runs on). The JSON object
holds ``sessionId`` ("handshake" until the phone gives one), ``addressPath``, ``transactionId``,
``timestamp`` (ms since 1970), ``type`` ("request", "response" or "update") and, optionally, ``body``
and ``error`` ({``name``, ``description``}). A response repeats its request's transaction id, address
path and session id; one that does not come within ``RESPONSE_WAIT_S`` is a failure.

A session, as Unreal runs it: /session/start (body ``sessionId``), /information (``id``, ``name``,
``model``, ``platformName``, ``platformVersion``, ``softwareName``, ``softwareVersion``, ``exportPort``),
/stream/subjects (``subjects``: ``id``, ``name``, ``animationMetadata``: ``type`` "arkit" or "mha",
``version``, ``controls``), /stream/start (``streamPort``: our UDP port, ``subjects``: [{``id``,
``name``}]); then /session/keep-alive every ``KEEP_ALIVE_S`` (the connection is dropped after
``KEEP_ALIVE_FAILURES`` failures in a row); at the end /stream/stop and /session/stop. A session that
does not start is tried again ``RETRY_S`` later; one that streamed and ended is started again at once.
Sources: Unreal Engine 5.8 ``LiveLinkFaceControl.cpp`` (MetaHumanLiveLink) and the CaptureProtocolStack's
``ControlMessenger``, ``ControlPacket``, ``ControlMessage``, ``ControlRequest``, ``ControlResponse`` and
``Constants``.

``PhoneStream`` runs that session in a thread and relays the phone's realtime packets
(``realtime_packet``) of an ARKit subject, as classic version-6 packets, to a ``LiveRecorder``'s socket
on this computer: the recording, its log, its takes and ``recover`` are those of the classic stream. A
MetaHuman Animator subject (controls of its own, any number) is logged directly in the recorder's frames
log, a CONTROLS record a packet after a STREAM record naming its controls and the head rotation's channels
(HeadYaw, HeadPitch, HeadRoll, as the classic stream's takes have them): its takes' channels are those.
"""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import json
import os
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from .errors import InputError, printable
from .realtime_packet import (
    CLASSIC_NAME_BYTES,
    MAX_REALTIME_PACKET_BYTES,
    REALTIME_REJECT_REASONS,
    ArkitMapping,
    classic_names,
    controls_record,
    decode_realtime_packet,
    head_channels,
)
from .record_log import RecordType, json_record
from .recorder import bound_udp_socket
from .replay import format_destination

FRAME_MAGIC = b"CPSCONTROL\0"
FRAME_HEAD = struct.Struct("<HI")  # protocol version, payload length
CPS_VERSION = 1
HANDSHAKE_SESSION = "handshake"
RESPONSE_WAIT_S = 3.0  # Unreal's ResponseWaitTime
KEEP_ALIVE_S = 5.0  # Unreal's KeepAliveInterval
KEEP_ALIVE_FAILURES = 3  # keep-alives unanswered in a row before the connection is dropped
RETRY_S = 5.0  # Unreal tries a session that did not start again five seconds later
CONNECT_TIMEOUT_S = 3.0
STOP_WAIT_S = 1.0  # what the stop requests at the end of a session wait for their answers
CANCEL_CHECK_S = 0.05  # how often a request waiting for its answer looks whether listen stopped
# The longest payload read: a subject list with a few hundred control names is a few KB; a length past
# this is no control message (another service on that port, or a broken phone).
MAX_CONTROL_PAYLOAD = 1 << 20

START_SESSION = "/session/start"
STOP_SESSION = "/session/stop"
KEEP_ALIVE = "/session/keep-alive"
SERVER_INFORMATION = "/information"
STREAMING_SUBJECTS = "/stream/subjects"
START_STREAMING = "/stream/start"
STOP_STREAMING = "/stream/stop"
ANIMATION_TYPES = ("arkit", "mha")
# The relay's rejection counts go into the recorder's under this prefix (``realtime_short``): the recorder
# checks the classic packets relayed to it with its own reasons.
REJECT_PREFIX = "realtime_"
REALTIME_SOURCE_KIND = "livelink_realtime"  # the takes of a subject logged with its own controls
LOG_EVERY_S = 0.1  # the relay hands its CONTROLS records to the log at least this often
RELAY_WAKE_S = 0.1  # the relay's socket wakes this often to see whether listen stopped


class ControlError(Exception):
    """A control session failed: what failed, in one line (a refusal, a disconnect, a silence)."""


def unmapped(address: str) -> str:
    """``address`` as the relay compares it: an IPv4 one on a dual-stack socket (``::ffff:a.b.c.d``) as
    ``a.b.c.d``, so that a phone and its packets match whichever family each was seen in."""
    return address.removeprefix("::ffff:")


def relay_socket(host: str, port: int) -> socket.socket:
    """The relay's UDP socket without ``--bind``. The phone streams to this computer's address as the
    control connection sees it: for a phone given by its IPv4 address, an IPv4 one (0.0.0.0, as Unreal
    binds); otherwise (an IPv6 address, or a name, which may resolve to either family and is connected to
    by the first address that answers) ``::``, which takes IPv4 senders too. A name on a system without
    dual-stack sockets gets 0.0.0.0."""
    try:
        ipaddress.IPv4Address(host)
        ipv4 = True
    except ValueError:
        ipv4 = False
    if not ipv4:
        try:
            sock = bound_udp_socket("::", port, RELAY_WAKE_S)
        except InputError:
            if ":" in host:
                raise
            # no IPv6 here: a name is an IPv4 phone
        else:
            if ":" in host or not sock.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY):
                return sock
            sock.close()
    return bound_udp_socket("0.0.0.0", port, RELAY_WAKE_S)


# what a non-blocking connect says while it goes on: EINPROGRESS on POSIX, WSAEWOULDBLOCK on Windows
CONNECT_PENDING = {errno.EINPROGRESS, errno.EWOULDBLOCK, getattr(errno, "WSAEWOULDBLOCK", errno.EINPROGRESS)}


def _wait_for(
    sock: socket.socket, deadline: float, cancel: threading.Event | None, write: bool = False
) -> None:
    """Wait until ``sock`` has bytes to read (or, ``write``, is connected): ``TimeoutError`` past
    ``deadline``, ``ControlError`` as soon as ``cancel`` is set (``listen`` stopped)."""
    while True:
        if cancel is not None and cancel.is_set():
            raise ControlError("stopped")
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("timed out")
        waits = ([], [sock]) if write else ([sock], [])
        # a connect refused shows in the exceptional list on Windows, in the writable one elsewhere
        if any(select.select(*waits, [sock] if write else [], min(left, CANCEL_CHECK_S))):
            return


def encode_frame(message: dict[str, Any]) -> bytes:
    """A control message in its frame."""
    payload = json.dumps(message, separators=(",", ":")).encode("utf-8")
    return FRAME_MAGIC + FRAME_HEAD.pack(CPS_VERSION, len(payload)) + payload


def _read_exactly(sock: socket.socket, size: int, deadline: float) -> bytes:
    data = bytearray()
    while len(data) < size:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        sock.settimeout(left)
        try:
            chunk = sock.recv(size - len(data))
        except TimeoutError:
            raise
        except OSError as exc:
            raise ControlError(f"the connection failed ({exc.strerror or exc})") from None
        if not chunk:
            raise ControlError("the phone closed the connection")
        data += chunk
    return bytes(data)


def read_frame(sock: socket.socket, deadline: float) -> dict[str, Any]:
    """The next control message on ``sock``; ``TimeoutError`` past ``deadline`` (monotonic seconds),
    ``ControlError`` for anything that is not a control message (the connection is then unusable)."""
    magic = _read_exactly(sock, len(FRAME_MAGIC), deadline)
    if magic != FRAME_MAGIC:
        raise ControlError(f"not a Capture Protocol Stack control stream (it began {magic!r})")
    version, size = FRAME_HEAD.unpack(_read_exactly(sock, FRAME_HEAD.size, deadline))
    if size > MAX_CONTROL_PAYLOAD:
        raise ControlError(f"a control message of {size} bytes (at most {MAX_CONTROL_PAYLOAD} are read)")
    payload = _read_exactly(sock, size, deadline)
    if version != CPS_VERSION:
        raise ControlError(f"control protocol version {version} (this listen speaks {CPS_VERSION})")
    try:
        message = json.loads(payload.decode("utf-8"))
    except (ValueError, RecursionError):  # RecursionError: arrays or objects nested thousands deep
        raise ControlError("a control message that is not JSON") from None
    if not isinstance(message, dict):
        raise ControlError("a control message that is not a JSON object")
    return message


@dataclass
class RemoteSubject:
    """A subject the phone can stream: its id (in the packets), name, animation type and controls."""

    id: str
    name: str
    kind: str  # "arkit" or "mha"
    version: int
    controls: list[str]


def parse_subjects(body: dict[str, Any]) -> tuple[list[RemoteSubject], list[str]]:
    """The valid subjects of a /stream/subjects response, and why each other one was skipped."""
    subjects, skipped = [], []
    items = body.get("subjects")
    if not isinstance(items, list):
        raise ControlError("the phone's subject list has no 'subjects' array")
    for item in items:
        meta = item.get("animationMetadata") if isinstance(item, dict) else None
        if not isinstance(meta, dict) or not isinstance(item.get("id"), str) or not item["id"]:
            skipped.append("a subject without an id or animation metadata")
            continue
        controls = meta.get("controls")
        kind = meta.get("type")
        if kind not in ANIMATION_TYPES:
            skipped.append(f"subject {item['id']!r} of unknown animation type {kind!r}")
            continue
        if not isinstance(controls, list) or not all(isinstance(c, str) for c in controls):
            skipped.append(f"subject {item['id']!r} without a list of control names")
            continue
        version = meta.get("version")
        name = item.get("name")
        subjects.append(
            RemoteSubject(
                item["id"],
                name if isinstance(name, str) and name else item["id"],
                kind,
                version if isinstance(version, int) else 0,
                controls,
            )
        )
    return subjects, skipped


class ControlClient:
    """One control connection to the phone; requests are answered in turn (``request``). Once ``cancel``
    is set, the connecting or a request waiting for its answer fails at once (``listen`` stopped while
    the phone is silent); ``answering`` says whether the last request got its answer (not when the phone
    refused it, or answered for another request or session)."""

    def __init__(
        self, host: str, port: int, wait_s: float = RESPONSE_WAIT_S, cancel: threading.Event | None = None
    ):
        self.wait_s = wait_s
        self.cancel = cancel
        self.answering = True
        self.session_id = HANDSHAKE_SESSION
        self._transaction = 0
        self.sock = self._connect(host, port)

    def _connect(self, host: str, port: int) -> socket.socket:
        """A connection to the first of ``host``'s addresses that answers, each given
        ``CONNECT_TIMEOUT_S`` (as ``socket.create_connection`` tries them), given up as soon as ``cancel``
        is set; ``ControlError`` saying why none did."""
        try:
            addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except OSError as exc:
            raise ControlError(f"cannot connect ({exc.strerror or exc})") from None
        failure: OSError = OSError("no address")
        for family, kind, proto, _, address in addresses:
            try:
                sock = socket.socket(family, kind, proto)
            except OSError as exc:  # a family this system makes no sockets of
                failure = exc
                continue
            try:
                sock.setblocking(False)
                code = sock.connect_ex(address)
                if code in CONNECT_PENDING:
                    _wait_for(sock, time.monotonic() + CONNECT_TIMEOUT_S, self.cancel, write=True)
                    code = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
                if code:
                    raise OSError(code, os.strerror(code))
            except OSError as exc:  # refused, unreachable, no answer: the next address
                sock.close()
                failure = exc
                continue
            except BaseException:  # a stop (ControlError)
                sock.close()
                raise
            sock.settimeout(CONNECT_TIMEOUT_S)
            return sock
        raise ControlError(f"cannot connect ({failure.strerror or failure})")

    @property
    def peer(self) -> str:
        """The phone's address as the connection sees it (where its realtime packets come from)."""
        return self.sock.getpeername()[0]

    def close(self) -> None:
        self.sock.close()

    def request(self, path: str, body: dict[str, Any] | None = None) -> dict[str, Any]:
        """Send a request and return the body of its response ({} when it has none); ``ControlError``
        for a refusal, a wrong answer, a closed connection or no answer within ``wait_s``."""
        self._transaction = (self._transaction + 1) & 0xFFFFFFFF
        message = {
            "sessionId": self.session_id,
            "addressPath": path,
            "transactionId": self._transaction,
            "timestamp": int(time.time() * 1000),
            "type": "request",
        }
        if body is not None:
            message["body"] = body
        try:
            self.sock.sendall(encode_frame(message))
        except OSError as exc:
            raise ControlError(f"cannot send {path} ({exc.strerror or exc})") from None
        deadline = time.monotonic() + self.wait_s
        self.answering = False
        while True:
            try:
                _wait_for(self.sock, deadline, self.cancel)
                answer = read_frame(self.sock, deadline)
            except TimeoutError:
                raise ControlError(f"the phone did not answer {path} within {self.wait_s:g} s") from None
            if answer.get("type") != "response" or answer.get("transactionId") != self._transaction:
                continue  # an update, or the late answer of an earlier request
            if answer.get("addressPath") != path or answer.get("sessionId") != self.session_id:
                raise ControlError(f"the phone answered {path} for another request or session")
            error = answer.get("error")
            if isinstance(error, dict) and error.get("name"):
                raise ControlError(
                    f"the phone refused {path}: {error.get('name')}: {error.get('description')}"
                )
            self.answering = True
            answered = answer.get("body")
            return answered if isinstance(answered, dict) else {}

    def idle(self, seconds: float) -> None:
        """Wait ``seconds`` for nothing but updates (read and dropped); ``ControlError`` when the phone
        closes the connection or sends what is no control message meanwhile."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            readable, _, _ = select.select([self.sock], [], [], left)
            if readable:
                try:
                    read_frame(self.sock, time.monotonic() + self.wait_s)
                except TimeoutError:
                    raise ControlError("the phone sent part of a message and stopped") from None

    def start_session(self) -> None:
        session = self.request(START_SESSION).get("sessionId")
        if not isinstance(session, str) or not session:
            raise ControlError("the phone started a session without a session id")
        self.session_id = session


def _own_controls_problem(subject: RemoteSubject) -> str | None:
    """Why a subject cannot be recorded with its own controls as a take's channels (None: it can)."""
    if not subject.controls or not all(subject.controls):
        return f"subject {subject.id!r} has an empty control list or an empty control name"
    folded = [c.lower() for c in subject.controls]
    twice = sorted({c for c in subject.controls if folded.count(c.lower()) > 1})
    if twice:  # a take's channels are looked up case-insensitively
        return f"subject {subject.id!r} names a control twice ({', '.join(twice[:5])}; case is ignored)"
    return None


def choose_subject(subjects: list[RemoteSubject], skipped: list[str]) -> RemoteSubject:
    """The first ARKit subject, else the first MetaHuman Animator one whose controls can be a take's
    channels; ``ControlError`` saying why there is none."""
    for subject in subjects:
        if subject.kind == "arkit":
            return subject
    for subject in subjects:
        problem = _own_controls_problem(subject)
        if problem is None:
            return subject
        skipped = [*skipped, problem]
    why = f" ({'; '.join(skipped)})" if skipped else ""
    raise ControlError(f"the phone lists no subject to stream{why}")


@dataclass
class _Streaming:
    """The subject being streamed and what its packets become."""

    subject: RemoteSubject
    device: str  # the device id (an ARKit subject's as its classic packets carry it: ``classic_names``)
    name: str  # the subject's name (likewise)
    mapping: ArkitMapping | None  # None: a subject logged with its own controls (``stream``)
    phone: str  # the phone's address (``unmapped``): realtime packets from elsewhere are not recorded
    stream: int = -1  # the CONTROLS records' stream id of a subject logged with its own controls
    stream_record: dict[str, Any] | None = None  # its STREAM record (the relay logs it before its frames)
    head_from: Any = None  # where its head channels' values are in the head pose (``head_channels``)


@dataclass
class PhoneStream:
    """A control session to the phone at ``host:port`` (kept up, retried every ``RETRY_S``) and the relay
    of its realtime packets, received on ``bind:port`` (``bind`` None: ``relay_socket``), to
    ``recorder_address`` as classic packets.

    ``say`` prints a line (each distinct failure once in a row); ``rejected`` is the recorder's rejection
    counts, which the relay adds to; ``note`` logs an event in the session log; ``allow`` (an
    ``AllowList``) accepts realtime packets from more addresses than the phone's; ``record`` hands
    complete records to the session log (``LogWriter.put``): a MetaHuman Animator subject is recorded
    only with it, as CONTROLS records (``logged`` counts them), one stream per device, subject and
    control list (a session started again with the same ones goes on in the same stream)."""

    host: str
    port: int
    recorder_address: tuple[str, int]
    say: Callable[[str], None]
    rejected: dict[str, int]
    note: Callable[[dict[str, Any]], None]
    bind: str | None = None
    stream_port: int = 0
    allow: Any = None
    retry_s: float = RETRY_S
    keep_alive_s: float = KEEP_ALIVE_S
    relayed: int = 0
    record: Callable[[bytes], None] | None = None
    logged: int = 0
    udp: socket.socket | None = None  # where the phone streams to (``open``)
    out: socket.socket | None = None  # to the recorder
    _streaming: _Streaming | None = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _restart: threading.Event = field(default_factory=threading.Event)
    _threads: list[threading.Thread] = field(default_factory=list)
    _last_said: str = ""
    _streamed: bool = False  # whether the current session got as far as streaming
    _stream_ids: dict[tuple[str, str, tuple[str, ...]], int] = field(default_factory=dict)
    _unlogged: bytearray = field(default_factory=bytearray)  # the relay's records not handed over yet
    _logged_streams: set[int] = field(default_factory=set)  # those whose STREAM record the relay logged

    def open(self) -> tuple[str, int]:
        """Bind the UDP socket the phone is told to stream to; its (address, port)."""
        if self.bind is None:
            self.udp = relay_socket(self.host, self.stream_port)
        else:
            self.udp = bound_udp_socket(self.bind, self.stream_port, RELAY_WAKE_S)
        # the relay's reasons, beside the recorder's own (which it checks on what is relayed)
        for reason in REALTIME_REJECT_REASONS:
            self.rejected.setdefault(REJECT_PREFIX + reason, 0)
        self.out = socket.socket(
            socket.AF_INET6 if ":" in self.recorder_address[0] else socket.AF_INET, socket.SOCK_DGRAM
        )
        return self.udp.getsockname()[:2]

    def start(self) -> None:
        for target, name in ((self._control, "phone-control"), (self._relay, "phone-relay")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def stop(self) -> None:
        """End the session (stop streaming, stop the session) and the relay; closes the sockets."""
        self._stop.set()
        for thread in self._threads:
            thread.join()
        for sock in (self.udp, self.out):
            if sock is not None:
                sock.close()

    @property
    def logged_streams(self) -> int:
        """The streams of CONTROLS records the relay logged (each subject logged with its own controls)."""
        return len(self._logged_streams)

    @property
    def _phone(self) -> str:
        """The phone's control address as ``--phone`` takes it (``[::1]:14785``)."""
        return format_destination(self.host, self.port)

    def _tell(self, line: str, note: dict[str, Any] | None = None) -> None:
        """Say ``line`` (and log ``note``) unless it was the last line said: a phone that fails the same
        way at every retry is told of once."""
        if line != self._last_said:
            self._last_said = line
            with contextlib.suppress(OSError):
                self.say(line)
            if note is not None:
                self.note(note)

    # -- the control session ------------------------------------------------------------------
    def _control(self) -> None:
        """Sessions, one after another, as Unreal's control thread runs them: one that does not start is
        tried again ``retry_s`` later; one that streamed and ended (the phone went away, keep-alives
        unanswered, the subject's control count changed) is started again at once, and after
        ``retry_s`` when it ended twice within ``retry_s`` (a phone that drops every session)."""
        again_at_once = -self.retry_s  # when a session was last started again at once
        while not self._stop.is_set():
            self._restart.clear()
            self._streamed = False
            try:
                self._session()
                why = "the subject's control count changed"
            except ControlError as exc:
                if self._stop.is_set():  # listen stopped (a request it cut short among them): no line
                    break
                if not self._streamed:
                    line = f"phone {self._phone}: {exc}; trying again every {self.retry_s:g} s"
                    self._tell(line, {"kind": "phone_session", "message": str(exc)})
                    self._stop.wait(self.retry_s)
                    continue
                why = str(exc)
            if self._stop.is_set():
                break
            line = f"phone {self._phone}: {why}; starting the session again"
            self._tell(line, {"kind": "phone_session", "message": why})
            if time.monotonic() - again_at_once < self.retry_s:
                self._stop.wait(self.retry_s)
            again_at_once = time.monotonic()

    def _session(self) -> None:
        client = ControlClient(self.host, self.port, cancel=self._stop)
        try:
            client.start_session()
            try:
                self._stream(client)
            finally:  # as Unreal does at the end: both asked, each failure only noted (sooner), and
                # not waited for when the phone left the last request unanswered (a silent phone)
                client.cancel = None
                client.wait_s = min(client.wait_s, STOP_WAIT_S) if client.answering else 0.0
                for path, body in ((STOP_STREAMING, {}), (STOP_SESSION, None)):
                    with contextlib.suppress(ControlError):
                        client.request(path, body)
        finally:
            client.close()

    def _stream(self, client: ControlClient) -> None:
        info = client.request(SERVER_INFORMATION)
        subjects, skipped = parse_subjects(client.request(STREAMING_SUBJECTS))
        subject = choose_subject(subjects, skipped)
        if subject.kind != "arkit" and self.record is None:
            raise ControlError(f"subject {subject.name} is a MetaHuman Animator one: no log to record it in")
        device = info.get("id") if isinstance(info.get("id"), str) and info.get("id") else client.peer
        phone_address = unmapped(client.peer)
        if subject.kind == "arkit":
            classic_device, classic_subject = self._classic_names(device, subject.name)
            mapping = ArkitMapping(subject.controls)
            self._streaming = _Streaming(subject, classic_device, classic_subject, mapping, phone_address)
        else:
            self._streaming = self._own_stream(subject, device, phone_address)
        udp_port = self.udp.getsockname()[1]
        client.request(
            START_STREAMING, {"streamPort": udp_port, "subjects": [{"id": subject.id, "name": subject.name}]}
        )
        self._streamed = True
        phone = info.get("name") if isinstance(info.get("name"), str) else client.peer
        kind = "ARKit" if subject.kind == "arkit" else "MetaHuman Animator"
        self._tell(
            f"phone {self._phone} ({phone}) streams subject {subject.name} "
            f"({len(subject.controls)} {kind} controls) to udp port {udp_port}"
        )
        mapping = self._streaming.mapping
        matched = (
            {"unmatched_controls": mapping.unmatched, "missing_channels": mapping.missing}
            if mapping is not None
            else {"stream": self._streaming.stream}
        )
        self.note(
            {
                "kind": "phone_streaming",
                "message": f"subject {subject.name} of {phone}",
                "subject_id": subject.id,
                "controls": subject.controls,
            }
            | matched
            | {"information": info}
        )
        failures = 0
        last_keep_alive = time.monotonic()
        while not (self._stop.is_set() or self._restart.is_set()):
            client.idle(0.1)
            if time.monotonic() - last_keep_alive < self.keep_alive_s:
                continue
            last_keep_alive = time.monotonic()
            try:
                client.request(KEEP_ALIVE)
                failures = 0
            except ControlError:
                failures += 1
                if failures >= KEEP_ALIVE_FAILURES:
                    raise ControlError(f"{failures} keep-alives in a row unanswered") from None

    def _classic_names(self, device: str, subject: str) -> tuple[str, str]:
        """The device id and subject name of an ARKit subject's classic packets (``classic_names``): UTF-8
        text (a lone surrogate, which JSON's ``"\\ud800"`` gives, as its escape, as the takes of a subject
        logged with its own controls name it), and those a classic packet cannot hold cut to fit, which is
        told and noted."""
        names = printable(device), printable(subject)
        short = classic_names(*names)
        cut = [what for what, name, kept in zip(("device id", "subject name"), names, short) if kept != name]
        if cut:
            size = sum(len(name.encode("utf-8")) for name in names)
            why = (
                f"device id and subject name take {size} bytes, more than the {CLASSIC_NAME_BYTES} a classic "
                f"packet holds: the takes name the {' and the '.join(cut)} cut to fit, "
                f"{'each ' if len(cut) > 1 else ''}ended by '~' and 8 hex digits of its SHA-1"
            )
            self._tell(f"phone {self._phone}: {why}", {"kind": "phone_names_shortened", "message": why})
        return short

    def _own_stream(self, subject: RemoteSubject, device: str, phone: str) -> _Streaming:
        """The streaming of a subject logged with its own controls: its stream id (a new one, whose
        STREAM record names its controls and head channels, unless a session before streamed the same
        subject)."""
        head, head_from = head_channels(subject.controls)
        stream = self._stream_ids.setdefault(
            (device, subject.name, tuple(subject.controls)), len(self._stream_ids)
        )
        record = {
            "stream": stream,
            "device": device,
            "subject": subject.name,
            "source": phone,
            "source_kind": REALTIME_SOURCE_KIND,
            "controls": subject.controls + head,
        }
        return _Streaming(subject, device, subject.name, None, phone, stream, record, head_from)

    # -- the relay ----------------------------------------------------------------------------
    def _relay(self) -> None:
        buf = bytearray(MAX_REALTIME_PACKET_BYTES + 1)
        handed = time.monotonic()
        while not self._stop.is_set():
            if self._unlogged and time.monotonic() - handed >= LOG_EVERY_S:
                handed = time.monotonic()
                self._hand_over()
            try:
                n, addr = self.udp.recvfrom_into(buf)
            except OSError:  # a timeout (``TimeoutError``) included
                continue
            reason = self._forward(memoryview(buf)[:n], addr)
            if reason is not None:  # a key ``open`` made: the recorder's thread copies the dict meanwhile
                self.rejected[REJECT_PREFIX + reason] += 1
        self._hand_over()

    def _hand_over(self) -> None:
        """Hand the CONTROLS records (and their STREAM records) received so far to the log."""
        if self._unlogged and self.record is not None:
            self.record(bytes(self._unlogged))
            self._unlogged.clear()

    def _forward(self, data: memoryview, addr: Any) -> str | None:
        streaming = self._streaming
        if streaming is None:
            return "not_streaming"
        source = unmapped(addr[0])  # an IPv4 phone on a dual-stack socket
        if source != streaming.phone and (self.allow is None or source not in self.allow):
            return "not_allowed"
        packet = decode_realtime_packet(data)
        if isinstance(packet, str):
            return packet
        if packet.subject_id != streaming.subject.id:
            return "unknown_subject"
        if packet.controls.size != len(streaming.subject.controls):
            self._restart.set()  # Unreal restarts the session: the phone's subject changed
            return "control_count"
        if streaming.mapping is None:
            if streaming.stream not in self._logged_streams:  # its first packet: the rate it declares
                self._logged_streams.add(streaming.stream)
                rate = {"rate_numerator": packet.rate_numerator, "rate_denominator": packet.rate_denominator}
                self._unlogged += json_record(RecordType.STREAM, streaming.stream_record | rate)
            self._unlogged += controls_record(
                streaming.stream, time.monotonic_ns(), packet, streaming.head_from
            )
            self.logged += 1
            return None
        classic = streaming.mapping.classic_packet(streaming.device, streaming.name, packet)
        with contextlib.suppress(OSError):
            self.out.sendto(classic, self.recorder_address)
            self.relayed += 1
        return None
