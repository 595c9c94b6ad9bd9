"""An append-only log of length-prefixed, checksummed records: what the live recorder writes while it
records, so that a SIGKILL or a power loss costs at most the last unflushed fraction of a second.

File layout (docs/live-capture.md)::

    magic  8 bytes  b"S2ALOG1\\n"
    record          u32 LE payload length | u32 LE CRC-32 of the payload | payload
    record          ...

The first payload byte is the record type (``RecordType``). A reader walks the records in order and
stops at the first one that is incomplete, longer than ``MAX_RECORD_BYTES`` or fails its checksum:
that is the torn tail (what a crash cut short), reported with its offset and size, never an error.

``LogWriter`` hands filled buffers to a background thread that writes and fsyncs them, so the caller
(the UDP loop) never blocks on the disk.
"""

from __future__ import annotations

import json
import os
import queue
import struct
import threading
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

from .errors import InputError

MAGIC = b"S2ALOG1\n"
RECORD_HEADER = struct.Struct("<II")  # payload length, CRC-32 of the payload
MAX_RECORD_BYTES = 1 << 24  # 16 MiB: anything longer is taken for garbage, not a record
MAX_UNWRITTEN_BYTES = 256 << 20  # what a writer holds in memory while the disk refuses writes


class RecordType(IntEnum):
    """First byte of a record's payload."""

    SESSION = 1  # JSON: session id, clock origin, listener address, ...
    STREAM = 2  # u16 stream id + JSON {device, subject, rate_numerator, rate_denominator, source}
    FRAME = 3  # u16 stream id, i64 arrival ns (recorder clock), 261-byte packet frame block
    REJECTS = 4  # JSON: datagram counts by rejection reason so far (cumulative)
    SYNC = 5  # i64 arrival ns + UTF-8 line from the serial sync box
    AUDIO_FORMAT = 6  # JSON: sample_rate, channels, subtype, source
    AUDIO = 7  # u64 index of the first sample, i64 clock ns of that sample, interleaved samples
    END = 8  # JSON: the recorder stopped cleanly (totals)
    NOTE = 9  # JSON: an event worth keeping (audio overflow, serial error, ...)
    NO_FACE = 10  # u16 stream id, i64 arrival ns, 16-byte frame time of a no-face packet (face lost)


def encode_record(payload: bytes) -> bytes:
    """One complete record (header + payload)."""
    return RECORD_HEADER.pack(len(payload), zlib.crc32(payload)) + payload


def json_record(kind: RecordType, data: dict[str, Any]) -> bytes:
    """A record whose payload is the type byte followed by compact JSON."""
    return encode_record(bytes([kind]) + json.dumps(data, separators=(",", ":"), default=str).encode())


@dataclass
class TornTail:
    """Where a log stops being valid and why (a crash or power loss cut the last write short)."""

    offset: int  # byte offset of the first invalid record
    bytes_discarded: int
    reason: str  # "incomplete_header", "incomplete_record", "bad_length", "checksum"

    def to_json(self) -> dict[str, Any]:
        return {"offset": self.offset, "bytes_discarded": self.bytes_discarded, "reason": self.reason}


class LogReader:
    """Iterates the valid records of a log file; ``torn_tail`` is set when the iteration is done."""

    def __init__(self, path: str | Path, block_bytes: int = 1 << 20):
        self.path = Path(path)
        self.block_bytes = block_bytes
        self.torn_tail: TornTail | None = None
        self.records = 0
        self.valid_bytes = 0

    def __iter__(self) -> Iterator[memoryview]:
        """Payloads (memoryviews, valid until the next step)."""
        try:
            f = open(self.path, "rb")
        except FileNotFoundError:
            raise InputError("record log not found", self.path) from None
        with f:
            size = os.fstat(f.fileno()).st_size
            magic = f.read(len(MAGIC))
            if magic != MAGIC:
                if len(magic) < len(MAGIC) and MAGIC.startswith(magic):
                    # Killed before the magic reached the disk: an empty log with a torn tail.
                    self.torn_tail = TornTail(0, len(magic), "incomplete_header")
                    return
                raise InputError("not a recorder log (bad magic bytes)", self.path)
            base = len(MAGIC)  # file offset of buf[0]
            buf = b""
            at = 0
            eof = False

            def refill() -> None:
                nonlocal buf, base, at, eof
                chunk = f.read(self.block_bytes)
                if not chunk:
                    eof = True
                    return
                base += at
                buf = buf[at:] + chunk
                at = 0

            while True:
                while not eof and len(buf) - at < RECORD_HEADER.size:
                    refill()
                left = len(buf) - at
                if left == 0:
                    break
                offset = base + at
                if left < RECORD_HEADER.size:
                    self.torn_tail = TornTail(offset, size - offset, "incomplete_header")
                    break
                length, crc = RECORD_HEADER.unpack_from(buf, at)
                if length == 0 or length > MAX_RECORD_BYTES:
                    self.torn_tail = TornTail(offset, size - offset, "bad_length")
                    break
                while not eof and len(buf) - at < RECORD_HEADER.size + length:
                    refill()
                offset = base + at
                if len(buf) - at < RECORD_HEADER.size + length:
                    self.torn_tail = TornTail(offset, size - offset, "incomplete_record")
                    break
                end = at + RECORD_HEADER.size + length
                payload = memoryview(buf)[at + RECORD_HEADER.size : end]
                if zlib.crc32(payload) != crc:
                    self.torn_tail = TornTail(offset, size - offset, "checksum")
                    break
                self.records += 1
                at = end
                self.valid_bytes = base + at
                yield payload
            if self.torn_tail is None:
                self.valid_bytes = base + at


class LogWriter:
    """Appends records to a log; a background thread writes and fsyncs each handed-over buffer.

    The owner appends to ``buffer`` (a bytearray) from one thread and calls ``flush()`` at least every
    flush interval; records from other threads go through ``put()``.

    A write that fails (disk full, I/O error) keeps the first error in ``error`` and counts in
    ``failed_writes``; what did not reach the file stays in memory (``unwritten_bytes``) and goes first
    at the next write, so the log stays a valid sequence of records once the disk has room again. Past
    ``MAX_UNWRITTEN_BYTES`` held, newly handed records are dropped and counted (``dropped_bytes``).
    """

    def __init__(self, path: str | Path, fsync: bool = True):
        self.path = Path(path)
        self.fsync = fsync
        self.buffer = bytearray()
        self._queue: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            if os.fstat(self._fd).st_size == 0:
                os.write(self._fd, MAGIC)  # a disk that is full already fails here, at the start
        except OSError:
            os.close(self._fd)
            raise
        self.error: OSError | None = None
        self.failed_writes = 0
        self.dropped_bytes = 0
        self.bytes_written = 0
        self._unwritten = b""
        self._thread = threading.Thread(target=self._write_loop, name=f"log-{self.path.name}", daemon=True)
        self._thread.start()

    @property
    def unwritten_bytes(self) -> int:
        """Bytes handed over that are not in the file yet (held after a failed write)."""
        return len(self._unwritten)

    def put(self, record: bytes) -> None:
        """Queue one complete record for writing (thread-safe)."""
        self._queue.put(record)

    def flush(self) -> None:
        """Hand the buffered records to the writer thread (returns at once)."""
        if self.buffer:
            self._queue.put(bytes(self.buffer))
            self.buffer.clear()

    def _write_loop(self) -> None:
        stop = False
        while not stop:
            item = self._queue.get()
            stop = item is None
            # Coalesce what is waiting so a slow disk sees few large writes.
            parts = [] if stop else [item]
            while not stop:
                try:
                    more = self._queue.get_nowait()
                except queue.Empty:
                    break
                if more is None:
                    stop = True
                else:
                    parts.append(more)
            self._write(b"".join(parts))  # at the stop too: a last try of what is held

    def _write(self, new: bytes) -> None:
        if len(self._unwritten) + len(new) > MAX_UNWRITTEN_BYTES:
            self.dropped_bytes += len(new)  # whole records: the held bytes stay a valid continuation
            new = b""
        data = self._unwritten + new if self._unwritten else new
        if not data:
            return
        view = memoryview(data)
        try:
            while view:
                n = os.write(self._fd, view)
                view = view[n:]
            if self.fsync:
                os.fdatasync(self._fd)
        except OSError as exc:  # disk full, I/O error: keep the first, report it at the end
            self.error = self.error or exc
            self.failed_writes += 1
        self.bytes_written += len(data) - len(view)
        self._unwritten = bytes(view)

    def close(self) -> None:
        """Flush, wait for the writer thread, fsync and close the file."""
        self.flush()
        self._queue.put(None)
        self._thread.join()
        try:
            os.fsync(self._fd)
        except OSError as exc:
            self.error = self.error or exc
        os.close(self._fd)
