"""Audio for a live session, stamped on the session clock and logged crash-safely in chunks.

Two sources feed the same ``AudioLog``:

- ``DeviceAudioSource``: a microphone through PortAudio (``sounddevice``, imported only when used).
  Each callback's first sample is placed at ``now - (currentTime - inputBufferAdcTime)``: PortAudio's
  own estimate of how long ago the buffer started being captured, moved onto our monotonic clock, when
  that estimate is one a buffer of that length can have (``capture_delay_s``), else the buffer's length.
- ``FileAudioSource``: a sound file played against the clock in real time, for tests and re-enacted
  sessions. Its first sample sits exactly at the moment playback starts (when listening starts, or
  when the first Live Link packet arrives).

Chunks are ~100 ms; each becomes one ``AUDIO`` record: index of its first sample, clock time of that
sample (ns) and the interleaved samples (little-endian, in the source's sample format).
"""

from __future__ import annotations

import struct
import threading
import time
import zlib
from collections.abc import Iterator, Sized
from pathlib import Path
from typing import Any

import numpy as np

from .audio_io import CHECK_FRAMES, Audio, FileAudio, audio_left_in_files, read_audio
from .errors import InputError
from .record_log import (
    INVALID_RECORD,
    RECORD_HEADER,
    LogReader,
    LogWriter,
    RecordType,
    TornTail,
    encode_record,
    json_fields,
    json_record,
)
from .session_clock import SessionClock

CHUNK_S = 0.1
# How far a chunk's first-sample index (as time) may run ahead of its clock stamp, beyond the recording's
# clock span: the stamp's jitter (a callback's latency) and a sound card's drift against the computer's
# clock (typically < 100 ppm).
AUDIO_CLOCK_TOLERANCE_S = 1.0
AUDIO_CLOCK_DRIFT = 1e-3
_FORMAT_FIELDS = {"sample_rate": (int,), "channels": (int,), "subtype": (str,), "source": (str,)}
_AUDIO_HEAD = struct.Struct("<BQq")  # type, first sample index, clock ns of the first sample
_DTYPES = {
    "PCM_16": np.dtype("<i2"),
    "PCM_24": np.dtype("<i4"),
    "PCM_32": np.dtype("<i4"),
    "FLOAT": np.dtype("<f4"),
}

PORTAUDIO_HINT = (
    "recording from a sound device needs the PortAudio library: install the Debian package "
    "libportaudio2 (apt-get install libportaudio2), or record with --audio-file"
)


# The most a sound device's input latency can add to a buffer's length (seconds): how long before the
# callback its first sample may have been captured, beyond the buffer itself.
MAX_INPUT_LATENCY_S = 1.0


def capture_delay_s(current_time: float, adc_time: float, frames: int, sample_rate: float) -> float:
    """How long before a sound-device callback the first sample of its buffer of ``frames`` was captured
    (seconds). PortAudio's times (``currentTime - inputBufferAdcTime``) when they are ones such a buffer
    can have: at least about its length (the buffer had to fill before the callback) and at most
    ``MAX_INPUT_LATENCY_S`` more. Otherwise the buffer's length: some host APIs leave both times 0
    (DirectSound, WDM-KS), give the ADC time with the wrong sign (WASAPI before PortAudio's fix of 2023)
    or derive it from another rate (CoreAudio input-only streams), and a delay of 0 stamped each buffer a
    whole buffer (0.1 s) late, which moved the take's audio by as much against its frames."""
    length = frames / sample_rate
    if current_time and adc_time:
        ago = current_time - adc_time
        if 0.5 * length <= ago <= length + MAX_INPUT_LATENCY_S:
            return ago
    return length


def check_regular_file(path: Path) -> None:
    """An --audio-file that exists must be a regular file, not a device, pipe or socket (checked when
    listen starts, and again when the file is opened at the first packet)."""
    if path.exists() and not path.is_file():
        raise InputError("the audio file is not a regular file (a device, pipe or socket)", path)


class AudioLog:
    """Writes one session's audio chunks to ``audio.log`` (thread-safe ``add_chunk``)."""

    def __init__(self, path: str | Path, fsync: bool = True):
        self.writer = LogWriter(path, fsync=fsync)
        self.format: dict[str, Any] | None = None
        self.samples = 0

    def start(self, sample_rate: int, channels: int, subtype: str, source: str) -> None:
        """Record the sample format; call once before the first chunk."""
        self.format = {"sample_rate": int(sample_rate), "channels": int(channels), "subtype": subtype}
        self.writer.put(json_record(RecordType.AUDIO_FORMAT, self.format | {"source": source}))

    def add_chunk(self, first_index: int, first_ns: int, samples: np.ndarray) -> None:
        """Log samples (frames x channels) whose first sample was captured at ``first_ns``."""
        assert self.format is not None
        dtype = _DTYPES[self.format["subtype"]]
        body = np.ascontiguousarray(samples, dtype=dtype).tobytes()
        self.writer.put(encode_record(_AUDIO_HEAD.pack(RecordType.AUDIO, first_index, first_ns) + body))
        self.samples = max(self.samples, first_index + len(samples))

    def note(self, data: dict[str, Any]) -> None:
        self.writer.put(json_record(RecordType.NOTE, data))

    def close(self) -> None:
        self.writer.close()


def _device_error(sd, device: int | str | None, exc: Exception) -> str:
    """Why a sound device did not open, in words: PortAudio's own message ("Error querying device 0")
    does not say that the machine has no input device at all."""
    try:
        inputs = [d for d in sd.query_devices() if d["max_input_channels"] > 0]
    except sd.PortAudioError:
        inputs = []
    listing = "python -m sounddevice lists the devices and their indexes"
    if not inputs:
        return f"cannot open audio device {device!r}: no sound input device found ({listing})"
    return f"cannot open audio device {device!r}: {exc} ({len(inputs)} input device(s); {listing})"


class DeviceAudioSource:
    """A sound-device input (mono or more channels, 16-bit) feeding an ``AudioLog``."""

    def __init__(
        self,
        log: AudioLog,
        clock: SessionClock,
        device: int | str | None,
        sample_rate: int,
        channels: int = 1,
    ):
        try:
            import sounddevice as sd
        except OSError:  # the Python package is there but libportaudio is not
            raise InputError(PORTAUDIO_HINT) from None
        except ImportError:
            raise InputError("recording from a sound device needs the Python package sounddevice") from None
        self._sd = sd
        self.log = log
        self.clock = clock
        self.index = 0
        self.overflows = 0
        self.error: str | None = None
        try:
            self.stream = sd.InputStream(
                device=device,
                samplerate=sample_rate,
                channels=channels,
                dtype="int16",
                blocksize=int(sample_rate * CHUNK_S),
                callback=self._callback,
            )
        except (sd.PortAudioError, ValueError) as exc:
            raise InputError(_device_error(sd, device, exc)) from None
        try:
            log.start(sample_rate, channels, "PCM_16", f"device:{device}")
        except BaseException:  # a stop that gave up listen's set-up (``_while_stoppable``): nobody has it
            self.stream.close()
            raise

    def _callback(self, indata, frames, time_info, status) -> None:
        now = self.clock.now_ns()
        times = time_info.currentTime, time_info.inputBufferAdcTime
        ago = capture_delay_s(*times, frames, self.stream.samplerate)
        if status.input_overflow:
            self.overflows += 1
            self.log.note({"kind": "audio_overflow", "at_sample": self.index})
        self.log.add_chunk(self.index, now - int(ago * 1e9), indata.copy())
        self.index += frames

    def start(self, at_ns: int | None = None) -> None:
        self.stream.start()

    def trigger(self, at_ns: int) -> None:
        """Device audio runs from the start; nothing waits for the first packet."""

    def stop(self) -> None:
        try:
            self.stream.stop()
            self.stream.close()
        except self._sd.PortAudioError as exc:
            self.error = str(exc)


class FileAudioSource:
    """Plays a sound file into an ``AudioLog`` in real time against the session clock.

    ``start_on_first_packet``: playback begins when ``trigger`` is called (the recorder calls it at
    the first Live Link packet), and the file is only opened then, so a replay can write it first.
    """

    def __init__(
        self, log: AudioLog, clock: SessionClock, path: str | Path, start_on_first_packet: bool = False
    ):
        self.log = log
        self.clock = clock
        self.path = Path(path)
        self.start_on_first_packet = start_on_first_packet
        self.error: str | None = None
        self._audio: Audio | None = None
        self._go = threading.Event()
        self._stop = threading.Event()
        self._start_ns = 0
        self._thread = threading.Thread(target=self._play, name="audio-file", daemon=True)
        if not start_on_first_packet:
            self._audio = _read_audio_file(self.path)  # a missing file is an error before recording starts

    def start(self) -> None:
        self._thread.start()
        if not self.start_on_first_packet:
            self.trigger(self.clock.now_ns())

    def trigger(self, at_ns: int) -> None:
        """Start playback with the first sample at clock time ``at_ns`` (first call only)."""
        if not self._go.is_set():
            self._start_ns = at_ns
            self._go.set()

    def _play(self) -> None:
        while not self._go.wait(0.05):
            if self._stop.is_set():  # stopped before the first packet: the file is never opened
                return
        try:
            check_regular_file(self.path)
            audio = self._audio or _read_audio_file(self.path)
            self.log.start(audio.sample_rate, audio.channels, audio.subtype, f"file:{self.path}")
            self._play_chunks(audio)
        except InputError as exc:  # also a file changed or removed while it plays (``FileAudio.blocks``)
            self.error = str(exc)
        except (OSError, MemoryError) as exc:  # too many open files, an I/O error, no memory left
            why = getattr(exc, "strerror", None) or str(exc) or "out of memory"
            self.error = f"{self.path}: cannot read the audio file: {why}"
        if self.error is not None:
            self.log.note({"kind": "audio_error", "message": self.error})

    def _play_chunks(self, audio: Audio) -> None:
        """Log ``audio`` a chunk at a time, each when its last sample has been played, until it ends or
        ``stop``. Audio left in its file is read a chunk at a time as it plays."""
        rate = audio.sample_rate
        chunk = max(1, int(rate * CHUNK_S))
        if isinstance(audio, FileAudio):
            chunks = audio.blocks(chunk)
        else:
            chunks = (audio.samples[first : first + chunk] for first in range(0, audio.frames, chunk))
        first = 0
        try:
            for samples in chunks:
                n = len(samples)
                # A chunk is "captured" once its last sample has been played.
                due = self._start_ns + int((first + n) * 1e9 / rate)
                while not self._stop.is_set():
                    wait = (due - self.clock.now_ns()) / 1e9
                    if wait <= 0:
                        break
                    time.sleep(min(wait, 0.05))
                if self._stop.is_set():
                    return
                self.log.add_chunk(first, self._start_ns + int(first * 1e9 / rate), samples)
                first += n
        finally:
            chunks.close()  # the file of audio left in it, at a stop before its end

    def stop(self) -> None:
        """Stop playing (within 0.05 s); playback that was never triggered never opens the file."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()


def _read_audio_file(path: Path) -> Audio:
    """The audio of an --audio-file: left in its file where ``read_audio`` can (``audio_left_in_files``:
    WAV, FLAC, OGG), so that an hour of it costs no more memory than a chunk, and the read is a loop of
    blocks that a stop during ``listen``'s set-up ends at its next step (``live_cli._while_stoppable``);
    other files (MP3, video) are read whole."""
    with audio_left_in_files():
        return read_audio(path)


class AudioLogChanged(InputError):
    """A session's audio log whose records are no longer those ``index_audio_log`` indexed: read it again."""


class SessionAudio:
    """A session's audio as its log holds it, read a span at a time (``read``): the log's chunks, placed
    by their sample index, are indexed by where their samples lie in the file, so a take's few minutes of
    an hour's log cost their own memory only. Samples no chunk holds (``gaps``: a lost callback, a torn
    tail) read as silence; where chunks overlap, the later one (by sample index, then stamp, then place in
    the file) wins. Each record read is checked against its checksum again: a log changed since it was
    indexed is an ``InputError``, never other samples read as the indexed ones."""

    def __init__(self, path: Path, fmt: dict[str, Any], chunks: list[tuple[int, int, int, int]]):
        self.path = path
        self.sample_rate: int = fmt["sample_rate"]
        self.channels: int = fmt["channels"]
        self.subtype: str = fmt["subtype"]
        self._dtype = _DTYPES[self.subtype]
        chunks = sorted(chunks)  # (first sample, clock ns, file offset of the record, samples)
        self._first = np.array([c[0] for c in chunks], dtype=np.int64)
        self._end = self._first + np.array([c[3] for c in chunks], dtype=np.int64)
        self._offset = [c[2] for c in chunks]
        self.frames = int(self._end.max())
        self.first_ns = chunks[0][1] - int(chunks[0][0] * 1e9 / self.sample_rate)  # clock ns of sample 0
        self.gaps: list[dict[str, int]] = []
        covered = 0
        for first, end in zip(self._first.tolist(), self._end.tolist(), strict=True):
            if first > covered:
                self.gaps.append({"at_sample": covered, "samples": first - covered})
            covered = max(covered, end)

    def read(self, lo: int = 0, hi: int | None = None) -> Audio:
        """Samples ``lo`` to ``hi`` (the end by default) of the session's audio, read from the log."""
        hi = self.frames if hi is None else hi
        samples = np.zeros((hi - lo, self.channels), dtype=self._dtype.newbyteorder("="))
        frame_bytes = self._dtype.itemsize * self.channels
        with open(self.path, "rb") as f:
            for i in np.flatnonzero((self._first < hi) & (self._end > lo)).tolist():
                first, end = int(self._first[i]), int(self._end[i])
                f.seek(self._offset[i])
                record = f.read(RECORD_HEADER.size + _AUDIO_HEAD.size + (end - first) * frame_bytes)
                payload = memoryview(record)[RECORD_HEADER.size :]
                if record[: RECORD_HEADER.size] != RECORD_HEADER.pack(len(payload), zlib.crc32(payload)):
                    raise AudioLogChanged(
                        "the audio log changed since it was indexed (read it again)", self.path
                    )
                block = np.frombuffer(payload[_AUDIO_HEAD.size :], dtype=self._dtype).reshape(
                    -1, self.channels
                )
                a, b = max(lo, first), min(hi, end)
                samples[a - lo : b - lo] = block[a - first : b - first]
        return Audio(samples, self.sample_rate, self.subtype)

    def span(self, lo: int, hi: int) -> Audio:
        """Samples ``lo`` to ``hi`` as ``read`` gives them, left in the log (``LoggedSpan``: a take's span
        is written a block at a time, never held whole, each record's checksum checked as it is copied).
        Float samples are read once here first, a block at a time: a span holding NaN or infinite samples,
        which no take holds, is an ``InputError`` before the take is written (integer samples are read
        only as they are copied). That error names no file: a take's repair keeps it in its ``take.json``,
        which is not to depend on the path ``recover`` was given."""
        span = LoggedSpan(self, lo, hi)
        if span.dtype.kind == "f":
            bad = sum(int(np.count_nonzero(~np.isfinite(block))) for block in span.blocks(CHECK_FRAMES))
            if bad:
                raise InputError(f"the span holds {bad} NaN or infinite sample(s)")
        return span

    def gaps_within(self, lo: int, hi: int) -> list[dict[str, int]]:
        """The ``gaps`` that samples ``lo`` to ``hi`` cross, as sample ranges counted from ``lo``."""
        cut = [(max(g["at_sample"], lo), min(g["at_sample"] + g["samples"], hi)) for g in self.gaps]
        return [{"at_sample": a - lo, "samples": b - a} for a, b in cut if a < b]


class LoggedSpan(FileAudio):
    """A span of a session's audio (``SessionAudio.span``) left in its log: ``write_audio`` copies it a
    block at a time, as it does audio left in its file (its samples, asked for, are read whole)."""

    def __init__(self, audio: SessionAudio, lo: int, hi: int):
        dtype = audio._dtype.newbyteorder("=")
        crcs = np.zeros(0, np.uint32)  # its blocks are checked against the log's own checksums
        super().__init__(audio.path, audio.sample_rate, audio.subtype, dtype, hi - lo, audio.channels, crcs)
        self._audio, self._lo = audio, lo

    def blocks(self, size: int) -> Iterator[np.ndarray]:
        end = self._lo + self.frames
        for at in range(self._lo, end, size):
            yield self._audio.read(at, min(at + size, end)).samples


def index_audio_log(path: str | Path) -> tuple[SessionAudio | None, dict[str, Any]]:
    """The audio of a session log (None without a log, a format or a chunk) and a report: ``chunks``,
    ``gaps`` (filled with silence when read), ``notes``, ``torn_tail`` and ``log_damage``. Chunks are
    placed by their sample index, so order in the file does not matter. Only the chunks' places are
    held: the samples stay in the log until ``SessionAudio.read``."""
    path = Path(path)
    report: dict[str, Any] = {"chunks": 0, "gaps": [], "notes": []}
    if not path.is_file():
        return None, report
    reader = LogReader(path)
    fmt = None
    # per chunk: first sample index, clock ns, where its samples lie in the file (a range of offsets) and
    # its record (offset, size)
    chunks: list[tuple[int, int, range, tuple[int, int]]] = []
    for payload in reader:
        kind = payload[0]
        if kind == RecordType.AUDIO_FORMAT:
            data = json_fields(payload, _FORMAT_FIELDS, ("sample_rate", "channels", "subtype"))
            if (
                data is None
                or data["subtype"] not in _DTYPES
                or not (
                    0 < data["sample_rate"] < 1 << 32 and 0 < data["channels"] < 1 << 16  # WAV's fields
                )
            ):
                reader.reject(INVALID_RECORD)
            else:
                fmt = data
        elif kind == RecordType.AUDIO and len(payload) >= _AUDIO_HEAD.size:
            _, first, ns = _AUDIO_HEAD.unpack_from(payload)
            at = reader.last[0] + RECORD_HEADER.size + _AUDIO_HEAD.size
            chunks.append((first, ns, range(at, reader.last[0] + reader.last[1]), reader.last))
        elif kind == RecordType.NOTE:
            note = json_fields(payload, {"kind": (str,), "message": (str,)})
            if note is None:
                reader.reject(INVALID_RECORD)
            else:
                report["notes"].append(note)
        elif kind == RecordType.AUDIO:
            reader.reject(INVALID_RECORD)
    if fmt is not None:
        chunks = _placeable(chunks, fmt, reader)
    tail: TornTail | None = reader.torn_tail
    if tail is not None:
        report["torn_tail"] = tail.to_json()
    if reader.skipped:
        report["log_damage"] = [d.to_json() for d in sorted(reader.skipped, key=lambda d: d.offset)]
    if fmt is None or not chunks:
        return None, report
    frame_bytes = _DTYPES[fmt["subtype"]].itemsize * fmt["channels"]
    audio = SessionAudio(
        path, fmt, [(first, ns, record[0], len(at) // frame_bytes) for first, ns, at, record in chunks]
    )
    report["chunks"] = len(chunks)
    report["gaps"] = audio.gaps
    return audio, report


def _placeable(
    chunks: list[tuple[int, int, Sized, tuple[int, int]]], fmt: dict[str, Any], reader: LogReader
) -> list[tuple[int, int, Sized, tuple[int, int]]]:
    """The chunks ``index_audio_log`` places by their sample index; the others are counted as damage
    (``LogReader.reject``): a body that is no whole number of sample frames, or a first-sample index
    further ahead of the chunk's clock stamp than any recording can put it - a forged index would make
    room for hours of silence. Each chunk's index and stamp give the clock time of sample 0; a sound
    card's drift and its dropped input (overflows, which the index does not count) move that time later
    as the recording goes on, never earlier by more than the drift, and never by more than the
    recording's clock span: so a chunk whose sample 0 lies earlier than the chunks' median by more than
    that span (``AUDIO_CLOCK_DRIFT`` included) and ``AUDIO_CLOCK_TOLERANCE_S`` is no recorder's."""
    frame_bytes = _DTYPES[fmt["subtype"]].itemsize * fmt["channels"]
    rate = fmt["sample_rate"]
    whole = [c for c in chunks if len(c[2]) % frame_bytes == 0]
    if whole:
        stamp_s = np.array([ns / 1e9 for _, ns, *_ in whole])
        start_s = stamp_s - np.array([first / rate for first, *_ in whole])  # the clock time of sample 0
        span_s = float(stamp_s.max() - stamp_s.min())
        ahead = np.median(start_s) - start_s > AUDIO_CLOCK_TOLERANCE_S + span_s * (1 + AUDIO_CLOCK_DRIFT)
        whole = [c for c, bad in zip(whole, ahead, strict=True) if not bad]
    kept = {id(c) for c in whole}
    for c in chunks:
        if id(c) not in kept:
            reader.reject(INVALID_RECORD, c[3])
    return whole
