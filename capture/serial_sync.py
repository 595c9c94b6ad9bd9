"""Sync markers from a serial sync box (button, clapper, timecode reader), stamped on the session clock.

Line protocol (docs/live-capture.md): the box sends one line per event, UTF-8, ended by ``\\n``
(``\\r\\n`` and a lone ``\\r`` accepted), at most ``MAX_LINE_BYTES`` bytes, sent the moment the
event happens::

    KIND [ARGUMENT ...]

``KIND`` is one word (``CLAP``, ``BUTTON``, ``MARK``, ``TC``, ...); e.g. ``BUTTON 1``, ``CLAP``,
``TC 14:58:02:44``. Empty lines are ignored; a longer line is one event, cut and flagged; a line with
control characters (other than tab) or invalid UTF-8 (line noise, a wrong baud rate) is dropped and
counted. Each event is logged with the clock time its line ending arrived.

Ports are pyserial URLs: a device (``/dev/ttyUSB0``), ``socket://HOST:PORT``, ``rfc2217://...`` or
``loop://`` for tests.
"""

from __future__ import annotations

import codecs
import contextlib
import re
import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .command import warn
from .errors import InputError
from .record_log import RecordType, encode_record
from .session_clock import SessionClock

MAX_LINE_BYTES = 256
_SYNC_HEAD = struct.Struct("<Bq")  # type, arrival ns
SYNC_HEAD_BYTES = _SYNC_HEAD.size  # what a SYNC record holds before its line
_TRUNCATED = b"\0"  # after a SYNC record's line: the line was cut
_LINE_END = re.compile(rb"\r\n?|\n")
_CONTROL = re.compile("[\x00-\x08\x0a-\x1f\x7f-\x9f]")  # control characters but tab


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


def _event(text: str, arrival_ns: int, truncated: bool) -> SyncEvent | None:
    """The event a line's text holds; None for a blank line."""
    text = text.strip()
    if not text:
        return None
    parts = text.split()
    return SyncEvent(arrival_ns, parts[0].upper(), parts[1:], text, truncated)


def parse_sync_line(raw: bytes, arrival_ns: int, cut: bool = False) -> SyncEvent | None:
    """A ``SyncEvent`` from one received line (with or without its ending); None for a blank line. A
    line over ``MAX_LINE_BYTES`` is cut there (at a character boundary) and flagged ``truncated``, as is
    one ``cut`` short. ``ValueError`` for line noise: invalid UTF-8 or a control character but tab."""
    raw = raw.rstrip(b"\r\n")
    truncated = cut or len(raw) > MAX_LINE_BYTES
    try:  # not final when cut: a character the cut splits is dropped, not an error
        text = codecs.getincrementaldecoder("utf-8")().decode(raw[:MAX_LINE_BYTES], final=not truncated)
    except UnicodeDecodeError:
        raise ValueError("invalid UTF-8") from None
    if _CONTROL.search(text):
        raise ValueError("control characters")
    return _event(text, arrival_ns, truncated)


def sync_record(event: SyncEvent) -> bytes:
    """The log record of an event: arrival ns and the line as received (cut to the limit), then a NUL
    byte when it was cut (``truncated``; a line never holds one, and logs without it still decode)."""
    flag = _TRUNCATED if event.truncated else b""
    return encode_record(
        _SYNC_HEAD.pack(RecordType.SYNC, event.arrival_ns) + event.text.encode("utf-8") + flag
    )


def decode_sync_record(payload) -> SyncEvent:
    _, arrival_ns = _SYNC_HEAD.unpack_from(payload)
    raw = bytes(payload[_SYNC_HEAD.size :])
    truncated = raw.endswith(_TRUNCATED)
    text = raw.removesuffix(_TRUNCATED).decode("utf-8", errors="replace")
    return _event(text, arrival_ns, truncated) or SyncEvent(arrival_ns, "", [], "")


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
        self.dropped = 0  # lines of line noise (invalid UTF-8, control characters)
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
            *lines, pending = _LINE_END.split(pending + data)
            for line in lines:
                self._line(line, now)
            # A line over the limit is cut there anyway: the rest up to its end is not kept.
            pending = pending[: MAX_LINE_BYTES + 1]
        # What came after the last line end (a box cut off mid-line): kept, flagged, stamped at its arrival.
        if pending:
            self._line(pending, now, cut=True)

    def _line(self, raw: bytes, arrival_ns: int, cut: bool = False) -> None:
        """Count and hand on the event of a received line; ``cut``: a line cut short. Line
        noise is dropped and counted (``dropped``), with one warning."""
        try:
            event = parse_sync_line(raw, arrival_ns, cut)
        except ValueError as exc:
            self.dropped += 1
            if self.dropped == 1:
                with contextlib.suppress(OSError):  # stderr that cannot be written must not stop the reading
                    warn(
                        f"the serial sync box sent a line that is not text ({exc}): such lines are dropped "
                        "(line noise or a wrong --baud?)"
                    )
            return
        if event is not None:
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
