"""Sync markers from a serial sync box (button, clapper, timecode reader), stamped on the session clock.

Line protocol (docs/live-capture.md): the box sends one line per event, UTF-8, ended by ``\\n``
(``\\r\\n`` accepted), at most ``MAX_LINE_BYTES`` bytes, sent the moment the event happens::

    KIND [ARGUMENT ...]

``KIND`` is one word (``CLAP``, ``BUTTON``, ``MARK``, ``TC``, ...); e.g. ``BUTTON 1``, ``CLAP``,
``TC 14:58:02:44``. Empty lines are ignored; longer lines are cut and flagged. Each event is logged
with the clock time its line ending arrived.

Ports are pyserial URLs: a device (``/dev/ttyUSB0``), ``socket://HOST:PORT``, ``rfc2217://...`` or
``loop://`` for tests.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .errors import InputError
from .record_log import RecordType, encode_record
from .session_clock import SessionClock

MAX_LINE_BYTES = 256
_SYNC_HEAD = struct.Struct("<Bq")  # type, arrival ns


@dataclass
class SyncEvent:
    """One line from the sync box: arrival (clock ns), kind, arguments and the raw text."""

    arrival_ns: int
    kind: str
    args: list[str]
    text: str
    truncated: bool = False

    def to_json(self, clock: SessionClock | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, "args": self.args, "text": self.text}
        if clock is not None:
            out["arrival_s"] = clock.seconds(self.arrival_ns)
        if self.truncated:
            out["truncated"] = True
        return out


def parse_sync_line(raw: bytes, arrival_ns: int) -> SyncEvent | None:
    """A ``SyncEvent`` from one received line (with or without its ending); None for blank lines."""
    truncated = len(raw.rstrip(b"\r\n")) > MAX_LINE_BYTES
    text = raw.rstrip(b"\r\n")[:MAX_LINE_BYTES].decode("utf-8", errors="replace").strip()
    if not text:
        return None
    parts = text.split()
    return SyncEvent(arrival_ns, parts[0].upper(), parts[1:], text, truncated)


def sync_record(event: SyncEvent) -> bytes:
    """The log record of an event: arrival ns and the line as received (cut to the limit)."""
    return encode_record(_SYNC_HEAD.pack(RecordType.SYNC, event.arrival_ns) + event.text.encode("utf-8"))


def decode_sync_record(payload) -> SyncEvent:
    _, arrival_ns = _SYNC_HEAD.unpack_from(payload)
    raw = bytes(payload[_SYNC_HEAD.size :])
    event = parse_sync_line(raw, arrival_ns)
    return event or SyncEvent(arrival_ns, "", [], "")


def open_serial(url: str, baudrate: int = 115200):
    """Open a pyserial port or URL with a short read timeout; ``InputError`` when it does not open."""
    try:
        import serial
    except ImportError:
        raise InputError("serial sync needs the Python package pyserial") from None
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=0.05)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise InputError(f"cannot open serial port {url!r}: {exc}") from None


class SerialSync:
    """Reads sync lines from an open serial port in a thread and hands each event to ``sink``.

    A port that fails (unplugged, the socket closed) ends the reading: ``error`` then says when and
    why, and a line received up to then but not ended is still handed over (flagged ``truncated``).
    """

    def __init__(self, port, clock: SessionClock, sink: Callable[[SyncEvent], None]):
        self.port = port
        self.clock = clock
        self.sink = sink
        self.events = 0
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="serial-sync", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        import serial

        pending = b""
        now = self.clock.now_ns()
        while not self._stop.is_set():
            try:
                data = self.port.read(max(1, self.port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                at = self.clock.seconds(self.clock.now_ns())
                self.error = f"serial port failed {at:.1f} s into the session: {exc}"
                break
            if not data:
                continue
            now = self.clock.now_ns()
            pending += data
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                self._emit(parse_sync_line(line, now))
            if len(pending) > 4 * MAX_LINE_BYTES:
                # A box that never ends its lines: keep what we have as one flagged event.
                self._emit(parse_sync_line(pending, now), truncated=True)
                pending = b""
        # What came after the last line end (a box cut off mid-line): kept, flagged, stamped at its arrival.
        if pending:
            self._emit(parse_sync_line(pending, now), truncated=True)

    def _emit(self, event: SyncEvent | None, truncated: bool = False) -> None:
        """Count and hand on a parsed line (None: not an event); ``truncated`` flags a line cut short."""
        if event is not None:
            event.truncated = truncated or event.truncated
            self.events += 1
            self.sink(event)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        try:
            self.port.close()
        except Exception:  # closing a failed port must not hide what was recorded
            pass
