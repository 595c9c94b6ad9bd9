"""An append-only log of length-prefixed, checksummed records: what the live recorder writes while it
records, so that a SIGKILL or a power loss costs at most the last unflushed fraction of a second.

File layout (docs/live-capture.md)::

    magic  8 bytes  b"S2ALOG1\\n"
    record          u32 LE payload length | u32 LE CRC-32 of the payload | payload
    record          ...

The first payload byte is the record type (``RecordType``). A reader walks the records in order. A
record that is incomplete, longer than ``MAX_RECORD_BYTES`` or fails its checksum starts a damaged
stretch: the reader searches the bytes after it for the next valid record (a known
type, a plausible length, a matching CRC-32) and goes on from there, so a flipped bit or a zeroed
block in the middle of a session costs only the records it hit (``skipped``). When no valid record
follows, the damage is the torn tail (what a crash cut short). Both are reported with offset, size and
reason, never as an error; so is a valid record whose content a reader finds is none a recorder writes
(``LogReader.reject``).

``LogWriter`` hands filled buffers to a background thread that writes and fsyncs them, so the caller
(the UDP loop) never blocks on the disk.
"""

from __future__ import annotations

import errno
import io
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

import numpy as np

from .errors import InputError

MAGIC = b"S2ALOG1\n"
RECORD_HEADER = struct.Struct("<II")  # payload length, CRC-32 of the payload
MAX_RECORD_BYTES = 1 << 24  # 16 MiB: anything longer is taken for garbage, not a record
MAX_UNWRITTEN_BYTES = 256 << 20  # what a writer holds in memory while the disk refuses writes
# Past damage, only records up to this long are looked for (the recorder's longest, 0.1 s of audio, is
# 614 KB even at 192 kHz x 8 channels of float32): each candidate is read and checksummed, and in random
# bytes candidates of up to 16 MiB would cost megabytes of reading every few kilobytes.
RESYNC_MAX_BYTES = 1 << 20
# Candidates longer than this must have a length the log has used before, or be followed by a record
# of the same length (the recorder's long records, audio chunks, come in runs of one size); and once
# the search has checksummed RESYNC_BUDGET times the bytes it has passed (plus RESYNC_MAX_BYTES), only
# the first kind. A pattern that mimics headers then costs a bounded multiple of its size.
RESYNC_FREE_BYTES = 4096
# ``TornTail.reason`` of a record whose checksum holds but whose content no recorder writes (a reader's
# ``LogReader.reject``): a record forged in bytes a sender chose, or another program's.
INVALID_RECORD = "invalid_record"
RESYNC_BUDGET = 8


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
    # u16 stream id, i64 arrival ns, 16-byte frame time (big-endian, as FRAME's), N big-endian f32 values:
    # a frame of a subject with its own controls (the newer app's MetaHuman Animator stream), their
    # names in the ``controls`` of its STREAM record (stream ids of their own, apart from FRAME's)
    CONTROLS = 11


def encode_record(payload: bytes) -> bytes:
    """One complete record (header + payload)."""
    return RECORD_HEADER.pack(len(payload), zlib.crc32(payload)) + payload


def json_record(kind: RecordType, data: dict[str, Any]) -> bytes:
    """A record whose payload is the type byte followed by compact JSON."""
    return encode_record(bytes([kind]) + json.dumps(data, separators=(",", ":"), default=str).encode())


def json_fields(payload, fields: dict[str, tuple[type, ...]], required: tuple[str, ...] = ()) -> dict | None:
    """The JSON object of a record (after its type byte), or None when it is none a recorder writes: not
    UTF-8 JSON, not an object, a ``required`` field missing or a field of ``fields`` of another type
    (``bool`` is no ``int`` here)."""
    try:
        data = json.loads(bytes(payload[1:]))
    except (ValueError, RecursionError):  # ValueError: bad JSON or UTF-8, an integer of 4300+ digits
        return None
    if not isinstance(data, dict) or any(key not in data for key in required):
        return None
    for key, types in fields.items():
        value = data.get(key)
        if key in data and (not isinstance(value, types) or isinstance(value, bool) and bool not in types):
            return None
    return data


@dataclass
class TornTail:
    """A stretch of a log that holds no valid record, and why: the torn tail (a crash or power loss cut
    the last write short) or a damaged stretch between valid records (``LogReader.skipped``)."""

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
        self.skipped: list[TornTail] = []  # damaged stretches with valid records after them
        self._lengths: set[int] = set()  # payload lengths of the valid records read so far
        self._shapes: set[tuple[int, int]] = set()  # (type, payload length) of the valid records read
        self.last: tuple[int, int] = (0, 0)  # offset and size of the record last yielded
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
            offset = len(MAGIC)
            while True:
                offset, bad = yield from self._records(f, offset, size)
                if bad is None:
                    break
                resume = self._resync(f, bad.offset, size)
                if resume is None:
                    self.torn_tail = TornTail(bad.offset, size - bad.offset, bad.reason)
                    break
                self.skipped.append(TornTail(bad.offset, resume - bad.offset, bad.reason))
                offset = resume

    def reject(self, reason: str, record: tuple[int, int] | None = None) -> None:
        """Count a record whose checksum holds but whose content no recorder writes (a field of the wrong
        type, a size that does not add up) as damage, like a record that fails its checksum: ``record``
        (offset, size) or the one last yielded goes to ``skipped`` with ``reason``."""
        offset, n = record or self.last
        self.skipped.append(TornTail(offset, n, reason))
        self.records -= 1

    def _resync(self, f, bad: int, size: int) -> int | None:
        """Offset of the next valid record after the invalid one at ``bad`` (None: there is none). When
        the invalid record's header has the type and length of a record read before (a FRAME record whose
        payload is damaged or cut), it is taken to span that length: a candidate lying inside it is
        accepted only if the valid records from it reach past its end (records a recorder appended after
        a torn record do; a record forged in a packet's bytes, which a Live Link sender chooses, does not)."""
        f.seek(bad)
        head = f.read(RECORD_HEADER.size + 1)
        end = None
        if len(head) == RECORD_HEADER.size + 1:
            (length, _) = RECORD_HEADER.unpack_from(head)
            if (head[-1], length) in self._shapes:
                end = bad + RECORD_HEADER.size + length
        start = bad + 1
        while (resume := _next_record(f, start, size, self._lengths)) is not None:
            if end is None or resume >= end or _chain_past(f, resume, end):
                return resume
            start = resume + 1
        return None

    def _records(self, f, offset: int, size: int) -> Iterator[memoryview]:
        """Yields the valid records from ``offset`` on; returns (end offset, the invalid record or None
        at the end of the file)."""
        f.seek(offset)
        base = offset  # file offset of buf[0]
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
            offset = base + at
            if left == 0:
                self.valid_bytes = offset
                return offset, None
            if left < RECORD_HEADER.size:
                return offset, TornTail(offset, size - offset, "incomplete_header")
            length, crc = RECORD_HEADER.unpack_from(buf, at)
            if length == 0 or length > MAX_RECORD_BYTES:
                return offset, TornTail(offset, size - offset, "bad_length")
            while not eof and len(buf) - at < RECORD_HEADER.size + length:
                refill()
            offset = base + at
            if len(buf) - at < RECORD_HEADER.size + length:
                return offset, TornTail(offset, size - offset, "incomplete_record")
            end = at + RECORD_HEADER.size + length
            payload = memoryview(buf)[at + RECORD_HEADER.size : end]
            if zlib.crc32(payload) != crc:
                return offset, TornTail(offset, size - offset, "checksum")
            self.records += 1
            if length > RESYNC_FREE_BYTES and len(self._lengths) < 256:
                self._lengths.add(length)
            if len(self._shapes) < 256:
                self._shapes.add((payload[0], length))
            self.last = (offset, RECORD_HEADER.size + length)
            at = end
            self.valid_bytes = base + at
            yield payload


_KNOWN_TYPES = frozenset(int(t) for t in RecordType)


def _plausible_next(f, end: int, size: int, length: int, lengths: set[int]) -> bool:
    """Whether a candidate record of ``length`` ending at ``end`` is worth checksumming: what follows
    could be the next record (the end of the file, a header cut short there, or a header of a known
    type and a plausible length), and a long candidate has a length used before or is followed by
    one of the same length."""
    if end + RECORD_HEADER.size + 1 > size:
        return length <= RESYNC_FREE_BYTES or length in lengths or end == size
    f.seek(end)
    head = f.read(RECORD_HEADER.size + 1)
    (following, _) = RECORD_HEADER.unpack_from(head)
    if not (0 < following <= MAX_RECORD_BYTES and head[RECORD_HEADER.size] in _KNOWN_TYPES):
        return False
    return length <= RESYNC_FREE_BYTES or length in lengths or following == length


def _chain_past(f, at: int, end: int) -> bool:
    """Whether valid records follow one another from ``at`` to past ``end``."""
    while at < end:
        f.seek(at)
        head = f.read(RECORD_HEADER.size)
        if len(head) < RECORD_HEADER.size:
            return False
        length, crc = RECORD_HEADER.unpack(head)
        if not 0 < length <= MAX_RECORD_BYTES or zlib.crc32(f.read(length)) != crc:
            return False
        at += RECORD_HEADER.size + length
    return at > end


def _next_record(f, start: int, size: int, lengths: set[int], block: int = 1 << 20) -> int | None:
    """Offset of the first valid record at or after ``start`` (None: there is none).

    Candidates are the offsets whose length field is at most ``RESYNC_MAX_BYTES`` and whose first
    payload byte is a known record type (about one offset in 100,000 of random bytes), that pass
    ``_plausible_next`` (``lengths``: the long lengths the log has used) and the budget
    (``RESYNC_BUDGET``); only those are read and checksummed. (Without them, 4 MB of a repeating pattern
    that mimics headers took 128 s.)"""
    need = RECORD_HEADER.size + 1
    pos = start
    spent = 0  # bytes checksummed for long candidates of new lengths
    while pos + need <= size:
        f.seek(pos)
        chunk = np.frombuffer(f.read(block + need - 1), np.uint8)
        n = chunk.size - need + 1  # offsets in this chunk with a whole header and type byte after them
        if n <= 0:
            return None
        length = (
            chunk[0:n].astype(np.uint32)
            | chunk[1 : n + 1].astype(np.uint32) << 8
            | chunk[2 : n + 2].astype(np.uint32) << 16
            | chunk[3 : n + 3].astype(np.uint32) << 24
        )
        kind = chunk[RECORD_HEADER.size : RECORD_HEADER.size + n]
        plausible = (length > 0) & (length <= RESYNC_MAX_BYTES) & np.isin(kind, list(_KNOWN_TYPES))
        for i in np.flatnonzero(plausible).tolist():
            at, n_bytes = pos + i, int(length[i])
            end = at + RECORD_HEADER.size + n_bytes
            if end > size or not _plausible_next(f, end, size, n_bytes, lengths):
                continue
            novel = n_bytes > RESYNC_FREE_BYTES and n_bytes not in lengths
            if novel and spent > RESYNC_BUDGET * (at - start) + RESYNC_MAX_BYTES:
                continue
            spent += n_bytes if novel else 0
            f.seek(at)
            (_, crc) = RECORD_HEADER.unpack(f.read(RECORD_HEADER.size))
            if zlib.crc32(f.read(n_bytes)) == crc:
                return at
        pos += n
    return None


# The ``LogWriter``s not closed yet (``LogWriter.close_open``), from before each opens its file.
_OPEN: set[LogWriter] = set()
_OPEN_LOCK = threading.Lock()


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
        self.error: OSError | None = None
        self.fsync_failed = False
        self.failed_writes = 0
        self.dropped_bytes = 0
        self.bytes_written = 0
        self._unwritten = b""
        self._file: io.FileIO | None = None
        self._thread = threading.Thread(target=self._write_loop, name=f"log-{self.path.name}", daemon=True)
        with _OPEN_LOCK:  # before the file is open: a stop signal from here on leaves it to ``close_open``
            _OPEN.add(self)
        try:
            # a file object, not a bare descriptor: one a stop signal loses on its way here is closed with it
            self._file = io.FileIO(self.path, "a")
            self._fd = self._file.fileno()
            if os.fstat(self._fd).st_size == 0:
                os.write(self._fd, MAGIC)  # a disk that is full already fails here, at the start
            self._thread.start()
        except OSError:
            self.close()
            raise

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
            try:
                self._write(b"".join(parts))  # at the stop too: a last try of what is held
            except MemoryError:  # no room to join what waits: those records are dropped, counted, and
                # the thread goes on (a dead writer thread would lose every later record unreported)
                self.dropped_bytes += sum(map(len, parts))
                self.failed_writes += 1
                self.error = self.error or OSError(errno.ENOMEM, "out of memory holding the records to write")

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
        """Flush, wait for the writer thread, fsync and close the file (once; again does nothing)."""
        with _OPEN_LOCK:
            if self not in _OPEN:
                return
            _OPEN.discard(self)
        self.flush()
        self._queue.put(None)
        if self._thread.ident is not None:  # started
            self._thread.join()
        if self._file is None:
            return
        try:
            os.fsync(self._file.fileno())
        except OSError as exc:  # what the kernel held may not be on disk: no "nothing was lost" after this
            self.error = self.error or exc
            self.fsync_failed = True
        self._file.close()

    @staticmethod
    def close_open(folder: str | Path) -> None:
        """Close every writer of a log in ``folder`` that is still open: those a stop signal (an exception
        at any step of the caller, ``listen``'s set-up) left without an owner to close them, between
        their making and the caller's keeping them (a writer thread and an open file otherwise)."""
        folder = Path(folder)
        with _OPEN_LOCK:
            left = [w for w in _OPEN if w.path.parent == folder]
        for writer in left:
            writer.close()

    @property
    def lost_nothing(self) -> bool:
        """Whether every record handed over reached the disk, failed writes retried included."""
        return not (self.unwritten_bytes or self.dropped_bytes or self.fsync_failed)

    def failure(self, what: str) -> str | None:
        """One phrase for a log whose writes failed (None when none did): what was lost and why."""
        if self.error is None:
            return None
        lost = self.unwritten_bytes + self.dropped_bytes
        counts = f"{self.failed_writes} failed writes, {lost} bytes not on disk"
        if self.fsync_failed:
            counts += ", the last sync to disk failed"
        return f"writing the {what} failed ({counts}): {self.error.strerror or self.error}"
