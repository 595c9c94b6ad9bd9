"""Reading and writing a take's audio, keeping the recorded sample rate and sample format.

WAV/FLAC/OGG (and MP3 where libsndfile supports it) are read with soundfile; everything else a phone or
editor produces (M4A/AAC, the Live Link Face ``.mov``) is decoded with PyAV. Integer PCM stays integer so
a take's audio round-trips exactly.
"""

from __future__ import annotations

import bisect
import io
import math
import os
import re
import shutil
import struct
import tempfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from itertools import accumulate
from pathlib import Path
from typing import IO, Any

import numpy as np
import soundfile as sf

from .atomic import atomic_write
from .command import stops_deferred, warn
from .errors import InputError, printable
from .growing import GrowingRows
from .numbers import number_array

_NATIVE = {"PCM_16": "int16", "PCM_24": "int32", "PCM_32": "int32", "FLOAT": "float32"}
_SCALE = {"int16": 32768.0, "int32": 2147483648.0}


# A recording peaking below -70 dBFS (of full scale) holds no usable sound: no speech to align or featurise,
# a silent track of a .mov.
SILENT_PEAK = 10 ** (-70 / 20)


def full_scale(samples: np.ndarray) -> float:
    """The value that is full scale for ``samples``' type: 32768 for int16, 2^31 for int32, 1 for float."""
    return _SCALE.get(samples.dtype.name, 1.0)


# More channels than this in the second axis of a shorter array: (channels, samples), not (samples, channels)
MAX_AUDIO_CHANNELS = 64


def whole_sample_rate(rate: Any) -> int:
    """``rate`` as a whole positive number of Hz (44100, 44100.0, a NumPy integer); an ``InputError`` for
    a fraction (44100.7), zero or less, NaN, a bool or text: a rate is never rounded silently."""
    if isinstance(rate, (bool, np.bool_)) or not isinstance(rate, (int, float, np.integer, np.floating)):
        raise InputError(f"audio sample rate must be a whole positive number of Hz, not {rate!r:.40}")
    if not (math.isfinite(rate) and rate > 0 and float(rate).is_integer()):
        raise InputError(f"audio sample rate must be a whole positive number of Hz, not {rate!r:.40}")
    return int(rate)


def audio_samples(samples: Any) -> np.ndarray:
    """``samples`` as a (samples, channels) array of numbers (a 1-D array or a list is one channel); an
    ``InputError`` for text, bools or objects, more than two dimensions, and an array that is obviously
    (channels, samples): more than ``MAX_AUDIO_CHANNELS`` columns and fewer rows."""
    x = number_array(samples, "audio samples")
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise InputError(f"audio samples must be (samples, channels), not an array of shape {x.shape}")
    if x.shape[1] > MAX_AUDIO_CHANNELS and x.shape[0] < x.shape[1]:
        raise InputError(
            f"audio samples of shape {x.shape} look like (channels, samples): give (samples, channels), "
            "e.g. samples.T"
        )
    return x


@dataclass
class Audio:
    """Samples (frames x channels) in their recorded format, and the rate in Hz.

    ``samples`` may be 1-D (one channel) or a list; it must hold numbers, and an array that is obviously
    (channels, samples) is refused (``audio_samples``). ``sample_rate`` must be a whole number of Hz
    (``whole_sample_rate``): each an ``InputError``."""

    samples: np.ndarray
    sample_rate: int
    subtype: str = "FLOAT"  # soundfile subtype used to store the samples: PCM_16, PCM_24, PCM_32, FLOAT

    def __post_init__(self) -> None:
        self.samples = audio_samples(self.samples)
        self.sample_rate = whole_sample_rate(self.sample_rate)

    @property
    def frames(self) -> int:
        return int(self.samples.shape[0])

    @property
    def channels(self) -> int:
        return int(self.samples.shape[1])

    @property
    def duration_s(self) -> float:
        return self.frames / self.sample_rate

    def pcm16(self) -> np.ndarray:
        """Samples as 16-bit PCM (frames x channels), as the app stores them in its ``.mov``."""
        x = self.samples
        if x.dtype == np.int16:
            return x
        if x.dtype == np.int32:
            return (x >> 16).astype(np.int16)
        return np.clip(np.rint(x.astype(np.float64) * 32768.0), -32768, 32767).astype(np.int16)

    def mono_float(self) -> np.ndarray:
        """Mono float32 samples in [-1, 1) (channels averaged)."""
        x = self.samples
        scale = _SCALE.get(x.dtype.name)
        y = x.astype(np.float32) / scale if scale else x.astype(np.float32)
        return y.mean(axis=1) if y.shape[1] > 1 else y[:, 0].copy()


def read_audio(path: str | Path, repairs: list[dict[str, Any]] | None = None) -> Audio:
    """Decode an audio file (or the audio track of a video) at its own rate and format.

    With ``repairs`` (a take's repair list), NaN or infinite float samples are set to 0 (repair
    ``bad_audio``), a WAV holding fewer samples than its header declares is noted (repair
    ``truncated_audio``) and one whose header declares none although samples follow is read to its end
    (repair ``unfinished_audio``); without it, non-finite samples and unfinished WAVs are an
    ``InputError``. AAC or MP3 whose file does not record the encoder's delay (raw ADTS ``.aac``, an MP3
    without a LAME tag) keeps it at its start: noted as repair ``encoder_delay_unknown``. An .mp3 of
    several files joined end to end (``cat a.mp3 b.mp3``) is read whole, each file without its own encoder
    delay and padding, the later ones mixed to the first one's channel count (repair
    ``channels_changed``); one whose sample rate changes is an ``InputError`` saying where. A later file
    without a LAME tag loses LAME's delay when it is LAME's output, else keeps its priming (noted:
    ``encoder_delay_unknown``), and its padding (noted when a file follows it: the sound after it may be
    up to a frame late). Frames lost at damage inside an .mp3 are put back as silence of their length, so
    the sound after it keeps its time (repair ``bad_audio``: where, how much, and, when their number is
    estimated, the most the sound after it may be shifted); damage running to its end (its last frames,
    into its end tags) leaves it short, noted (repair ``bad_audio``: by how much), and bytes after it in
    which frame headers of another format (rate, layer, channels) chain by chance (junk, a picture: no run
    of them ``_REAL_RUN_FRAMES`` frames long, nor after a tag or at an Info frame, nor beginning as an
    encoder's output does: ``_real_run``) are left out, said (``_junk_after``), and a file of such bytes
    alone is an ``InputError`` (``_refuse_no_mpeg_audio``); damage running to a file joined on is put back
    as inside (counted by the file's Info frame, or estimated when its bytes start as a frame does), else
    noted with the frames it could hold. An .mp3 whose Xing/Info frame counts fewer frames than it holds
    (libsndfile would stop at the count), or none though its LAME tag records the encoder's delay
    (libsndfile would keep the delay), is read whole, its count corrected (``MpegRun.count_low``), and one
    without a frame count whose length libsndfile estimates short (VBR without a Xing header) as joined
    files are; one libsndfile cannot open whose frames need mending too (``_read_mpeg_unopened``). A file
    starting with an ID3v2 tag over ``_BIG_TAG`` (a cover picture) is read from after it, by libsndfile and
    FFmpeg alike. Within ``audio_left_in_files`` (an import), audio libsndfile reads cleanly is a
    ``FileAudio``: checked a block at a time, left in its file; given a scratch folder there, audio FFmpeg
    decodes, and any .mp3, is a ``FileAudio`` of the scratch file it was decoded into, the same samples and
    repairs as read whole (``_read_mpeg``)."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder, not an audio file", path)
    if not path.exists():
        raise InputError("audio file not found", path)
    if not path.is_file():
        raise InputError("not a regular file (a device or a pipe?): give an audio file", path)
    try:
        with _libsndfile_source(path) as source:
            info = sf.info(source)
    except (sf.LibsndfileError, RuntimeError, TypeError):
        info = None
    if info is not None:
        if info.subtype.startswith("MPEG_LAYER"):
            return _read_mpeg(path, info, repairs)
        dtype = _NATIVE.get(info.subtype, "float32")
        subtype = info.subtype if info.subtype in _NATIVE else "FLOAT"
        audio = None
        if _LEFT_IN_FILES.get() is not None:
            audio = _left_in_file(path, info, dtype, subtype, repairs)
        if audio is None:
            audio, read = _read_whole(path, info, dtype, subtype, repairs)
            if not read:
                return audio
        rate = audio.sample_rate
        declared = wav_declared_frames(path)
        if repairs is not None and declared is not None and declared > audio.frames:
            repairs.append(
                {
                    "line": None,
                    "kind": "truncated_audio",
                    "message": f"{shown_name(path)}: header declares {declared / rate:.3f} s of audio, "
                    f"the file holds {audio.duration_s:.3f} s (cut short?): the samples present are used",
                }
            )
        return audio
    audio = _read_mpeg_unopened(path, repairs)
    if audio is not None:
        return audio
    return check_samples(decode_with_pyav(path, repairs=repairs), path, repairs)


def _read_whole(
    path: Path, info: Any, dtype: str, subtype: str, repairs: list[dict[str, Any]] | None
) -> tuple[Audio, bool]:
    """The audio libsndfile reads of ``path`` in one read (``dtype``, as ``subtype``), checked, and True;
    or what is read in its place (a file cut short, an unfinished WAV: its repairs noted), and False."""
    try:
        with _libsndfile_source(path) as source:
            data, rate = sf.read(source, dtype=dtype, always_2d=True)
    except (sf.LibsndfileError, RuntimeError) as exc:
        return _read_cut_short(path, info, exc, repairs), False
    if data.shape[0] == 0:
        return _read_unfinished_wav(path, repairs), False
    return check_samples(Audio(data, rate, subtype), path, repairs), True


def _read_mpeg(path: Path, info: Any, repairs: list[dict[str, Any]] | None) -> Audio:
    """``read_audio``'s audio of an MPEG audio file (.mp3): libsndfile's (``_read_by_libsndfile``), unless it
    would stop early: several files joined, a change of channels, a frame count too low, a length estimated
    short (``_estimated_short``), or its decoder ended its read at damage, short of the samples the frames
    code (``_MPG123_DROPS``; a frame with no frame count), its length is over twice theirs (a Xing/Info frame
    count of 2**32 - 1: libsndfile's read would ask for an array of that length, 9 TiB), or frames were lost
    at damage (``MpegRun.losses``: put back as silence, so the sound after it keeps its time), or bytes other
    than tags follow its last frame (damage at its end, zeros, junk: ``MpegLoss.ends``), or its first frame
    is a VBRI frame (mpg123 decodes it as a frame of silence): then decoded as
    joined files are (``_read_joined_mpeg``). Within ``audio_left_in_files`` given a scratch folder (an
    import), decoded a block at a time into a scratch file there (``_streamed``), the same samples and repairs
    as read whole. Its frames are found in the file read a block at a time (``_FileBytes``), not whole."""
    with _FileBytes.of(path) as data:  # not read whole: a 60 MB cover picture, an hour at 320 kbit/s
        free = _free_format_start(data)
        # free format: any frame the scan finds is a header's bytes inside its audio (it finds no real one)
        runs = [] if free is not None else mpeg_runs(data)
        if free is None:
            _refuse_no_mpeg_audio(path, data, runs)
        coded = sum(run.samples for run in runs)
        counts_wrong = bool(runs) and info.frames > 2 * coded
        skipped = _gapless_skip(data, runs[0]) if runs else 0
        drops = _MPG123_DROPS if skipped else 1152  # no frame count: mpg123 drops no delay nor padding
        if not (_mending_needed(data, runs) or counts_wrong or _estimated_short(info, coded, drops)):
            found: list[dict[str, Any]] | None = None if repairs is None else []
            audio = _read_by_libsndfile(
                path,
                info,
                skipped,
                found,
                free is not None and _untagged(data, free),
                _delay_dropped(data, runs, skipped),
            )
            if found is not None and free is not None:
                found += _free_format_damage(path, data, free)
            if audio.frames + drops >= coded:
                if repairs is not None and found:
                    repairs += found
                return audio
            if isinstance(audio, FileAudio):
                audio.discard()
            del audio  # its decoder stopped at damage (4655 of 129600 samples): FFmpeg's reads on
        return _read_joined_mpeg_checked(path, data, runs, repairs)


def _mending_needed(data: bytes | _FileBytes, runs: list[MpegRun]) -> bool:
    """Whether the .mp3 whose runs are ``runs`` is to be decoded as joined files are (``_read_joined_mpeg``),
    its frames mended, not read as it is: several files joined, or a change of channels or layer; damage,
    or bytes after its last frame (libsndfile's decoder gives up on 1 KB of zeros, said to be cut short:
    FFmpeg is given its frames only); a frame count too low; its first frame no sound (a VBRI frame, or a
    Xing/Info frame destroyed by damage)."""
    if not runs:
        return False
    lost = any(loss.frames or loss.ends for run in runs for loss in run.losses)
    return len(runs) > 1 or lost or any(run.count_low for run in runs) or _no_sound_first(data, runs[0])


def _read_mpeg_unopened(path: Path, repairs: list[dict[str, Any]] | None) -> Audio | None:
    """An .mp3 that libsndfile cannot open (its first frame of sound damaged after an Info frame, at 8 to
    24 kHz) and FFmpeg opens as MPEG audio, decoded as joined files are when its frames need mending
    (``_mending_needed``: frames lost at damage put back as silence, the sound after it on time), with
    the same repairs as one libsndfile opens; None when none do (or it is no MPEG audio, or in free
    format): ``decode_with_pyav`` decodes it, as any file libsndfile cannot open."""
    if _ffmpeg_format(path) != "mp3":
        return None
    with _FileBytes.of(path) as data:
        free = _free_format_start(data) is not None
        runs = [] if free else mpeg_runs(data)
        if not free:
            _refuse_no_mpeg_audio(path, data, runs)
        if _mending_needed(data, runs):
            return _read_joined_mpeg_checked(path, data, runs, repairs)
    return None


def _ffmpeg_format(path: Path) -> str | None:
    """The name of the container format FFmpeg finds ``path`` to be ("mp3": MPEG audio of any layer);
    None when it cannot open it."""
    import av

    try:
        with av.open(_ffmpeg_source(path)) as container:
            return container.format.name
    except (av.FFmpegError, OSError, ValueError):
        return None


def _read_joined_mpeg_checked(
    path: Path, data: bytes | _FileBytes, runs: list[MpegRun], repairs: list[dict[str, Any]] | None
) -> Audio:
    """``_read_joined_mpeg``'s audio, checked: into a scratch file within ``audio_left_in_files`` given a
    scratch folder (``_streamed``), else into memory."""
    scratch = _scratch_folder()
    if scratch is not None:
        audio = _streamed(
            path, repairs, scratch, lambda found, sink_of: _read_joined_mpeg(path, data, runs, found, sink_of)
        )
        if audio is not None:
            return check_samples(audio, path, repairs)
    return check_samples(_read_joined_mpeg(path, data, runs, repairs), path, repairs)


def _read_by_libsndfile(
    path: Path,
    info: Any,
    skipped: int,
    repairs: list[dict[str, Any]] | None,
    free_format: bool = False,
    delay_dropped: bool = False,
) -> Audio:
    """An .mp3 read by libsndfile: a block at a time into a scratch file within ``audio_left_in_files``
    given a scratch folder (``_mpeg_to_file``), else whole; the unrecorded encoder delay noted (also of
    ``free_format`` audio without a Xing/Info frame, ``_free_format_start`` and ``_untagged``, which FFmpeg
    cannot open to tell), unless its decoder dropped the delay a LAME tag records (``delay_dropped``,
    ``_delay_dropped``)."""
    audio: Audio | None = None
    scratch = _scratch_folder()
    if scratch is not None:
        audio = _streamed(
            path, repairs, scratch, lambda _found, sink_of: _mpeg_to_file(path, info, skipped, sink_of)
        )
    if audio is None:
        audio, read = _read_whole(path, info, "float32", "FLOAT", repairs)
        if not read:
            return audio
    else:
        audio = check_samples(audio, path, repairs)
    if repairs is not None and free_format:
        repairs.append(_unknown_delay_note(path, "mp3", info.samplerate))
    elif repairs is not None and not delay_dropped:  # mpg123 drops a recorded delay
        note_unknown_delay(path, repairs)
    return audio


# Bytes past a free-format header its next is looked for in: a frame of 640 kbit/s at 8 kHz is 5760.
_FREE_FORMAT_MAX = 8192


def _free_format_start(data: bytes | _FileBytes) -> int | None:
    """Where an .mp3 (``data``) in free format starts, its tags skipped: a layer III header of bit rate
    index 0 (no header says its frames' size: ``mpeg_runs`` finds none, only a header's bytes inside
    the audio by chance; FFmpeg cannot open it, libsndfile's mpg123 reads it), found again one frame on
    and two frames on (a frame a byte longer with padding). None when the data starts otherwise (or
    with damage that formed such a header: it is not found again)."""
    pos = 0
    while skip := _tag_bytes(data, pos):
        pos += skip
    head = data[pos : pos + 4]
    if (
        len(head) < 4
        or not _starts_sync(head, 0)
        or head[1] >> 1 & 3 != 1
        or head[2] >> 4
        or head[1] >> 3 & 3 == 1
        or head[2] >> 2 & 3 == 3
    ):
        return None  # not layer III (bits 01), a bit rate in the header, a reserved version or rate

    return pos if _free_frame_bytes(data, pos) else None


def _same_free_header(data: bytes | _FileBytes, head: bytes, at: int) -> bool:
    """Whether the free-format header ``head`` (its first 3 bytes) is at ``at`` too, its padding bit aside."""
    other = data[at : at + 3]
    return len(other) == 3 and other[:2] == head[:2] and other[2] | 2 == head[2] | 2


def _free_frame_bytes(data: bytes | _FileBytes, pos: int) -> int:
    """The bytes of a frame without padding of the free-format stream whose first header is at ``pos``:
    where its header is found again, and again a frame on (a byte more or less: padding); 0 when nowhere
    within ``_FREE_FORMAT_MAX``."""
    head = data[pos : pos + 3]
    at = pos + 4
    while (at := data.find(head[:2], at, pos + _FREE_FORMAT_MAX)) >= 0:
        size = at - pos  # a frame's size if a header starts there (padding: one byte more or less)
        if _same_free_header(data, head, at) and any(
            _same_free_header(data, head, at + size + d) for d in (-1, 0, 1)
        ):
            return size - (head[2] >> 1 & 1)
        at += 1
    return 0


def _free_format_damage(path: Path, data: bytes | _FileBytes, pos: int) -> list[dict[str, Any]]:
    """The repairs ``bad_audio`` of damage in the free-format stream whose first header is at ``pos``
    (``_free_format_start``): where its frames stop following one another (each the unpadded size
    ``_free_frame_bytes``, a byte more with padding) until a header of it that a frame follows, the frames
    lost there counted from the bytes between. mpg123 resyncs there without them and FFmpeg cannot decode
    free format to put them back as silence: the sound after it is early by them (600 bytes at 128 kbit/s
    and 48 kHz: 2 frames, 48 ms), said."""
    head, size, end = data[pos : pos + 3], _free_frame_bytes(data, pos), _end_tags_at(data)
    samples = 1152 if head[1] >> 3 & 3 == 3 else 576
    rate = _MPEG_RATES[head[1] >> 3 & 3][head[2] >> 2 & 3]

    def next_frame(i: int) -> int:  # where the frame after the one at ``i`` starts (a byte on: padding)
        return i + size + (data[i + 2] >> 1 & 1)

    notes, at, frames = [], pos, 0
    while at + 4 <= end:
        if _same_free_header(data, head, at):
            at, frames = next_frame(at), frames + 1
            continue
        found = data.find(head[:2], at + 1, end)
        while found >= 0 and not (
            _same_free_header(data, head, found) and _same_free_header(data, head, next_frame(found))
        ):
            found = data.find(head[:2], found + 1, end)
        if found < 0:  # to its end: no sound after it to be early
            break
        lost = round((found - at) / size)
        if lost:
            ms, seconds = 1000 * lost * samples / rate, frames * samples / rate
            message = (
                f"{shown_name(path)}: damaged MPEG audio at about {seconds:.3f} s: about {lost} frame(s) "
                f"lost there ({ms:.0f} ms); free format, which FFmpeg cannot decode to put them back as "
                "silence: the sound after it is that much early"
            )
            notes.append({"line": None, "kind": "bad_audio", "message": message})
        at = found
    return notes


def _untagged(data: bytes | _FileBytes, pos: int) -> bool:
    """Whether the layer III frame at ``pos`` (a free-format stream's first, ``_free_format_start``) is
    no Xing/Info frame: no LAME tag records the encoder's delay, which libsndfile's decoder keeps (LAME's
    output 1105 samples late)."""
    head = data[pos : pos + 4]
    side = (32, 17) if head[1] >> 3 & 3 == 3 else (17, 9)  # MPEG-1, else MPEG-2 and 2.5: stereo, mono
    text_at = pos + 4 + (0 if head[1] & 1 else 2) + side[_mpeg_channels(data, pos) == 1]
    return not data.startswith(_XING_TEXTS, text_at)


def _mpeg_to_file(path: Path, info: Any, skipped: int, sink_of: _SinkOf) -> FileAudio:
    """An .mp3 libsndfile reads (one file, its frame count right) read a block at a time into a scratch
    file (``sink_of`` makes it), the same samples as its whole read: after a seek to the start as
    ``sf.read`` does, each read ending where a decoded frame does (``skipped``: the samples the decoder
    drops at the start, ``_gapless_skip``). libsndfile's decoder (mpg123) gives samples up to 1 ulp apart
    after a read that ends within a frame, or without the seek. ``_NotStreamed`` when it does not read it
    to its end without an error (``_read_cut_short`` says what is wrong, from the whole read), it holds no
    samples or it was replaced since ``info``."""
    sink = sink_of(lambda: info.samplerate)
    size = _MPEG_BLOCK - skipped % _MPEG_BLOCK
    try:
        with _libsndfile_source(path) as source, sf.SoundFile(source) as f:
            if not _opened_as(f, info):
                raise _NotStreamed
            f.seek(0)
            while len(block := f.read(size, dtype="float32", always_2d=True)):
                sink.append(block)
                if len(block) < size:  # its end, or an error it resyncs after: the whole read ends there
                    break
                size = _MPEG_BLOCK
    except (sf.LibsndfileError, RuntimeError):
        raise _NotStreamed from None
    if not sink.used:
        raise _NotStreamed
    return sink.finish(None, info.samplerate, "flt")


# Frames of an .mp3 read at once: a whole number of MPEG frames of every layer (384 or 1152 samples, 576
# for layer III below 32 kHz)
_MPEG_BLOCK = 1152 * 64

# What mpg123 drops at the start of a file whose LAME tag records the encoder's delay, besides that delay:
# its synthesis filter bank's (as FFmpeg's 528 + 1)
_MPG123_GAPLESS_DELAY = 529


# The most samples mpg123 leaves out of those an .mp3's frames code: its own delay, the header frame's and
# the encoder's delay and padding a LAME tag records (12 bits each)
_MPG123_DROPS = _MPG123_GAPLESS_DELAY + 1152 + 2 * 4095


def _estimated_short(info: Any, coded: int, drops: int) -> bool:
    """Whether libsndfile's length of an .mp3 (``info.frames``: mpg123's estimate from the first frame's
    bit rate when no header frame counts its frames) falls short of the samples its frames code by more
    than mpg123 ``drops`` (``_MPG123_DROPS`` when a header counts its frames, else a frame: 8869 of 17856
    samples of a 1.6 s VBR file at 11 kHz were read, unnoted, within ``_MPG123_DROPS``): a VBR file without
    a Xing header, or files of other bit rates joined without a tag between them. libsndfile reads no
    further than its length (a loud start at 192 kbit/s then silence: 1.2 s of 6.5 s read)."""
    return info.frames + drops < coded


def _gapless_skip(data: bytes | _FileBytes, run: MpegRun, counted: bool = False) -> int:
    """The samples libsndfile's decoder (mpg123) drops at the start of the file whose first run is
    ``run``: when its Xing/Info frame declares a frame count (else none; ``counted``: as if it did, its
    count set right, ``_counted_whole``), the decoder's own delay and the encoder's that a LAME tag after
    it records."""
    frame = _mpeg_frame(data, run.start)
    if (
        frame is None
        or not _is_file_header(data, run.start, frame)
        or data.startswith(b"VBRI", run.start + 36)
    ):
        return 0
    if not (counted or _file_header_frames(data, run.start, frame)):  # it checks the flag of a frame count
        return 0
    lame = _lame_tag_at(data, run.start, frame)
    if not lame:
        return _MPG123_GAPLESS_DELAY
    return _MPG123_GAPLESS_DELAY + (data[lame + 21] << 4 | data[lame + 22] >> 4)


def _dropped_at_start(data: bytes | _FileBytes, run: MpegRun, counted: bool = False) -> int:
    """The samples of the file whose first run is ``run`` that FFmpeg does not decode as sound: its header
    frame's and the encoder's delay (``_gapless_skip``); a VBRI frame's or a destroyed header frame's (the
    encoder's delay kept: ``_no_sound_first``)."""
    skip = _gapless_skip(data, run, counted)
    if skip:
        return skip + run.frame_samples
    return run.frame_samples if _no_sound_first(data, run) else 0


def _no_sound_first(data: bytes | _FileBytes, run: MpegRun) -> bool:
    """Whether the file whose first run is ``run`` begins with a frame of no sound that ``_mended`` leaves
    out of what FFmpeg is given: a VBRI frame (``_begins_with_vbri``) or a header frame destroyed by damage
    (``_header_destroyed``)."""
    return _begins_with_vbri(data, run) or _header_destroyed(data, run)


def _header_destroyed(data: bytes | _FileBytes, run: MpegRun) -> bool:
    """Whether the file whose first run is ``run`` begins with a layer III frame that is no Xing/Info nor
    VBRI frame, yet no file's first frame of sound: all zeros after its header (no sound, nor the
    ancillary bytes an encoder fills its frames with: LAME's "LAME3.100UUU...") or its sound begun in bytes
    before it (``main_data_begin``: a file's first frame has none before it) with side information no frame
    of sound has (``_holds_sound``: a file cut from a longer one may begin with a whole frame of sound whose
    reservoir bytes were cut off, kept: left out, the sound after it would be a frame early), and the frame
    after it begins its sound in its own bytes as an encoder's first frame of sound does: the file's
    Xing/Info frame, its text and LAME tag destroyed by damage. FFmpeg decoded it as a frame of sound and
    kept the encoder's delay its LAME tag recorded: the sound a frame and the delay late (2257 samples at
    44.1 kHz)."""
    frame = _mpeg_frame(data, run.start)
    if frame is None or frame[3] != 3 or _is_file_header(data, run.start, frame):
        return False
    after = run.start + frame[0]
    first = _mpeg_frame(data, after) if after < run.end else None
    return (
        first is not None
        and _starts_reservoir(data, after, first)
        and (
            not any(data[run.start + 4 : after])
            or not (_starts_reservoir(data, run.start, frame) or _holds_sound(data, run.start, frame))
        )
    )


def _holds_sound(data: bytes | _FileBytes, pos: int, frame: _MpegFrame) -> bool:
    """Whether the layer III frame at ``pos`` has side information a frame of sound has: each granule's
    ``big_values`` at most 288 (pairs of its 576 lines), a block type when its window is switched, and its
    bits of sound (``part2_3_length``) within the reservoir bytes before it (``main_data_begin``) and its own
    bytes after it. A frame that begins a file cut from a longer one has (its reservoir bytes cut off, its
    next frame's sound in the next frame's bytes); garbled bytes seldom do."""
    mpeg1 = frame[1] == 1152
    channels = _mpeg_channels(data, pos)
    side = pos + frame[6]
    size = _xing_at(data, pos, frame) - side  # the side information's bytes
    if side + size > len(data):
        return True
    bits, total = int.from_bytes(data[side : side + size], "big"), 8 * size

    def field(at: int, width: int) -> int:
        return bits >> (total - at - width) & ((1 << width) - 1)

    reservoir = field(0, 9 if mpeg1 else 8)
    at = 9 + (5 if channels == 1 else 3) + 4 * channels if mpeg1 else 8 + channels  # after the private bits
    coded = 0
    for _ in range((2 if mpeg1 else 1) * channels):  # each granule's each channel
        coded += field(at, 12)
        switched = at + 33 if mpeg1 else at + 38  # after part2_3_length, big_values, gain, scalefac_compress
        if field(at + 12, 9) > 288 or field(switched, 1) and not field(switched + 1, 2):
            return False
        at += 59 if mpeg1 else 63
    return coded <= 8 * (reservoir + frame[0] - frame[6] - size)


def _begins_with_vbri(data: bytes | _FileBytes, run: MpegRun) -> bool:
    """Whether the file whose first run is ``run`` begins with a VBRI frame (Fraunhofer's encoders): mpg123
    (libsndfile) decodes it as a frame of silence, and FFmpeg too when it declares no frame nor byte
    count; ``_mended`` leaves it out of what FFmpeg is given."""
    frame = _mpeg_frame(data, run.start)
    return (
        frame is not None
        and not data[run.start + frame[6]]  # no sound (``_begins_file``, the frame parsed once)
        and data.startswith(b"VBRI", run.start + 36)
    )


def _lame_tag_at(data: bytes | _FileBytes, pos: int, frame: _MpegFrame) -> int:
    """Where the LAME tag after the Xing/Info header of the frame at ``pos`` starts (its encoder's version,
    then at 21 its delay and padding, 12 bits each); 0 when the frame holds none."""
    text_at = _xing_at(data, pos, frame)
    flags = data[text_at + 7] if text_at + 8 <= len(data) else 0
    lame = (
        text_at + 8 + 4 * (flags & 1) + 4 * (flags >> 1 & 1) + 100 * (flags >> 2 & 1) + 4 * (flags >> 3 & 1)
    )
    return 0 if lame + 24 > min(pos + frame[0], len(data)) or not data[lame] else lame


def _gapless_tag(data: bytes | _FileBytes, pos: int, frame: _MpegFrame) -> bool:
    """Whether the Xing/Info frame at ``pos`` holds a LAME tag recording the encoder's delay and padding that
    FFmpeg drops (its encoder one of ``_GAPLESS_ENCODERS``)."""
    lame = _lame_tag_at(data, pos, frame)
    return bool(lame) and data.startswith(_GAPLESS_ENCODERS, lame)


def _uncounted_gapless(data: bytes | _FileBytes, pos: int, frame: _MpegFrame) -> bool:
    """Whether the Xing/Info frame at ``pos`` declares no frame count (0, or no field for it), though the
    LAME tag after it records the encoder's delay and padding: without a count, libsndfile's decoder keeps
    both (the sound 1105 samples late, 25 ms at 44.1 kHz, unnoted: FFmpeg finds the delay recorded)."""
    if data.startswith(b"VBRI", pos + 36) or _file_header_frames(data, pos, frame):
        return False
    return _gapless_tag(data, pos, frame)


def _delay_dropped(data: bytes | _FileBytes, runs: list[MpegRun], skipped: int) -> bool:
    """Whether libsndfile's decoder drops the encoder's delay of the .mp3 whose runs are ``runs``: its
    Xing/Info frame declares its frame count (``skipped``, what ``_gapless_skip`` found it drops, not 0) and
    its LAME tag records the delay. FFmpeg, asked by ``note_unknown_delay``, finds the tag only where the
    audio starts: after zeros a tagger padded its ID3v2 tag with (past the size the tag declares) it said
    the delay unknown, though it was dropped."""
    if not skipped:  # also no runs, or no frame at the first's start
        return False
    frame = _mpeg_frame(data, runs[0].start)
    return frame is not None and _gapless_tag(data, runs[0].start, frame)


def _read_cut_short(path: Path, info: Any, exc: Exception, repairs: list[dict[str, Any]] | None) -> Audio:
    """A file libsndfile stops reading partway (a FLAC cut short: "lost sync"): an ``InputError``, unless
    ``repairs`` is given and FFmpeg decodes samples of it: then those are used (the cut packet, which
    FFmpeg cannot decode, as silence of its length) and the repair ``truncated_audio`` says how much of
    the length its header declares is there (as for a WAV cut short, which libsndfile reads to its end)."""
    unreadable = InputError(f"audio is unreadable: {exc}", path)
    if repairs is None:
        raise unreadable from None
    found: list[dict[str, Any]] = []
    try:
        audio = decode_with_pyav(path, repairs=found, skip_damaged=True)
    except InputError:
        raise unreadable from None
    if audio.frames == 0:
        raise unreadable from None
    repairs += found
    repairs.append(
        {
            "line": None,
            "kind": "truncated_audio",
            "message": f"{shown_name(path)}: header declares {info.frames / info.samplerate:.3f} s of audio, "
            f"the file holds {audio.duration_s:.3f} s ({exc}; cut short?): the samples present are used, "
            "the packet cut through as silence",
        }
    )
    return check_samples(audio, path, repairs)


def _read_unfinished_wav(path: Path, repairs: list[dict[str, Any]] | None) -> Audio:
    """A WAV whose header declares no samples: an error, unless samples follow the header (a recorder
    that crashed before it wrote the sizes) and ``repairs`` is given: then they are read (FFmpeg reads
    to the end of the file) and the repair ``unfinished_audio`` says so."""
    extra = wav_unfinished_bytes(path)
    if not extra:
        raise InputError("audio file holds no samples", path)
    if repairs is None:
        raise InputError(
            f"the WAV header declares no samples, but {extra} bytes follow it (a recording that was not "
            "finished?)",
            path,
        )
    audio = check_samples(decode_with_pyav(path), path, repairs)
    repairs.append(
        {
            "line": None,
            "kind": "unfinished_audio",
            "message": f"{shown_name(path)}: the WAV header declares no samples (a recorder that did not "
            f"finish the file?): the {audio.duration_s:.3f} s of samples after it are used",
        }
    )
    return audio


class _Scratch:
    """Where an import's decoded audio waits until its take is written: WAV files in a hidden folder made
    in ``folder`` when the first one is, removed with them. None: decoded audio is held whole."""

    def __init__(self, folder: Path | None, prefix: str):
        self.folder, self.prefix = folder, prefix
        self._made: Path | None = None
        self._count = 0
        self._told = False  # that a scratch file was refused

    def refused(self, why: _ScratchRefused) -> None:
        """Say on stderr, once, that the system refused a scratch file (``why``): the audio it was for is
        decoded in memory instead, and the import goes on (a disk too full for it fails at the take's
        own write, which says so)."""
        if not self._told:
            self._told = True
            warn(f"{why}: decoded in memory instead (an hour of 48 kHz stereo takes 1.4 GB)")

    def new_file(self) -> Path:
        assert self.folder is not None
        if self._made is None:
            with stops_deferred():  # met between its making and its noting, a stop would leave the folder
                self._made = Path(tempfile.mkdtemp(prefix=self.prefix, dir=self.folder))
        self._count += 1
        return self._made / f"decoded-{self._count}.wav"

    def remove(self) -> None:
        if self._made is not None:
            shutil.rmtree(self._made, ignore_errors=True)
            self._made = None


# Where read_audio leaves what it decodes, when it leaves a cleanly read file's samples in it
# (``audio_left_in_files``); None: it holds every file's samples whole.
_LEFT_IN_FILES: ContextVar[_Scratch | None] = ContextVar("_LEFT_IN_FILES", default=None)


def _scratch_folder() -> _Scratch | None:
    """Where decoded audio goes a block at a time: the ``_Scratch`` of ``audio_left_in_files`` given a
    scratch folder (an import); None: it is held whole."""
    scratch = _LEFT_IN_FILES.get()
    return scratch if scratch is not None and scratch.folder is not None else None


@contextmanager
def audio_left_in_files(scratch: str | Path | None = None, prefix: str = ".s2a-decoded-") -> Iterator[None]:
    """Within it, ``read_audio`` gives the audio of a file libsndfile reads to its end without an error
    (WAV, FLAC, AIFF, OGG; not MP3) as a ``FileAudio``: its samples are checked a block at a time and
    left in the file, for ``write_audio`` to copy a block at a time (an import holds no take's recorded
    audio whole: 317 MB an hour at 44.1 kHz int16 mono). Given a ``scratch`` folder (an import's output
    folder), audio FFmpeg decodes (``decode_with_pyav``: a .mov's AAC, an .m4a) and MP3 (``_read_mpeg``)
    is decoded a block at a time into a scratch WAV, in a hidden folder made there whose name starts with
    ``prefix``, and given as a ``FileAudio`` of it (an import of an hour of 48 kHz stereo AAC peaked at
    1.4 GB, now 117 MB; of 45 min of 44.1 kHz stereo MP3 at 1.0 GB, now 129 MB); a scratch file the
    system refuses (a full disk) is said on stderr, once, and the audio held whole instead; that
    folder is removed when the block ends, however it ends, so such audio must be written within it (read
    after it, it is an ``InputError``). Without one it is held whole: audio read here and used after the
    block (``listen --audio-file`` plays it later) stays readable. Float samples past full scale (of a
    file, or decoded), which ``check_samples`` may repair, are looked at in passes over the file
    (``_damaged_in_file``)."""
    left = _Scratch(None if scratch is None else Path(scratch), prefix)
    token = _LEFT_IN_FILES.set(left)
    try:
        yield
    finally:
        with stops_deferred():  # Ctrl-C, a second one too, cuts no removal short
            _LEFT_IN_FILES.reset(token)
            left.remove()


# An ID3v2 tag at the start of an MPEG audio file larger than this (a cover picture) is not shown to
# libsndfile: its decoder (mpg123) reads the whole tag into memory, on each open (a 60 MB picture: 61 MB)
_BIG_TAG = 1 << 20


def _big_tag(path: Path) -> int:
    """The bytes of the ID3v2 tag ``path`` starts with when over ``_BIG_TAG`` (a cover picture), else 0
    (also when it cannot be read: the decoder says so)."""
    try:
        with open(path, "rb") as f:
            size = _tag_bytes(f.read(10), 0)
    except OSError:
        return 0
    return size if size > _BIG_TAG else 0


@contextmanager
def _libsndfile_source(path: Path) -> Iterator[bytes | IO[bytes]]:
    """What libsndfile is to open of ``path``: its name (``libsndfile_name``); for an .mp3 starting with
    a tag over ``_BIG_TAG`` (``_big_tag``), the file from its first frame on (``_AfterTag``)."""
    view = None
    if skip := _big_tag(path):
        try:
            view = _AfterTag(open(path, "rb"), skip)  # noqa: SIM115
        except OSError:  # unreadable: libsndfile says so
            pass
    if view is not None and (not _mpeg_frame_table() or _mpeg_frame(view.read(4), 0) is None):
        view.close()  # no MPEG audio after it: libsndfile reads the file as it is
        view = None
    if view is None:
        yield libsndfile_name(path)
        return
    view.seek(0)
    with view:
        yield view


def shown_name(path: Path) -> str:
    """``path``'s name as a message shows it (``caf\\xe9.mp3``: see ``printable``)."""
    return printable(path.name)


def libsndfile_name(path: Path) -> bytes:
    """``path`` as libsndfile is to open it: its bytes (soundfile encodes a name given as text to UTF-8,
    which fails on a name that is not UTF-8, held by Python as surrogate escapes)."""
    return os.fsencode(path)


def ffmpeg_name(path: str | Path) -> str:
    """``path`` as FFmpeg (PyAV) is to open or write it: absolute, for its ``file`` protocol (a relative name
    with a colon, "take:1.mov", or a hidden ".take:1.mp4.partial.mp4", FFmpeg reads as another
    protocol's: "Protocol not found")."""
    return f"file:{Path(path).absolute()}"


def _ffmpeg_source(path: Path) -> str:
    """What FFmpeg is to open of ``path``: the file, named for FFmpeg's ``file`` protocol (a plain name
    with a colon, "take:1.aac", FFmpeg takes for another protocol's: "Protocol not found"); for a file
    starting with an ID3v2 tag over ``_BIG_TAG``, the file from after the tag on (its ``subfile``
    protocol, which reads its options up to ",,", then the file's name as it is): FFmpeg reads a picture
    in a tag whole (a 48 MB cover: 50 MB more, in an .mp3's check of its encoder delay or a raw .aac's
    decoding)."""
    name = ffmpeg_name(path)
    skip = _big_tag(path)
    return f"subfile,,start,{skip},end,0,,:{name}" if skip else name


class _AfterTag(io.RawIOBase):
    """A file read from ``start`` on, as if its bytes began there."""

    def __init__(self, file: IO[bytes], start: int):
        super().__init__()
        self.file, self.start = file, start
        file.seek(start)

    def close(self) -> None:
        self.file.close()
        super().close()

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        return self.file.readinto(buffer)  # type: ignore[attr-defined]

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        return self.file.seek(offset + self.start if whence == io.SEEK_SET else offset, whence) - self.start

    def tell(self) -> int:
        return self.file.tell() - self.start


def _opened_as(f: sf.SoundFile, info: Any) -> bool:
    """Whether ``f`` opened with the rate, channel count and subtype of ``info`` (not replaced since)."""
    return (f.samplerate, f.channels, f.subtype) == (info.samplerate, info.channels, info.subtype)


def _file_blocks(path: Path, dtype: str, size: int, info: Any = None) -> Iterator[np.ndarray]:
    """The samples of a file libsndfile reads, ``size`` frames (frames x channels) at a time; nothing
    when the file opens with another rate, channel count or subtype than ``info`` (replaced since)."""
    with sf.SoundFile(libsndfile_name(path)) as f:
        if info is not None and not _opened_as(f, info):
            return
        while len(block := f.read(size, dtype=dtype, always_2d=True)):
            yield block


# Float subtypes whose samples libsndfile seeks to exactly (a seek into Vorbis or Opus lands up to a few
# hundred samples off): those whose damaged samples ``_damaged_in_file`` may look for in passes.
_SEEKS_TO_THE_SAMPLE = ("FLOAT", "DOUBLE")


def _left_in_file(
    path: Path, info: Any, dtype: str, subtype: str, repairs: list[dict[str, Any]] | None
) -> FileAudio | None:
    """``read_audio``'s audio of a file libsndfile reads, checked a block at a time and left in the file
    (NaN or infinite float samples counted, set to 0 when it is copied; the CRC-32s of the samples so
    checked kept, to tell the file changed), then float samples given to ``check_samples``, which notes
    them and looks for damaged samples past full scale in passes over the file; None when reading it
    whole decides more: an error of libsndfile (a file cut short), no samples, NaN without ``repairs``
    (an ``InputError``), samples past full scale to repair in a file libsndfile cannot seek to the
    sample (Vorbis, Opus: the passes read the samples around each candidate where they lie)."""
    frames, bad, peak, crcs = 0, 0, 0.0, _BlockCrcs()
    try:
        for block in _file_blocks(path, dtype, CHECK_FRAMES, info):
            frames += len(block)
            if block.dtype.kind == "f":
                bad += _non_finite_zeroed(block)
                peak = max(peak, float(block.max()), -float(block.min()))
            crcs.add(block)
    except (sf.LibsndfileError, RuntimeError):
        return None
    if frames == 0 or (bad and repairs is None):
        return None
    if peak > 1.0 and repairs is not None and info.subtype not in _SEEKS_TO_THE_SAMPLE:
        return None
    kept = np.dtype(dtype)
    if kept.kind != "f":
        return FileAudio(path, info.samplerate, subtype, kept, frames, info.channels, crcs.done())
    audio = FileAudio(
        path, info.samplerate, subtype, kept, frames, info.channels, crcs.done(), non_finite=bad, peak=peak
    )
    return check_samples(audio, path, repairs)


class _BlockCrcs:
    """The CRC-32s of samples (frames x channels) given in blocks of any size, one per ``CHECK_FRAMES``
    frames (the last of fewer): what ``FileAudio`` keeps of the samples it checked (an hour of 48 kHz
    audio: 2637 of them), to tell each of its blocks read again."""

    def __init__(self) -> None:
        self._crcs: list[int] = []
        self._crc, self._frames = 0, 0  # of the block being filled

    def add(self, samples: np.ndarray) -> None:
        while len(samples):
            part = samples[: CHECK_FRAMES - self._frames]
            self._crc = zlib.crc32(np.ascontiguousarray(part), self._crc)
            self._frames += len(part)
            samples = samples[len(part) :]
            if self._frames == CHECK_FRAMES:
                self._crcs.append(self._crc)
                self._crc, self._frames = 0, 0

    def done(self) -> np.ndarray:
        """The CRC-32s, the block filled last included."""
        return np.array(self._crcs + ([self._crc] if self._frames else []), np.uint32)


class FileAudio(Audio):
    """Audio left in its file (``audio_left_in_files``), read a block at a time when it is written
    (``write_audio``) and read whole only when ``samples`` is asked for. Float samples that are NaN or
    infinite are read as 0 (``read_audio``'s repair). A file whose samples changed since they were read
    (their count or the CRC-32 of a block of them, ``crcs``: also a file rewritten in place to the same
    size and modification time) or that was removed is an ``InputError`` once the changed block is read
    again, before any of its samples is given: the audio is never other than the one checked. A file only
    touched, or replaced by a copy of the same samples, is read as it was.

    ``shown``: the file to name instead of ``path`` (the source of audio decoded into a scratch file).
    ``non_finite``: the NaN or infinite float samples found when it was checked (read as 0), and
    ``peak`` the largest magnitude of the others (None: not known), for ``check_samples`` and
    ``finite_peak`` to tell without reading the file whole."""

    def __init__(
        self,
        path: Path,
        sample_rate: int,
        subtype: str,
        dtype: np.dtype,
        frames: int,
        channels: int,
        crcs: np.ndarray,
        *,
        shown: Path | None = None,
        non_finite: int = 0,
        peak: float | None = None,
    ):
        self.path, self.dtype = path if shown is None else shown, dtype  # as given, to name it
        self._read_from = path.absolute()  # where it is, whatever the working folder is later
        self.sample_rate, self.subtype = whole_sample_rate(sample_rate), subtype
        # as read_audio found them: the CRC-32 of each CHECK_FRAMES frames (``_BlockCrcs``)
        self._frames, self._channels, self._crcs = frames, channels, crcs
        self.non_finite, self.peak = non_finite, peak
        self._scratch = shown is not None  # a scratch file of decoded audio (``_DecodedToFile``), ours
        self._held: np.ndarray | None = None
        # samples set right (frame, channel, value), sorted by frame: applied as blocks are read
        self._mend_at, self._mend_channel = np.zeros(0, np.int64), np.zeros(0, np.int64)
        self._mend_value = np.zeros(0, dtype)

    def __repr__(self) -> str:
        """The file and its layout: never the samples (``Audio``'s would read them all, and a file
        changed or removed since would make repr an error)."""
        held = ", held" if self.held else ""
        return (
            f"FileAudio({str(self.path)!r}, {self.frames} frames, {self.channels} channel(s), "
            f"{self.sample_rate} Hz, {self.subtype}{held})"
        )

    @property
    def held(self) -> bool:
        """Whether the samples were read into memory (asked for, or set)."""
        return self._held is not None

    @property
    def samples(self) -> np.ndarray:  # type: ignore[override]
        if self._held is None:
            held = np.empty((self._frames, self._channels), self.dtype)
            at = 0
            for block in self.blocks(CHECK_FRAMES):
                held[at : at + len(block)] = block
                at += len(block)
            self._held = held
        return self._held

    @samples.setter
    def samples(self, value: Any) -> None:
        self._held = audio_samples(value)

    @property
    def frames(self) -> int:
        return self._frames if self._held is None else int(self._held.shape[0])

    @property
    def channels(self) -> int:
        return self._channels if self._held is None else int(self._held.shape[1])

    @property
    def nbytes(self) -> int:
        """The size of the samples in memory, read whole."""
        return self.frames * self.channels * self.dtype.itemsize

    def discard(self) -> None:
        """Audio decoded into a scratch file that will not be used (a .mov's other tracks): the file removed
        now, not when the import ends (an hour of 48 kHz stereo: 1.4 GB); read after, it is an
        ``InputError``. A file of the user's is never removed."""
        if self._scratch:
            self._read_from.unlink(missing_ok=True)

    def mend(self, frames: np.ndarray, channel: int, values: np.ndarray) -> None:
        """Set the samples at ``frames`` of ``channel`` to ``values`` (damaged samples set right) as they
        are read: the file is left as it was checked."""
        at = np.concatenate([self._mend_at, frames])
        order = np.argsort(at, kind="stable")
        self._mend_at = at[order]
        self._mend_channel = np.concatenate([self._mend_channel, np.full(len(frames), channel)])[order]
        self._mend_value = np.concatenate([self._mend_value, values.astype(self.dtype)])[order]

    def _mended(self, block: np.ndarray, start: int) -> None:
        """The mends of the frames of ``block`` (from frame ``start``) applied to it."""
        lo, hi = np.searchsorted(self._mend_at, [start, start + len(block)])
        if hi > lo:
            block[self._mend_at[lo:hi] - start, self._mend_channel[lo:hi]] = self._mend_value[lo:hi]

    def blocks(self, size: int) -> Iterator[np.ndarray]:
        """The samples, ``size`` frames at a time (the last block fewer), as ``read_audio`` checked them
        (NaN set to 0). The file changed since is told at its first changed block (``_checked_blocks``),
        after every sample before it is given (a block of fewer frames then), never one of the new."""
        waiting: list[np.ndarray] = []  # checked, fewer than ``size`` frames in all: joined once
        count = 0
        try:
            for block in self._checked_blocks():
                waiting.append(block)
                count += len(block)
                if count < size:
                    continue
                joined = waiting[0] if len(waiting) == 1 else np.concatenate(waiting)
                whole = count - count % size
                for at in range(0, whole, size):
                    yield joined[at : at + size]
                waiting, count = ([joined[whole:]], count - whole) if count > whole else ([], 0)
        except InputError:
            if count:
                yield np.concatenate(waiting)
            raise
        if count:
            yield np.concatenate(waiting)

    def _checked_blocks(self) -> Iterator[np.ndarray]:
        """The samples, ``CHECK_FRAMES`` frames at a time, each compared with the CRC-32 kept of it before
        it is given: a file rewritten in place, cut short, grown or removed since it was checked is an
        ``InputError`` at its first block that differs, naming the time from which it does."""
        frames, same = 0, True
        try:
            with open(self._read_from, "rb"):  # removed, or unreadable: the system's own words
                pass
            for i, block in enumerate(_file_blocks(self._read_from, self.dtype.name, CHECK_FRAMES)):
                if block.dtype.kind == "f":
                    block[~np.isfinite(block)] = 0.0
                same = (
                    i < len(self._crcs)
                    and block.shape[1] == self._channels
                    and zlib.crc32(block) == self._crcs[i]
                )
                if not same:
                    break
                self._mended(block, frames)
                frames += len(block)
                yield block
        except OSError as exc:
            raise InputError(f"audio file cannot be read again: {exc.strerror or exc}", self.path) from None
        except (sf.LibsndfileError, RuntimeError) as exc:
            raise InputError(f"audio file cannot be read again: {exc}", self.path) from None
        if not same or frames != self._frames:
            raise InputError(
                "audio file changed since it was read (its samples differ from "
                f"{frames / self.sample_rate:.1f} s on): run the command again",
                self.path,
            )


def _non_finite_note(path: Path, count: int) -> dict[str, Any]:
    """The repair ``bad_audio`` of ``count`` NaN or infinite samples set to 0."""
    return {
        "line": None,
        "kind": "bad_audio",
        "message": f"{shown_name(path)}: {count} NaN or infinite samples set to 0",
    }


CHECK_FRAMES = 1 << 16  # frames of float audio checked for NaN at once


def _non_finite_zeroed(block: np.ndarray, zero: bool = True) -> int:
    """How many samples of the float ``block`` are NaN or infinite; set to 0 in place when ``zero``."""
    finite = np.isfinite(block)
    if finite.all():
        return 0
    if zero:
        block[~finite] = 0.0
    return int(finite.size - np.count_nonzero(finite))


def check_samples(audio: Audio, path: Path, repairs: list[dict[str, Any]] | None) -> Audio:
    """Damaged float samples, set right and recorded in ``repairs`` (repair ``bad_audio``): NaN or
    infinite samples are set to 0 (without ``repairs``: an ``InputError``), and isolated samples far past
    full scale (``damaged_samples``) are replaced by the interpolation of their neighbours (without
    ``repairs`` they are left as they are). A ``FileAudio`` checked as it was written to its file is
    told by what that check found, its float32 samples past full scale looked at in passes over the file
    (``_damaged_in_file``): it is never read whole here."""
    if isinstance(audio, FileAudio) and not audio.held and audio.peak is not None:
        if audio.dtype.kind != "f":
            return audio
        count = audio.non_finite  # read as 0
        past_full_scale = audio.peak > 1.0
    else:
        if audio.samples.dtype.kind != "f":
            return audio
        count = 0
        for lo in range(0, audio.frames, CHECK_FRAMES):  # a block at a time: no mask of all the samples
            count += _non_finite_zeroed(audio.samples[lo : lo + CHECK_FRAMES], zero=repairs is not None)
        past_full_scale = True  # damaged_samples tells
    if count:
        if repairs is None:
            raise InputError(f"audio holds {count} NaN or infinite sample(s)", path)
        repairs.append(_non_finite_note(path, count))
    if repairs is None or not past_full_scale:
        return audio
    if isinstance(audio, FileAudio) and not audio.held and audio.dtype == np.float32:
        found, worst = _damaged_in_file(audio)  # in passes over the file, not on whole channels
    else:
        found, worst = 0, 0.0
        for c in range(audio.channels):
            x = audio.samples[:, c]
            spikes = damaged_samples(x)
            if spikes.size:
                found += int(spikes.size)
                worst = max(worst, float(np.max(np.abs(x[spikes]))))
                good = np.ones(x.size, bool)
                good[spikes] = False
                keep = np.flatnonzero(good)
                x[spikes] = np.interp(spikes, keep, x[keep]).astype(x.dtype)
    if found:
        repairs.append(
            {
                "line": None,
                "kind": "bad_audio",
                "message": f"{shown_name(path)}: {found} isolated sample(s) up to {worst:.3g}, past full "
                f"scale and over {SPIKE_FACTOR:g} times the signal around them (damaged), replaced by the "
                "interpolation of their neighbours",
            }
        )
    return audio


def finite_peak(audio: Audio) -> float:
    """The largest magnitude of ``audio``'s finite samples, full scale 1 whatever the sample format (0
    for silence); of a ``FileAudio``, the one found when it was checked, when known."""
    if isinstance(audio, FileAudio) and not audio.held and audio.peak is not None:
        return audio.peak / _SCALE.get(audio.dtype.name, 1.0)
    x = audio.samples
    if x.dtype.kind != "f":  # Python ints: -(-32768) does not wrap
        return (max(int(x.max()), -int(x.min())) if x.size else 0) / full_scale(x)
    peak = 0.0
    for lo in range(0, len(x), CHECK_FRAMES):  # a block at a time: no mask or copy of all the samples
        block = x[lo : lo + CHECK_FRAMES]
        finite = block[np.isfinite(block)]
        if finite.size:
            peak = max(peak, float(finite.max()), -float(finite.min()))
    return peak / full_scale(x)


# A damaged float sample: past full scale, and over SPIKE_FACTOR times both the take's level (its 99.9th
# percentile of |x|; speech peaks at 1.3-2.0 times it in every real sample) and every sample 4 to 32
# samples away (a band-limited sound, even a click, spreads over its neighbours; a flipped bit does
# not): runs of up to 4 damaged samples, a few per take.
SPIKE_FACTOR = 10.0
LEVEL_PERCENTILE = 99.9
_SPIKE_RING = np.concatenate([np.arange(-32, -3), np.arange(4, 33)])


def damaged_samples(x: np.ndarray) -> np.ndarray:
    """Indices of the isolated damaged samples of one channel of finite float audio (see SPIKE_FACTOR):
    impulses far above the signal around them, which no microphone or converter produces."""
    # within full scale, a legal value of every format: told without |x|, a copy of the channel
    if x.size == 0 or max(float(x.max()), -float(x.min())) <= 1.0:
        return np.zeros(0, np.int64)
    a = np.abs(x)
    level = float(np.percentile(a, LEVEL_PERCENTILE))
    cand = np.flatnonzero(a > max(1.0, SPIKE_FACTOR * level))  # by construction under 0.1 % of samples
    if cand.size == 0:
        return cand
    return _isolated(cand, a, 0, a.size)


def _isolated(cand: np.ndarray, a: np.ndarray, start: int, n: int) -> np.ndarray:
    """Those of the samples ``cand`` (indices into a channel of ``n``) over ``SPIKE_FACTOR`` times every
    sample 4 to 32 away (none before the first or after the last); ``a``: |x| from sample ``start`` on,
    holding all of them."""
    ring = cand[:, None] + _SPIKE_RING[None, :]
    inside = (ring >= 0) & (ring < n)
    ring = np.clip(ring - start, 0, a.size - 1)
    neighbours = np.where(inside, a[ring], 0.0)
    return cand[a[cand - start] > SPIKE_FACTOR * neighbours.max(axis=1)]


def _damaged_in_file(audio: FileAudio) -> tuple[int, float]:
    """``check_samples``' repair of damaged samples (``damaged_samples``) of float32 audio left in its file,
    found in passes over the file instead of on whole channels (|x| of an hour of 48 kHz audio: 691 MB a
    channel): each channel's peak and the histogram of |x|'s upper 16 bits; the lower bits of the buckets
    holding the level's two ranks (the level NumPy's percentile gives, to the bit: ``_level_ranks``); the
    samples past the threshold. Their neighbours, and those a mend interpolates, are read where they lie.
    The mends are kept in ``audio`` (``FileAudio.mend``), to be applied as its blocks are read. Returns
    the number of damaged samples and the largest magnitude among them."""
    n, channels = audio.frames, audio.channels
    high = np.zeros((channels, 1 << 16), np.int64)
    peaks = np.zeros(channels, np.float32)
    for block in audio.blocks(CHECK_FRAMES):
        bits = np.abs(block).view(np.uint32)  # the order of non-negative floats
        for c in range(channels):
            high[c] += np.bincount(bits[:, c] >> 16, minlength=1 << 16)
        peaks = np.maximum(peaks, bits.max(axis=0).view(np.float32))
    past = [c for c in range(channels) if peaks[c] > 1.0]  # within full scale: none damaged
    if not past:
        return 0, 0.0
    lo_rank, hi_rank, gamma = _level_ranks(n)
    buckets = {}  # (channel, rank): (bucket, rank within it)
    for c in past:
        counts = np.cumsum(high[c])
        for rank in (lo_rank, hi_rank):
            bucket = int(np.searchsorted(counts, rank, side="right"))
            buckets[c, rank] = (bucket, rank - (int(counts[bucket - 1]) if bucket else 0))
    low = {(c, b): np.zeros(1 << 16, np.int64) for (c, _), (b, _) in buckets.items()}
    for block in audio.blocks(CHECK_FRAMES):
        bits = np.abs(block).view(np.uint32)
        for (c, b), counts in low.items():
            column = bits[:, c]
            counts += np.bincount(column[column >> 16 == b] & 0xFFFF, minlength=1 << 16)
    thresholds = {}
    for c in past:
        ranked = []
        for rank in (lo_rank, hi_rank):
            b, within = buckets[c, rank]
            lower = int(np.searchsorted(np.cumsum(low[c, b]), within, side="right"))
            ranked.append(np.array([b << 16 | lower], np.uint32).view(np.float32)[0])
        thresholds[c] = max(1.0, SPIKE_FACTOR * _lerp(ranked[0], ranked[1], gamma))
    found: dict[int, list[np.ndarray]] = {c: [] for c in past}
    at = 0
    for block in audio.blocks(CHECK_FRAMES):
        for c in past:
            hits = np.flatnonzero(np.abs(block[:, c]) > thresholds[c])
            if hits.size:
                found[c].append(hits + at)
        at += len(block)
    count, worst = 0, 0.0
    with sf.SoundFile(libsndfile_name(audio._read_from)) as f:
        for c, parts in found.items():
            if not parts:
                continue
            cand = np.concatenate(parts)
            spikes, values, mended = _spikes_in_file(f, c, cand, n)
            if spikes.size:
                count += int(spikes.size)
                worst = max(worst, float(np.max(values)))
                audio.mend(spikes, c, mended)
    return count, worst


def _level_ranks(n: int) -> tuple[int, int, float]:
    """The ranks (from 0, of n values in order) NumPy's percentile ``LEVEL_PERCENTILE`` interpolates
    between, and the weight of the upper one: its 'linear' method, in its arithmetic."""
    q = np.true_divide(LEVEL_PERCENTILE, 100)
    virtual = n * q + (1 + q * (1 - 1 - 1)) - 1
    lower = int(np.floor(virtual))
    gamma = float(virtual - lower)
    if virtual >= n - 1:
        return n - 1, n - 1, gamma
    if virtual < 0:
        return 0, 0, gamma
    return lower, lower + 1, gamma


def _lerp(a: np.floating, b: np.floating, t: float) -> float:
    """NumPy's interpolation of a percentile between ``a`` and ``b`` (in their type): from the nearer one."""
    diff = b - a
    return float(b - diff * (1 - t)) if t >= 0.5 else float(a + diff * t)


def _window_reads(
    f: sf.SoundFile, c: int, starts: np.ndarray, ends: np.ndarray
) -> Iterator[tuple[int, np.ndarray]]:
    """Channel ``c`` of the file ``f`` over each window [start, end) (overlapping ones merged), NaN or
    infinite samples read as 0."""
    i = 0
    while i < len(starts):
        start, end = int(starts[i]), int(ends[i])
        while i + 1 < len(starts) and starts[i + 1] <= end:
            i += 1
            end = max(end, int(ends[i]))
        f.seek(start)
        x = f.read(end - start, dtype="float32", always_2d=True)[:, c]
        x[~np.isfinite(x)] = 0.0
        yield start, x
        i += 1


def _spikes_in_file(
    f: sf.SoundFile, c: int, cand: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_isolated`` of the candidates ``cand`` (sorted) of channel ``c`` of the file ``f``, read around
    each; with their magnitudes and the values ``check_samples`` gives them: the interpolation of the
    nearest samples on either side that are not damaged. Those lie in the window read: two damaged
    samples are never 4 to 32 apart (each would be over 10 times the other), so one is at most 4 away."""
    reach = int(np.abs(_SPIKE_RING).max())
    starts, ends = np.maximum(cand - reach, 0), np.minimum(cand + reach + 1, n)
    spikes, values, mended = [], [], []
    for start, x in _window_reads(f, c, starts, ends):
        a = np.abs(x)
        here = cand[(cand >= start) & (cand < start + a.size)]
        isolated = _isolated(here, a, start, n)
        good = np.ones(x.size, bool)
        good[isolated - start] = False
        keep = np.flatnonzero(good)
        spikes.append(isolated)
        values.append(a[isolated - start])
        mended.append(np.interp(isolated - start, keep, x[keep]).astype(np.float32))
    return np.concatenate(spikes), np.concatenate(values), np.concatenate(mended)


def _wav_data_chunk(path: Path) -> tuple[int, int, int | None] | None:
    """Where a RIFF WAV's ``data`` chunk starts (byte offset of its samples), the size its header
    declares, and the block alignment of its ``fmt`` chunk; ``None`` for other files."""
    try:
        with open(path, "rb") as f:
            if f.read(4) != b"RIFF" or f.read(4) == b"" or f.read(4) != b"WAVE":
                return None
            block_align = None
            while True:
                head = f.read(8)
                if len(head) < 8:
                    return None
                chunk, size = head[:4], struct.unpack("<I", head[4:])[0]
                if chunk == b"fmt " and size >= 14:
                    block_align = struct.unpack("<12xH", f.read(14))[0]
                    size -= 14
                elif chunk == b"data":
                    return f.tell(), size, block_align
                f.seek(size + (size & 1), 1)
    except OSError:
        return None


def wav_declared_frames(path: Path) -> int | None:
    """Sample frames a RIFF WAV's ``data`` chunk header declares; ``None`` for other files, RF64 and
    streamed or unfinished WAVs whose header leaves the size open (0 or 0xFFFFFFFF)."""
    found = _wav_data_chunk(path)
    if found is None:
        return None
    _, size, block_align = found
    return None if not block_align or size in (0, 0xFFFFFFFF) else size // block_align


def wav_unfinished_bytes(path: Path) -> int:
    """Bytes of samples after a WAV ``data`` chunk whose header declares none: what a recorder that
    stopped before it wrote the sizes leaves (0 for other files)."""
    found = _wav_data_chunk(path)
    if found is None or found[1] != 0:
        return 0
    start, size = found[0], path.stat().st_size
    try:
        with open(path, "rb") as f:
            f.seek(start)
            head = f.read(8)
    except OSError:
        return 0
    # an empty data chunk followed by another chunk (LIST, id3 ...) that ends the file holds no samples
    if len(head) == 8 and head[:4].isascii() and head[:4].strip().isalnum():
        if start + 8 + struct.unpack("<I", head[4:])[0] + 1 >= size:
            return 0
    return max(size - start, 0)


# Codecs (FFmpeg's decoder names) whose encoder puts priming samples before the sound (AAC: 1024 or
# 2112, MP3: 1105 and more), which a decoder can only drop when the file records how many (an MP4 edit
# list, an MP3's LAME tag).
PRIMED_CODECS = ("aac", "mp3", "mp3float")


def note_unknown_delay(
    path: Path, repairs: list[dict[str, Any]], stream: Any = None, first_pts: int | None = None
) -> None:
    """Note (repair ``encoder_delay_unknown``) audio of a ``PRIMED_CODECS`` codec whose file records no
    encoder delay for the decoder to drop: FFmpeg finds neither a start after 0 (an MP3's LAME tag) nor
    packets before it (an MP4 edit list). ``stream``: the file's PyAV audio stream and ``first_pts`` its
    first packet's (None: the file is opened here, as for what libsndfile decoded)."""
    if stream is None:
        unknown = _unknown_delay_codec(_ffmpeg_source(path))
    else:
        unknown = None if _delay_known(stream, first_pts) else _codec_and_rate(stream)
    if unknown is None:
        return
    repairs.append(_unknown_delay_note(path, *unknown))


def _unknown_delay_note(path: Path, codec: str, rate: int) -> dict[str, Any]:
    """The repair ``encoder_delay_unknown`` of ``note_unknown_delay``: audio of FFmpeg's decoder ``codec``
    at ``rate`` Hz (0: not known) keeps its priming."""
    return {
        "line": None,
        "kind": "encoder_delay_unknown",
        "message": f"{shown_name(path)}: {codec.removesuffix('float').upper()} audio whose file does not "
        "record the encoder's delay (raw ADTS .aac, an MP3 without a LAME tag): its priming samples are "
        f"kept, so the audio may start up to ~{_priming_ms(rate)} ms late; s2a-align measures the offset",
    }


# The most samples of an encoder's priming a decoder may keep: Apple's AAC encoder's 2112 (FFmpeg's AAC
# encoder primes 1024, LAME's output decodes 1105 before its sound)
_PRIMING_MOST = 2112


def _priming_ms(rate: int) -> int:
    """How late (ms) the sound may start in audio at ``rate`` Hz whose encoder's priming is kept: its
    samples are as many at any rate (at 16 kHz raw AAC was 64 ms late, LAME's MP3 69 ms, 138 ms at 8
    kHz); said as ~50 ms at 44.1 and 48 kHz."""
    return max(50, math.ceil(1000 * _PRIMING_MOST / rate)) if rate > 0 else 50


def _codec_and_rate(stream: Any) -> tuple[str, int]:
    """The decoder name and sample rate of a PyAV audio ``stream`` (0: not known)."""
    return stream.codec_context.name, stream.codec_context.sample_rate or 0


def _delay_known(stream: Any, first_pts: int | None) -> bool:
    """Whether the audio of ``stream`` (``first_pts``: its first packet's time) has no encoder delay FFmpeg
    leaves in: its codec has none (not one of ``PRIMED_CODECS``: PCM, MPEG layer I or II), or FFmpeg found
    it recorded in the file, for it to drop: a start after 0 (an MP3's LAME tag) or packets before it (an
    MP4 edit list)."""
    if stream.codec_context.name not in PRIMED_CODECS:
        return True
    return (first_pts or 0) < 0 or (stream.start_time or 0) > 0


def _unknown_delay_codec(source: str) -> tuple[str, int] | None:
    """The codec of the first audio stream of the file ``source`` when its encoder's delay is not known
    (``_delay_known``): FFmpeg's decoder name, and its sample rate; None when it is, and when FFmpeg
    cannot open it (nothing is known of a delay then)."""
    import av

    try:
        with av.open(source) as container:
            stream = container.streams.audio[0]
            first_pts = next((p.pts for p in container.demux(stream) if p.pts is not None), None)
            return None if _delay_known(stream, first_pts) else _codec_and_rate(stream)
    except (av.FFmpegError, OSError, ValueError, IndexError):
        return None


def _to_channels(samples: np.ndarray, channels: int) -> np.ndarray:
    """Frames x channels samples mixed to ``channels``: their mean on each channel (mono to stereo
    copies the channel, stereo to mono averages the two)."""
    mixed = samples.mean(axis=1, keepdims=True, dtype=np.float64).astype(samples.dtype)
    return np.repeat(mixed, channels, axis=1)


def _note_channels_changed(
    path: Path, repairs: list[dict[str, Any]] | None, changed: int, at: int, rate: int, channels: int
) -> None:
    if repairs is not None and changed:
        repairs.append(
            {
                "line": None,
                "kind": "channels_changed",
                "message": f"{shown_name(path)}: the audio's channel count changes mid-stream (from "
                f"{at / rate:.3f} s): {changed} samples were mixed to the first frame's "
                f"{channels} channel(s)",
            }
        )


class _DecodedLayout:
    """What both keepers of decoded frames (``_Samples``, ``_DecodedToFile``) note of their layout: the
    samples kept, those mixed to the first frame's channel count and where that began, and the last
    frame's layout (for silence in its place, ``_silence_of``)."""

    def __init__(self) -> None:
        self.used = 0  # samples kept
        self.changed, self.first_changed = 0, 0  # samples mixed to the first channel count, where from
        self.last_channels: int | None = None
        self.last_dtype: np.dtype | None = None

    def __bool__(self) -> bool:
        return self.last_dtype is not None

    def _noted(self, arr: np.ndarray, channels: int) -> np.ndarray:
        """``arr`` noted as the last frame, mixed to ``channels`` when it has other channels
        (``_to_channels``)."""
        self.last_channels, self.last_dtype = arr.shape[1], arr.dtype
        if arr.shape[1] == channels:
            return arr
        self.first_changed = self.first_changed if self.changed else self.used
        self.changed += len(arr)
        return _to_channels(arr, channels)


class _Samples(_DecodedLayout):
    """Decoded frames written one after another into one array (frames x channels), as they come: the
    audio is held once, not as a list of chunks and then their join. Each frame is mixed to the first
    frame's channel count (``_to_channels``) and the array takes the dtype joining them would give
    (``np.concatenate``'s promotion). ``expected``: the samples the stream is thought to hold, to allocate
    once; a short guess grows the array in place, and what is not used is given back at the end."""

    def __init__(self, expected: int = 0):
        super().__init__()
        self._rows: GrowingRows | None = None
        self._expected = max(expected, 0)

    def append(self, arr: np.ndarray) -> None:
        if self._rows is None:
            self._rows = self._allocated(arr)
        rows = self._rows
        arr = self._noted(arr, rows.array.shape[1])
        if arr.dtype != rows.array.dtype:
            joined = np.result_type(rows.array, arr)
            if joined != rows.array.dtype:
                rows.array = rows.array.astype(joined)  # a format change mid-stream: rare
        end = self.used + len(arr)
        if end > len(rows):
            rows.resize(max(end, len(rows) * 3 // 2))
        rows.array[self.used : end] = arr
        self.used = end

    @property
    def channels(self) -> int:
        assert self._rows is not None
        return self._rows.array.shape[1]

    def _allocated(self, first: np.ndarray) -> GrowingRows:
        # untouched pages of a generous guess cost no memory: the slack covers a frame of padding. A
        # container that claims more than can be allocated (damaged) only loses the head start
        try:
            return GrowingRows(max(self._expected + 4096, len(first)), first.shape[1], first.dtype)
        except (MemoryError, ValueError):
            return GrowingRows(len(first), first.shape[1], first.dtype)

    def take(self, frames: int | None = None) -> np.ndarray:
        """The samples written (the first ``frames`` of them), the unused rest of the array given back."""
        assert self._rows is not None
        rows, self._rows = self._rows, None
        rows.resize(self.used if frames is None else frames)
        return rows.array


@dataclass
class _Decoded:
    """What FFmpeg decoded from one audio stream: where its frames went, and what is known of them."""

    kept: _Samples | _DecodedToFile | _JoinedPart  # where its frames went: one array, a scratch file, or
    # handed on (a file of a joined .mp3)
    rate: int
    sample_format: str  # FFmpeg's sample format of the last frame, planar or not: s16, s32, u8, flt ...
    last_frame: int  # samples of the last decoded frame
    declared: int | None  # samples the container declares (AAC only), None when unknown
    damaged: int = 0  # packets FFmpeg could not decode (only when asked to skip them): silence in their place


def _expected_samples(stream: Any) -> int:
    """The samples a stream's container says it holds (0 when it does not say), to allocate for."""
    rate = stream.rate or stream.codec_context.sample_rate or 0
    if stream.duration and stream.time_base and rate:
        return round(float(stream.duration * stream.time_base) * rate)
    return 0


def _decode_frames(
    source: str | IO[bytes] | _MendedPart,
    path: Path,
    stream_index: int,
    repairs: list[dict[str, Any]] | None,
    skip_damaged: bool = False,
    into: Callable[[Any], _DecodedToFile | _JoinedPart] | None = None,
) -> _Decoded:
    """Every frame of one audio stream of ``source`` (a file name, a file-like object, or a file of an
    .mp3 as ``_mended`` gives it), decoded by FFmpeg; an undecodable stream is an ``InputError`` naming
    ``path`` (with ``skip_damaged``, a packet FFmpeg cannot decode is counted and replaced by silence of
    its duration, so the sound after it keeps its time). ``repairs``: where the note of an unrecorded
    encoder delay goes (``note_unknown_delay``). The frames are written into one array as they are
    decoded (``_Samples``), or into what ``into`` makes, given the stream: a scratch file
    (``_DecodedToFile``), a file of a joined .mp3 (``_JoinedPart``: told the stream and its first
    packet's time before that packet is decoded, ``_JoinedPart.opened``)."""
    import av  # imported here: only needed for containers soundfile cannot read

    try:
        with av.open(source, format="mp3" if isinstance(source, _MendedPart) else None) as container:
            streams = container.streams.audio
            if not streams:
                raise InputError("file has no audio stream", path)
            stream = streams[stream_index]
            kept = _Samples(_expected_samples(stream)) if into is None else into(stream)
            fmt = "flt"
            last_frame = 0
            first_pts = None
            damaged = 0
            for packet in container.demux(stream):
                if first_pts is None and packet.pts is not None:
                    first_pts = packet.pts
                    if isinstance(kept, _JoinedPart):
                        kept.opened(stream, first_pts)
                try:
                    frames = packet.decode()
                except av.InvalidDataError:
                    if not skip_damaged:
                        raise
                    damaged += 1
                    kept.append(_silence_of(packet, stream, kept))
                    continue
                for frame in frames:
                    fmt, last_frame = frame.format.name, frame.samples
                    arr = frame.to_ndarray()
                    if frame.format.is_planar:
                        arr = arr.T
                    else:
                        arr = arr.reshape(-1, len(frame.layout.channels))
                    kept.append(arr)
            rate = stream.rate or stream.codec_context.sample_rate
            # AAC only: an MP3's duration may be an estimate from its bit rate
            aac = stream.codec_context.name == "aac"
            declared = (
                round(float(stream.duration * stream.time_base) * rate)
                if aac and stream.duration and rate
                else None
            )
            if repairs is not None:
                note_unknown_delay(path, repairs, stream, first_pts)
        failed = source.failed if isinstance(source, _MendedPart) else None
        if failed is not None:  # FFmpeg took it for the end of the file
            raise failed
    except InputError:
        raise
    except (av.FFmpegError, OSError, ValueError) as exc:
        failed = source.failed if isinstance(source, _MendedPart) else None
        if failed is not None and not isinstance(failed, OSError):  # FFmpeg's error is of no bytes read
            raise failed from None
        # FFmpeg's errors carry its own negative error code ("[Errno 1094995529] Invalid data found ..."):
        # the text is what tells the user something
        why = getattr(failed or exc, "strerror", None) or str(failed or exc)
        raise InputError(f"audio could not be decoded (a truncated or damaged file?): {why}", path) from None
    return _Decoded(kept, rate, fmt.rstrip("p"), last_frame, declared, damaged)


def _silence_of(packet: Any, stream: Any, kept: _DecodedLayout | _JoinedPart) -> np.ndarray:
    """Silence as long as an undecodable packet (none when its duration is unknown), in the layout of what
    was decoded before it."""
    rate = stream.rate or stream.codec_context.sample_rate
    seconds = float(packet.duration * packet.time_base) if packet.duration and packet.time_base else 0.0
    channels = stream.codec_context.channels if kept.last_channels is None else kept.last_channels
    dtype = np.float32 if kept.last_dtype is None else kept.last_dtype
    return np.zeros((round(seconds * rate), channels), dtype)


def _in_recorded_format(data: np.ndarray, rate: int, sample_format: str) -> Audio:
    """Decoded samples as the recorded format's: converted in place where the dtype allows, so the audio
    is not held twice."""
    return Audio(*_recorded_samples(data, sample_format, rate))


def _recorded_samples(data: np.ndarray, sample_format: str, rate: int = 0) -> tuple[np.ndarray, int, str]:
    """(samples, ``rate``, subtype) of ``_in_recorded_format``: sample by sample, so a block at a time
    converts as the whole does."""
    if sample_format == "s16":
        return data.astype(np.int16, copy=False), rate, "PCM_16"
    if sample_format == "s32":
        return data.astype(np.int32, copy=False), rate, "PCM_32"
    if sample_format == "u8":
        unsigned = data.astype(np.float32)
        unsigned -= 128.0  # the same float32 arithmetic as (x - 128.0) / 128.0, without its temporaries
        unsigned /= 128.0
        return unsigned, rate, "FLOAT"
    return data.astype(np.float32, copy=False), rate, "FLOAT"


# FFmpeg's sample format of decoded frames (planar or not) by the dtype PyAV gives them in
_FORMAT_OF_DTYPE = {"int16": "s16", "int32": "s32", "uint8": "u8", "float32": "flt", "float64": "dbl"}


def decode_with_pyav(
    path: str | Path,
    stream_index: int = 0,
    repairs: list[dict[str, Any]] | None = None,
    skip_damaged: bool = False,
) -> Audio:
    """The first audio stream of any container FFmpeg reads (.mov, .m4a, .mp3, ...).

    FFmpeg drops the encoder's priming samples at the start (the edit list); the padding that fills the
    last coded frame (AAC: up to 1023 samples) is cut here, where the container's stream duration ends
    inside that frame (AAC only: other codecs trim their own padding, and an MP3's duration may be an
    estimate). A file that records no delay keeps it: noted in ``repairs`` (``note_unknown_delay``).
    Audio whose channel count changes mid-stream is mixed to the first frame's (repair
    ``channels_changed``). ``skip_damaged``: a packet FFmpeg cannot decode is silence of its duration.
    The frames are written into one array as they are decoded (``_Samples``): an hour's take is held once.
    Within ``audio_left_in_files`` given a scratch folder (an import) they are written a block at a time
    into a scratch WAV there instead, and the audio is a ``FileAudio`` of it (``_decoded_to_file``): the
    same samples, never held whole."""
    path = Path(path)
    scratch = _scratch_folder()
    if scratch is not None:
        audio = _decoded_to_file(path, stream_index, repairs, skip_damaged, scratch)
        if audio is not None:
            return audio
    decoded = _decode_frames(_ffmpeg_source(path), path, stream_index, repairs, skip_damaged)
    samples = decoded.kept
    assert isinstance(samples, _Samples)
    if not samples:
        raise InputError("audio stream holds no samples", path)
    _note_channels_changed(
        path, repairs, samples.changed, samples.first_changed, decoded.rate, samples.channels
    )
    data = samples.take(_without_padding(decoded, samples.used))
    return _in_recorded_format(data, decoded.rate, decoded.sample_format)


def _without_padding(decoded: _Decoded, used: int) -> int | None:
    """The samples to keep of the ``used`` decoded: the container's declared duration when it ends inside
    the last frame (its padding), else None (all)."""
    declared = decoded.declared
    padded = declared is not None and 0 < used - declared < decoded.last_frame
    return declared if padded else None


class _NotStreamed(Exception):
    """Audio that cannot be written into a scratch file as reading it whole would give it (a sample format
    that changes mid-stream, no sample rate, libsndfile's read of an .mp3 ending in an error, no samples):
    read whole instead, which says what is wrong."""


def _decoded_to_file(
    path: Path,
    stream_index: int,
    repairs: list[dict[str, Any]] | None,
    skip_damaged: bool,
    scratch: _Scratch,
) -> FileAudio | None:
    """``decode_with_pyav``'s audio written a block at a time into a new file of ``scratch`` as it is
    decoded, as a ``FileAudio`` of it naming ``path``: the same samples, repairs and notes, never held
    whole. None (see ``_streamed``) when the sample format changes mid-stream, which the whole-array way
    joins by NumPy's promotion and converts by the last frame's format, or when the system refuses the
    scratch file: decoded whole then."""

    def decode(found: list[dict[str, Any]] | None, sink_of: _SinkOf) -> FileAudio:
        sinks: list[_DecodedToFile] = []

        def into(stream: Any) -> _DecodedToFile:
            sinks.append(sink_of(lambda: stream.rate or stream.codec_context.sample_rate))
            return sinks[0]

        decoded = _decode_frames(_ffmpeg_source(path), path, stream_index, found, skip_damaged, into=into)
        sink = sinks[0]
        if not sink:
            raise InputError("audio stream holds no samples", path)
        _note_channels_changed(path, found, sink.changed, sink.first_changed, decoded.rate, sink.channels)
        return sink.finish(_without_padding(decoded, sink.used), decoded.rate, decoded.sample_format)

    return _streamed(path, repairs, scratch, decode)


# makes the scratch file decoded audio is written into, given the function that tells its rate
_SinkOf = Callable[[Callable[[], int]], "_DecodedToFile"]


def _streamed(
    path: Path,
    repairs: list[dict[str, Any]] | None,
    scratch: _Scratch,
    decode: Callable[[list[dict[str, Any]] | None, _SinkOf], FileAudio],
) -> FileAudio | None:
    """The audio ``decode`` writes a block at a time into scratch files of ``scratch`` (it makes them by
    its second argument, and notes repairs in its first), its repairs then added to ``repairs``. None,
    nothing noted and its files removed, when it raises ``_NotStreamed``: the caller decodes whole. Then
    a scratch file the system refused (``_ScratchRefused``: a full disk) is said on stderr, once a block
    of ``audio_left_in_files``: the audio is held in memory instead. Whatever else ends the decoding (an
    error, Ctrl-C) removes its files too."""
    found: list[dict[str, Any]] | None = None if repairs is None else []
    sinks: list[_DecodedToFile] = []

    def sink_of(rate_of: Callable[[], int]) -> _DecodedToFile:
        try:
            sinks.append(_DecodedToFile(scratch.new_file(), path, rate_of))
        except OSError as exc:
            raise _scratch_refused(scratch.folder, exc, path) from None
        return sinks[-1]

    try:
        audio = decode(found, sink_of)
    except _ScratchRefused as refused:
        scratch.refused(refused)
        return None
    except _NotStreamed:
        return None
    finally:
        for sink in sinks:
            sink.close()  # an error, Ctrl-C: the file goes now; done: it stays for the FileAudio
    if repairs is not None and found:
        repairs += found
    return audio


class _ScratchRefused(_NotStreamed):
    """The system refused the scratch file (a disk too full for the audio twice, a folder gone): decoded
    whole instead, as before there was a scratch file, so an import that fitted in memory still works."""


def _scratch_refused(folder: Path, exc: OSError, source: Path) -> _ScratchRefused:
    """What ends decoding ``source`` into a scratch file in ``folder`` that the system refuses."""
    return _ScratchRefused(f"{source}: audio could not be decoded into {folder}: {exc.strerror or exc}")


class _DecodedToFile(_DecodedLayout):
    """Decoded frames written into a scratch WAV a block at a time, as ``_Samples`` would hold them: each
    mixed to the first frame's channel count, converted to the recorded format (``_recorded_samples``),
    NaN or infinite float samples set to 0 and counted, the largest magnitude and the CRC-32s of what is
    written kept (for the ``FileAudio`` of the file). The last frame's worth of samples waits in memory
    until the end, for the padding the container's duration cuts there (``_without_padding``)."""

    def __init__(self, scratch: Path, source: Path, rate_of: Callable[[], int]):
        super().__init__()
        self.scratch, self.source = scratch, source
        self._rate_of = rate_of  # the rate to write at, asked when the first block is
        self.channels = 0
        self._dtype: np.dtype | None = None  # that of every decoded chunk
        self._waiting: list[np.ndarray] = []  # decoded, not yet written
        self._waiting_frames = 0
        self._longest = 0  # the longest chunk yet: the padding a duration may cut lies within it
        self._file: IO[bytes] | None = None
        self._sink: _WavSink | None = None
        self._out: sf.SoundFile | None = None
        self._rate = 0
        self._crcs, self._bad, self._peak = _BlockCrcs(), 0, 0.0
        self._recorded: tuple[np.dtype, str] | None = None  # the dtype and subtype written
        self._done = False

    def append(self, arr: np.ndarray) -> None:
        if self._dtype is None:
            self._dtype, self.channels = arr.dtype, arr.shape[1]
        if arr.dtype != self._dtype:
            raise _NotStreamed
        arr = self._noted(arr, self.channels)
        self._waiting.append(arr)
        self._waiting_frames += len(arr)
        self.used += len(arr)
        self._longest = max(self._longest, len(arr))
        if self._waiting_frames >= self._longest + WRITE_FRAMES:
            self._write(self._waiting_frames - self._longest)

    def _write(self, frames: int) -> None:
        """Write the first ``frames`` of the samples waiting."""
        assert self._dtype is not None
        if not self._waiting:  # chunks of no samples
            waiting = np.zeros((0, self.channels), self._dtype)
        else:
            waiting = self._waiting[0] if len(self._waiting) == 1 else np.concatenate(self._waiting)
        self._waiting = [waiting[frames:]] if len(waiting) > frames else []
        self._waiting_frames = len(waiting) - frames
        block, rate, subtype = _recorded_samples(waiting[:frames], _FORMAT_OF_DTYPE.get(self._dtype.name, ""))
        block = np.ascontiguousarray(block)
        if block.dtype.kind == "f":
            finite = np.isfinite(block)
            if not finite.all():
                self._bad += int(finite.size - np.count_nonzero(finite))
                block = block if block.flags.writeable else block.copy()
                block[~finite] = 0.0
        if len(block):
            self._peak = max(self._peak, float(block.max()), -float(block.min()))
        self._crcs.add(block)
        if self._out is None:
            self._open(subtype)
        out = self._out
        assert out is not None
        self._into_file(lambda: out.write(block))
        self._recorded = (block.dtype, subtype)

    def _open(self, subtype: str) -> None:
        rate = self._rate_of()
        if not rate or rate <= 0:
            raise _NotStreamed  # no rate to write: the whole-array way says what is wrong
        self._rate = int(rate)
        try:
            self._file = open(self.scratch, "wb", buffering=1 << 20)
        except OSError as exc:
            raise _scratch_refused(self.scratch.parent, exc, self.source) from None
        sink = self._sink = _WavSink(self._file)

        def opened() -> None:
            # RF64: a size past 4 GB is no error; libsndfile reads it as it reads a WAV
            self._out = sf.SoundFile(sink, "w", self._rate, self.channels, subtype=subtype, format="RF64")

        self._into_file(opened)

    def _into_file(self, call: Callable[[], None]) -> None:
        """``call``'s writing through libsndfile into the scratch file, a write the system refuses (a full
        disk) an ``InputError``; Ctrl-C or SIGTERM waits until it returns (``stops_deferred``), and is met
        as it does: what ``call`` makes is kept within it (``self._out``), else it would be lost."""
        sink = self._sink
        assert sink is not None
        try:
            with stops_deferred():  # met in libsndfile's callback, a stop would be lost there
                call()
        except (AssertionError, sf.SoundFileError):  # soundfile's check that every frame was written
            if sink.error is None:
                raise
        if sink.error is not None:
            raise _scratch_refused(self.scratch.parent, sink.error, self.source)

    def finish(self, frames: int | None, rate: int, sample_format: str) -> FileAudio:
        """The audio decoded (its first ``frames``; None: all) as a ``FileAudio`` of the file; ``rate``
        and ``sample_format``: the stream's, as decoding ends."""
        assert self._dtype is not None
        frames = self.used if frames is None else frames
        cut = self.used - frames
        if cut > self._waiting_frames or (self._out is not None and rate != self._rate):
            raise _NotStreamed  # cannot happen: a duration ends inside the last chunk, rates do not change
        if self._out is None:
            self._rate_of = lambda: rate
        if _FORMAT_OF_DTYPE.get(self._dtype.name) != sample_format:
            raise _NotStreamed  # silence only (decoded as float), or frames of a format not listed
        self._write(self._waiting_frames - cut)
        assert self._out is not None and self._file is not None
        self._into_file(self._out.close)
        self._out = None
        try:
            self._file.close()
        except OSError as exc:
            raise _scratch_refused(self.scratch.parent, exc, self.source) from None
        self._done = True
        assert self._recorded is not None
        dtype, subtype = self._recorded
        return FileAudio(
            self.scratch,
            self._rate,
            subtype,
            np.dtype(dtype),
            frames,
            self.channels,
            self._crcs.done(),
            shown=self.source,
            non_finite=self._bad,
            peak=self._peak,
        )

    def close(self) -> None:
        """Unless ``finish`` made a ``FileAudio`` of it: the file closed and removed."""
        if self._done:
            return
        try:
            if self._out is not None:
                with stops_deferred():  # met in libsndfile's callback, a stop would be lost there
                    self._out.close()
        except (AssertionError, sf.SoundFileError):
            pass  # a full disk: the file goes all the same
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass
        self.scratch.unlink(missing_ok=True)


class _FileBytes:
    """A file's bytes as ``bytes`` to the frame scan (indexing, slices, ``find``, ``startswith``), read a
    block of ``_SCAN_BLOCK`` at a time, not whole (a 60 MB cover picture, an hour at 320 kbit/s: 144 MB)
    nor mapped: a file another program cuts short while it is read is an ``InputError`` saying so (a
    mapped file's pages past its new end kill the process: SIGBUS)."""

    def __init__(self, file: IO[bytes], path: Path):
        self.file, self.path, self.size = file, path, os.fstat(file.fileno()).st_size
        self.block, self.block_at = b"", 0  # the block read last, and where it starts

    @classmethod
    @contextmanager
    def of(cls, path: Path) -> Iterator[_FileBytes]:
        with open(path, "rb") as f:
            yield cls(f, path)

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, at: int | slice) -> Any:
        if isinstance(at, slice):
            start, stop, _ = at.indices(self.size)
            return self._bytes(start, stop)
        at += self.size if at < 0 else 0
        i = at - self.block_at
        if not 0 <= i < len(self.block):
            if not 0 <= at < self.size:
                raise IndexError("index out of range")
            i = at - self._load(at)
        return self.block[i]

    def find(self, sub: bytes, start: int, end: int | None = None) -> int:
        return self._search(lambda block, i, j: block.find(sub, i, j), start, end, len(sub))

    def search(self, pattern: re.Pattern[bytes], start: int, span: int) -> int:
        """Where ``pattern`` (matching ``span`` bytes) first matches from ``start`` on; -1 when nowhere."""

        def first(block: bytes, i: int, j: int) -> int:
            found = pattern.search(block, i, j)
            return found.start() if found else -1

        return self._search(first, start, None, span)

    def _search(self, first: Callable[[bytes, int, int], int], start: int, end: int | None, span: int) -> int:
        """Where ``first`` (given a block, where to start and end in it) finds ``span`` bytes between
        ``start`` and ``end``; -1 when nowhere. Looked for in the block held from ``start`` on, then block
        by block: a scan that looks again a few bytes on reads no block twice (a slice of 2 MB from each
        place read it again each time: 5 MB of junk dense in 0xFF bytes took 32 s)."""
        end = self.size if end is None else min(end, self.size)
        while start <= end - span:
            if not self.block_at <= start <= self.block_at + len(self.block) - span:
                self._load(start)
            stop = min(end, self.block_at + len(self.block)) - self.block_at
            found = first(self.block, start - self.block_at, stop)
            if found != -1:
                return self.block_at + found
            start = self.block_at + len(self.block) - span + 1
        return -1

    def startswith(self, prefix: bytes | tuple[bytes, ...], start: int = 0) -> bool:
        texts = prefix if isinstance(prefix, tuple) else (prefix,)
        return any(self._bytes(start, start + len(text)) == text for text in texts)

    def aside(self, start: int, stop: int) -> bytes:
        """The bytes from ``start`` to ``stop``, the block held kept (a look elsewhere while a part is
        decoded from it: reading the block again would read 2 MB more)."""
        return self._read(start, max(min(stop, self.size) - start, 0))

    def _bytes(self, start: int, stop: int) -> bytes:
        stop = min(stop, self.size)
        if stop <= start:
            return b""
        if stop - start > _SCAN_BLOCK:  # a file's part, to decode: read alone
            return self._read(start, stop - start)
        if not (self.block_at <= start and stop <= self.block_at + len(self.block)):
            self._load(start)
        return self.block[start - self.block_at : stop - self.block_at]

    def _load(self, at: int) -> int:
        """Reads the block starting at ``at`` (with the bytes a frame header's look ahead needs); where."""
        self.block, self.block_at = b"", at  # the one before it given back first
        self.block = self._read(at, _SCAN_BLOCK + _SCAN_OVERLAP)
        return at

    def shrunk(self) -> bool:
        """Whether the file is now shorter than when it was opened (``_read`` fails)."""
        return os.fstat(self.file.fileno()).st_size < self.size

    def _read(self, at: int, size: int) -> bytes:
        self.file.seek(at)
        got = self.file.read(min(size, self.size - at))
        if len(got) < min(size, self.size - at):
            raise InputError(
                f"the file got shorter while it was read ({self.size} bytes, now "
                f"{os.fstat(self.file.fileno()).st_size}): is another program writing it? Read it again "
                "once it is written",
                self.path,
            )
        return got


# Bytes of a file the frame scan holds at a time (``_FileBytes``), and the bytes after them read with
# them: a frame header and what its look ahead reads (a Xing/Info header, the next frame's header)
_SCAN_BLOCK = 2 << 20
_SCAN_OVERLAP = 4096


# MPEG audio frame headers (ISO/IEC 11172-3, 13818-3 and the MPEG 2.5 extension): 11 sync bits, then the
# version (2 bits: 3 MPEG-1, 2 MPEG-2, 0 MPEG-2.5), layer (3 - bits), CRC flag; bitrate index, sample rate
# index, padding, private bit; channel mode (3: mono), mode extension, flags. Bit rates in kbit/s.
_MPEG_RATES = {3: (44100, 48000, 32000), 2: (22050, 24000, 16000), 0: (11025, 12000, 8000)}
_MPEG1_KBPS = {
    1: (32, 64, 96, 128, 160, 192, 224, 256, 288, 320, 352, 384, 416, 448),
    2: (32, 48, 56, 64, 80, 96, 112, 128, 160, 192, 224, 256, 320, 384),
    3: (32, 40, 48, 56, 64, 80, 96, 112, 128, 160, 192, 224, 256, 320),
}
_MPEG2_KBPS = {
    1: (32, 48, 56, 64, 80, 96, 112, 128, 144, 160, 176, 192, 224, 256),
    2: (8, 16, 24, 32, 40, 48, 56, 64, 80, 96, 112, 128, 144, 160),
    3: (8, 16, 24, 32, 40, 48, 56, 64, 80, 96, 112, 128, 144, 160),
}
# a frame header's second and third bytes -> (frame bytes, samples per channel, sample rate, layer, format
# bits, where a Xing/Info header's text would start (stereo, mono), where the side information starts)
_MpegFrame = tuple[int, int, int, int, int, tuple[int, int], int]
_MPEG_FRAMES: dict[int, _MpegFrame] = {}


def _mpeg_frame_table() -> dict[int, _MpegFrame]:
    """Every valid combination of a header's second and third bytes (free-format bit rates left out: their
    frame size is not in the header), computed once."""
    if _MPEG_FRAMES:
        return _MPEG_FRAMES
    for version, rates in _MPEG_RATES.items():
        for layer in (1, 2, 3):
            kbps = (_MPEG1_KBPS if version == 3 else _MPEG2_KBPS)[layer]
            samples = 384 if layer == 1 else 1152 if layer == 2 or version == 3 else 576
            side = (32, 17) if version == 3 else (17, 9)  # layer III side information: stereo, mono
            for b1 in range(0xE0, 0x100):
                if (b1 >> 3) & 3 != version or 4 - ((b1 >> 1) & 3) != layer:
                    continue
                crc = 0 if b1 & 1 else 2
                for b2 in range(0x100):
                    bitrate, rate_index, padding = b2 >> 4, (b2 >> 2) & 3, (b2 >> 1) & 1
                    if bitrate in (0, 15) or rate_index == 3:
                        continue
                    rate, bits = rates[rate_index], kbps[bitrate - 1] * 1000
                    if layer == 1:
                        size = (12 * bits // rate + padding) * 4
                    else:
                        size = samples // 8 * bits // rate + padding
                    fmt = (b1 & 0x1E) << 8 | (b2 & 0x0C) << 1  # version, layer, rate; bit 0 left for mono
                    text_at = (4 + crc + side[0], 4 + crc + side[1])
                    _MPEG_FRAMES[b1 << 8 | b2] = (size, samples, rate, layer, fmt, text_at, 4 + crc)
    return _MPEG_FRAMES


def _mpeg_frame(data: bytes, pos: int) -> _MpegFrame | None:
    if pos + 4 > len(data) or data[pos] != 0xFF:
        return None
    return _MPEG_FRAMES.get(data[pos + 1] << 8 | data[pos + 2])


def _mpeg_channels(data: bytes, pos: int) -> int:
    return 1 if data[pos + 3] >> 6 == 3 else 2


def _tag_bytes(data: bytes, pos: int) -> int:
    """Bytes of the ID3v2, ID3v1 (and extended "TAG+") or APEv2 tag at ``pos``; 0 when none starts there."""
    head = data[pos : pos + 32]
    if head[:3] == b"ID3" and len(head) >= 10 and head[3] < 0xFF and all(b < 0x80 for b in head[6:10]):
        size = head[6] << 21 | head[7] << 14 | head[8] << 7 | head[9]
        return 10 + size + (10 if head[5] & 0x10 else 0)  # the footer flag
    if head[:4] == b"TAG+":
        return 227
    if head[:3] == b"TAG":
        return 128
    if head[:8] == b"APETAGEX" and len(head) == 32:
        size, flags = struct.unpack("<4xI4xI", head[8:24])
        return 32 + size if flags & (1 << 29) else 32  # a header: the items and footer follow it
    return 0


_XING_TEXTS = (b"Xing", b"Info")


def _xing_at(data: bytes, pos: int, frame: _MpegFrame) -> int:
    """Where the text of a Xing/Info header would start in the frame at ``pos`` (after its side
    information, which is shorter in a mono frame)."""
    return pos + frame[5][data[pos + 3] >= 0xC0]


def _is_file_header(data: bytes, pos: int, frame: _MpegFrame) -> bool:
    """Whether the frame at ``pos`` is the Xing/Info (LAME) or VBRI frame an encoder writes first, holding
    the file's frame count (no sound). One in the middle of a stream is where another file was joined on."""
    text_at = _xing_at(data, pos, frame)
    return data.startswith(_XING_TEXTS, text_at) or data.startswith(b"VBRI", pos + 36)


def _file_header_frames(data: bytes, pos: int, frame: _MpegFrame) -> int:
    """The frames a file's Xing/Info or VBRI frame at ``pos`` declares follow it; 0 when it does not say."""
    if data.startswith(b"VBRI", pos + 36):
        return int.from_bytes(data[pos + 50 : pos + 54], "big")
    text_at = _xing_at(data, pos, frame)
    flags = data[text_at + 4 : text_at + 8]
    return int.from_bytes(data[text_at + 8 : text_at + 12], "big") if flags[3:] and flags[3] & 1 else 0


def _file_header_bytes(data: bytes, pos: int, frame: _MpegFrame) -> int:
    """The bytes a file's Xing/Info frame at ``pos`` declares its stream holds (from that frame on: FFmpeg,
    LAME; some writers count the ID3v2 tag before it too); 0 when it does not say."""
    at = _byte_count_at(data, pos, frame)
    return int.from_bytes(data[at : at + 4], "big") if at else 0


def _byte_count_at(data: bytes, pos: int, frame: _MpegFrame) -> int:
    """Where the byte count of a file's Xing/Info frame at ``pos`` lies (``_file_header_bytes``); 0 when
    it declares none."""
    if data.startswith(b"VBRI", pos + 36):
        return 0  # its byte count's extent varies between writers: not used
    text_at = _xing_at(data, pos, frame)
    flags = data[text_at + 4 : text_at + 8]
    if not (flags[3:] and flags[3] & 2):
        return 0
    return text_at + 8 + (4 if flags[3] & 1 else 0)  # after the frame count, when there is one


def _count_low(data: bytes, pos: int, size: int, file_ends: tuple[int, ...]) -> bool:
    """Whether the frame at ``pos`` (``size`` bytes), past the frame count its file's Xing/Info frame
    declares, is that file's own all the same: where the byte count the same header declares ends
    (``file_ends``: counted from the header, or from the tag before it) lies after this frame, on a frame,
    a tag or the end of the data. Only the count is wrong then (a file edited after encoding); a file
    joined on begins where the byte count ends."""
    if pos in file_ends:
        return False
    n = len(data)
    return any(
        end > pos + size and (end == n or _tag_bytes(data, end) or _mpeg_frame(data, end) is not None)
        for end in file_ends
    )


def _stops_at_count(data: bytes, header: int) -> bool:
    """Whether a decoder stops at the frame count the file header frame at ``header`` declares: a Xing/Info
    frame's (libsndfile, FFmpeg), not a VBRI frame's (libsndfile reads past it to the last frame)."""
    return not data.startswith(b"VBRI", header + 36)


def _ends_stream(data: bytes, end: int) -> bool:
    """Whether a frame ending at ``end`` is the stream's last whole one: the data ends there, or tags do
    (ID3v1, APEv2 at a file's end) with no frame after them."""
    n = len(data)
    while end < n:
        skip = _tag_bytes(data, end)
        if not skip:
            return False
        end += skip
    return end == n


def _confirmed(data: bytes, pos: int, frame: _MpegFrame, end_confirms: bool = True) -> bool:
    """Whether a frame header at ``pos`` is followed by another of the same format, a tag or (with
    ``end_confirms``) the end of the data: what tells a real frame (a resync point, a change of format)
    from stray bytes. A change of format needs a frame after it: one damaged last header is no change."""
    nxt = pos + frame[0]
    if nxt >= len(data) - 3:
        return end_confirms
    if _tag_bytes(data, nxt):
        return True
    after = _mpeg_frame(data, nxt)
    return (
        after is not None and after[4] == frame[4] and _mpeg_channels(data, nxt) == _mpeg_channels(data, pos)
    )


# A frame header's first three bytes as ``_mpeg_frame_table`` has them: its sync, a version and layer that
# are not reserved, a bit rate in the header (not free format, not 15) and a sample rate not reserved
_HEADER_START = re.compile(
    rb"\xff[%s][%s]"
    % (
        re.escape(bytes(b for b in range(0xE0, 0x100) if b >> 3 & 3 != 1 and b >> 1 & 3)),
        re.escape(bytes(b for b in range(0x100) if b >> 4 not in (0, 15) and b >> 2 & 3 != 3)),
    )
)


def _next_header(data: bytes | _FileBytes, pos: int) -> int:
    """Where the next bytes that start a frame header lie at or after ``pos`` (a C search: the bytes
    between are never looked at one by one); -1 when none do."""
    if isinstance(data, _FileBytes):
        return data.search(_HEADER_START, pos, 3)
    found = _HEADER_START.search(data, pos)
    return found.start() if found else -1


def _resync(data: bytes, pos: int) -> int | None:
    """The next confirmed frame or tag at or after ``pos`` (stray bytes skipped); None at the end."""
    while True:
        sync = _next_header(data, pos)
        tag = data.find(b"ID3", pos, len(data) if sync == -1 else sync + 2)  # only before that sync
        if tag != -1 and _tag_bytes(data, tag):
            return tag
        if sync == -1:
            return None
        frame = _mpeg_frame(data, sync)
        if frame is not None and _confirmed(data, sync, frame):
            return sync
        pos = sync + 1


def _starts_reservoir(data: bytes, pos: int, frame: _MpegFrame) -> bool:
    """Whether the frame at ``pos`` could be a file's first: not layer III, or its sound starts in its own
    bytes (``main_data_begin`` 0: a layer III frame may begin its sound in the bytes of the frames before
    it, the bit reservoir, which a file's first frame has none of)."""
    return not _reservoir_bytes(data, pos, frame)


def _reservoir_bytes(data: bytes | _FileBytes, pos: int, frame: _MpegFrame) -> int:
    """How many bytes before the frame at ``pos`` its sound begins (``main_data_begin``: the side
    information's first 9 bits in MPEG-1, 8 in MPEG-2 and 2.5); 0 in layers I and II, and at the data's
    end."""
    side = pos + frame[6]
    if frame[3] != 3 or side + 2 > len(data):
        return 0
    return data[side] if frame[1] == 576 else data[side] << 1 | data[side + 1] >> 7


_NO_COUNT = 1 << 62  # a file whose header declares no frame count: never past it


@dataclass
class MpegRun:
    """Consecutive MPEG audio frames of one format in an .mp3: where they lie (bytes), their sample rate
    (Hz), channel count and layer, the samples coded in them (per channel: encoder delay and padding
    included), and whether they begin a file of their own (the file's first frames, or frames after a tag
    or at a Xing/Info frame: another recording joined on). ``count_low``: a file's first run, whose Xing/Info
    frame declares fewer frames than the file holds (its byte count says so, the frames past the count go
    on in its bit reservoir, or one whole frame past it ends the data): a decoder would stop early."""

    start: int
    end: int
    sample_rate: int
    channels: int
    layer: int
    samples: int
    new_file: bool
    count_low: bool = False
    losses: list[MpegLoss] = field(default_factory=list)

    @property
    def frame_samples(self) -> int:
        # 576 in layer III below 32 kHz only (MPEG-2 and 2.5: one granule); layer II has 1152 at any rate
        return 384 if self.layer == 1 else 1152 if self.layer == 2 or self.sample_rate >= 32000 else 576

    @property
    def frames(self) -> int:
        return self.samples // self.frame_samples


@dataclass
class MpegLoss:
    """Damaged bytes inside a run of MPEG frames (``start`` to ``end``), or before a file's first frame
    (where they start as a frame's header does: ``coded`` 0), where no frame header is found:
    ``frames`` frames lost there, ``coded`` samples (per channel) coded in the run before them. ``exact``:
    their number is known (see ``_count_lost``), else estimated from the bytes damaged."""

    start: int
    end: int
    coded: int
    frames: int = 0
    exact: bool = False
    # it runs to the end of the data, or to tags that end it: nothing after it to keep on time
    ends: bool = False
    # it runs to the tag or Xing/Info frame a file joined on begins with: its file's last frames, counted
    # as at the end (from the count its own Xing/Info frame declares), put back as silence (sound follows)
    before_join: bool = False
    # before a file joined on, bytes that start no frame and no frame count to tell whether they held any
    # (damage, or a tag not known here; not a Lyrics3 tag nor an APE tag without a header, ``_lone_tag``):
    # the frames they could hold, said, none put back
    unsure: int = 0
    # it runs to the end from the last frames of sound: bytes after them in which frames of another sample
    # rate chained by chance (``_junk_after``): no frames lost, left out, said
    junk: bool = False

    @property
    def last(self) -> bool:
        """Whether it runs to where its file's frames end (the end of the data, tags, a file joined on)."""
        return self.ends or self.before_join


def mpeg_runs(data: bytes | _FileBytes) -> list[MpegRun]:
    """The runs of frames of an MPEG audio stream (an .mp3's bytes), split where another file was joined
    on or where the sample rate, channel count or layer changes; tags skipped. One run: a plain file.
    Damage inside a run, where frames may have been lost, is in its ``losses``."""
    table = _mpeg_frame_table()
    runs: list[MpegRun] = []
    pos, n, after_tag, tag_start = 0, len(data), True, 0
    # the current run, kept in locals (written to runs[-1] when it ends): this loop runs once per frame
    run_format, end, coded = -1, 0, 0
    last_frame, counted = _NO_COUNT, 0  # the frames its file's Xing/Info header declares, and those seen
    file_ends: tuple[int, ...] = ()  # where the bytes its header declares end (see _count_low)
    file_run = 0  # the run its header begins
    tagged: set[int] = set()  # where runs after a tag start (files joined on: no junk, ``_junk_after``)
    lead: int | None = None  # where stray bytes before a file's first frame start (after a tag, the data's)
    while pos < n - 6:  # a header and its CRC: no frame of sound ends within the last bytes
        frame = table.get(data[pos + 1] << 8 | data[pos + 2]) if data[pos] == 0xFF else None
        if frame is not None and (after_tag or not runs) and _stray_first(data, pos, frame):
            frame = None
        if frame is None:
            skip = _tag_bytes(data, pos)
            if skip:
                pos, after_tag, tag_start = pos + skip, True, pos if not after_tag else tag_start
                lead = None
                continue
            found = _resync(data, pos + 1)  # stray bytes inside a file: not a join
            if runs and not after_tag:
                _note_damage(data, runs[-1], end, found, coded)
            elif lead is None:
                lead = pos
            if found is None:
                break
            pos = found
            continue
        size, samples = frame[0], frame[1]
        mono = data[pos + 3] >= 0xC0
        # a header frame holds no sound: its side information is zeros (a cheap test first, once per frame)
        header = not data[pos + frame[6]] and _is_file_header(data, pos, frame)
        counted += 1
        if frame[4] | mono == run_format and not (after_tag or header or counted > last_frame):
            pos, end, coded = pos + size, pos + size, coded + samples
            continue
        # frames past the count a file declares are another file (LAME counts them without its Info frame;
        # one more frame at the very end is none: the file's own, below, or a cut tail)
        past_count = counted > last_frame and _mpeg_frame(data, pos + size) is not None
        if past_count and not _starts_reservoir(data, pos, frame):
            # its sound begins in the bytes of frames before it: the same file, whose count is wrong (a
            # file edited after encoding); read on as one, the count no more trusted (split there, the
            # part after it would lose the start of its sound: a click). Read whole, the count corrected:
            # a decoder that trusts it stops there (libsndfile: 1152 samples lost per frame uncounted)
            past_count, last_frame = False, _NO_COUNT
            runs[file_run].count_low = _stops_at_count(data, runs[file_run].start)
        elif past_count and _count_low(data, pos, size, file_ends):
            # its sound starts in its own bytes, as a file's first frame does, but the byte count of the
            # same header says the file goes on: only the count is wrong. Read whole, the count corrected
            # (split there, FFmpeg trimmed the file's padding from the middle and restarted its filter
            # bank: about a frame lost, the sound after it early)
            past_count, last_frame = False, _NO_COUNT
            runs[file_run].count_low = True
        elif counted > last_frame and not (header or after_tag) and _ends_stream(data, pos + size):
            # one whole frame past the count ends the file (no frame follows it, only its tags): the file's
            # last, uncounted (a partial frame there is a cut tail, left to the decoder as before)
            last_frame = _NO_COUNT
            runs[file_run].count_low = _stops_at_count(data, runs[file_run].start)
        joined = not runs or after_tag or header or past_count  # a file's first frame
        new_file = joined or frame[3] != runs[-1].layer
        if not new_file and frame[4] | mono == run_format:
            end, coded = pos + size, coded + samples
        elif joined or _confirmed(data, pos, frame, end_confirms=False):
            # a change of layer or channels needs a frame of its format after it (a header in damaged bytes
            # has none: no file of another rate to refuse). A change of channels whose sound starts in the
            # frame's own bytes: an encoder's first frame (an encoder cannot change channels mid-stream), so
            # another file, joined on bare: its priming is dropped or noted as a later file's
            new_file = new_file or _starts_reservoir(data, pos, frame)
            if runs:
                runs[-1].end, runs[-1].samples = end, coded
            runs.append(MpegRun(pos, pos + size, frame[2], 1 if mono else 2, frame[3], samples, new_file))
            run_format, end, coded = frame[4] | mono, pos + size, samples
            if after_tag:
                tagged.add(pos)
            if (
                joined
                and lead is not None
                and (
                    _starts_sync(data, lead)
                    or not _starts_reservoir(data, pos, frame)
                    or (not header and _frames_apart(data, lead, pos, frame))
                )
            ):
                # its first frames' bytes damaged, their header's sync left, or this frame's sound begins in
                # the bytes before it (a bit reservoir, which a file's first frame has none of), or they are
                # as long as frames of its format (unless it is a Xing/Info frame, which a file begins with):
                # frames lost before its first
                runs[-1].losses.append(MpegLoss(lead, pos, 0))
            lead = None
            if new_file:
                file_run = len(runs) - 1
                last_frame, counted = (_file_header_frames(data, pos, frame) if header else 0) or _NO_COUNT, 0
                # read whole, its count set (``_counted_whole``): FFmpeg drops the delay and padding then
                runs[-1].count_low = header and _uncounted_gapless(data, pos, frame)
                declared = _file_header_bytes(data, pos, frame) if header else 0
                file_ends = (pos + declared, (tag_start if after_tag else pos) + declared) if declared else ()
        else:  # a lone header of another format or layer (damage): stray bytes
            found = _resync(data, pos + 1)
            _note_damage(data, runs[-1], end, found, coded)
            if found is None:
                break
            pos = found
            continue
        pos, after_tag = pos + size, False
    if runs:
        runs[-1].end, runs[-1].samples = min(end, n), coded
    _junk_after(data, runs, tagged)
    _count_lost(data, runs)
    return runs


# Consecutive frames of one format, no damage between them, that only sound holds: junk dense in 0xFF
# bytes (a picture written after the audio) chains a few frame headers by chance (each header's next one
# found where its size says, in that format: each frame more about 1 in 45 as likely; 5 at most in 600 MB
# of it), never a run of 8 frames (a 0.3 s clip joined on at 16 kHz or more holds as many) nor one half a
# second long (fewer, longer frames: layer III at 8 to 12 kHz)
_REAL_RUN_FRAMES = 8
_REAL_RUN_S = 0.5


def _clean_frames(run: MpegRun) -> int:
    """The longest stretch of ``run``'s frames that follow one another without damage between them."""
    marks = [0, *(loss.coded for loss in run.losses), run.samples]
    return max(b - a for a, b in zip(marks, marks[1:])) // run.frame_samples


def _real_run(data: bytes | _FileBytes, run: MpegRun, tagged: set[int]) -> bool:
    """Whether ``run`` is sound, not frame headers that junk formed by chance: it begins after a tag
    (``tagged``: where runs after one start) or at a Xing/Info/VBRI frame (``_begins_file``), or holds
    ``_REAL_RUN_FRAMES`` frames, or ``_REAL_RUN_S`` of them, without damage (``_clean_frames``), or begins as
    an encoder's output does (``_begins_sound``)."""
    clean = _clean_frames(run)
    return (
        clean >= min(_REAL_RUN_FRAMES, _REAL_RUN_S * run.sample_rate / run.frame_samples)
        or run.start in tagged
        or _begins_file(data, run.start)
        or clean == run.frames
        and _begins_sound(data, run)
    )


def _begins_sound(data: bytes | _FileBytes, run: MpegRun) -> bool:
    """Whether the layer III frames of ``run`` (2 or more, without damage) begin as an encoder's output does:
    the first one's sound in its own bytes (``_starts_reservoir``), each one's side information a frame of
    sound's (``_holds_sound``). A clip of under 8 frames joined on bare does (0.1 s at 44.1 kHz: 4 frames);
    frames that junk chains by chance seldom: 1 in 3000 of random bytes' first frames, 1 in 8 of each next
    one, none of 100,000 of bytes 90 % 0xFF."""
    if run.layer != 3 or run.frames < 2:
        return False
    pos = run.start
    for _ in range(run.frames):
        frame = _mpeg_frame(data, pos)
        if (
            frame is None
            or not _holds_sound(data, pos, frame)
            or pos == run.start
            and not _starts_reservoir(data, pos, frame)
        ):
            return False
        pos += frame[0]
    return True


def _junk_after(data: bytes | _FileBytes, runs: list[MpegRun], tagged: set[int]) -> None:
    """Takes the runs after an .mp3's last real one out of ``runs`` when one of them is of another format
    than it (sample rate, layer or channels): frame headers that bytes after its audio formed by chance
    (junk appended, a cover picture written after it), not a file joined on at that rate (refused), of that
    layer or channel count (decoded, mixed to its channels). A real run is the first, or ``_real_run``. Their
    bytes are the last real run's damage at its end, junk (``MpegLoss.junk``): no frames lost, left out,
    said."""

    def form(run: MpegRun) -> tuple[int, int, int]:
        return run.sample_rate, run.layer, run.channels

    if all(form(run) == form(runs[0]) for run in runs):
        return  # (no look at the runs' bytes: a block of the file read again each)
    real = max(i for i, run in enumerate(runs) if not i or _real_run(data, run, tagged))
    last = runs[real]
    if all(form(run) == form(last) for run in runs[real + 1 :]):
        return
    del runs[real + 1 :]
    if not (last.losses and last.losses[-1].start == last.end):
        last.losses.append(MpegLoss(last.end, last.end, last.samples))
    loss = last.losses[-1]
    loss.end, loss.ends, loss.before_join, loss.junk = max(_end_tags_at(data), last.end), True, False, True


def _stray_first(data: bytes | _FileBytes, pos: int, frame: _MpegFrame) -> bool:
    """Whether the header at ``pos``, where a file's first frame would be (after a tag, at the data's
    start), was formed by damage over that frame: no frame of its format follows it, the next that is
    followed by one (``_resync``) is of another format (version, layer, sample rate) or channel count, and
    it is no file's header frame. Taken for a file's first frame, it made the file one joined to a file at
    another rate (refused), or a mono file's sound mixed to the 2 channels of that header."""
    if _confirmed(data, pos, frame) or _begins_file(data, pos):
        return False
    found = _resync(data, pos + 1)
    after = None if found is None else _mpeg_frame(data, found)
    return after is not None and (
        after[4] != frame[4] or _mpeg_channels(data, found) != _mpeg_channels(data, pos)
    )


# frames the damage at a file's start may have destroyed that ``_frames_apart`` tells by their length: a
# wiped first frame or a few; more is a header not known here (stray bytes of some length match whole frames
# about 1 in 200 times: a fill of seconds where nothing was lost)
_FIRST_FRAMES_LOST_MAX = 4


def _frames_apart(data: bytes | _FileBytes, lead: int, pos: int, frame: _MpegFrame) -> bool:
    """Whether the stray bytes from ``lead`` (where a file's first frame would start: the data's start, a
    tag's end) to its first frame found, at ``pos``, are as long as a whole number of frames at its bit
    rate (their mean size, to the padding slot: 4 bytes in layer I, else 1), at most
    ``_FIRST_FRAMES_LOST_MAX``: its first frames, their headers destroyed by damage (at a constant bit
    rate). What else lies there (a tag not known here, a writer's zeros) is seldom that long to the byte;
    zeros alone are no frames (a tagger's padding written past the size its ID3v2 tag declares). Layer I
    and II frames, and a layer III frame after silence (no bit reservoir used), begin their sound in their
    own bytes as a file's first frame does: only their length tells them lost (read a frame early,
    unsaid). A Xing/Info frame whose header's sync was wiped (its text left) is no sound lost."""
    mean = _mean_frame_bytes(data, pos, frame)
    frames = round((pos - lead) / mean)
    if any(data.startswith(_XING_TEXTS, lead + at) for at in frame[5]) or data.startswith(b"VBRI", lead + 36):
        return False
    if not (
        0 < frames <= _FIRST_FRAMES_LOST_MAX
        and abs(pos - lead - frames * mean) <= (4 if frame[3] == 1 else 1)
    ):
        return False
    return data[lead:pos].count(0) < pos - lead


def _mean_frame_bytes(data: bytes | _FileBytes, pos: int, frame: _MpegFrame) -> float:
    """The mean bytes of frames at the bit rate of the frame at ``pos``, their padding slots counted."""
    version, index = data[pos + 1] >> 3 & 3, data[pos + 2] >> 4
    kbps = (_MPEG1_KBPS if version == 3 else _MPEG2_KBPS)[frame[3]][index - 1]
    return frame[1] * kbps * 125 / frame[2]  # bytes: samples / 8 * bits per second / rate


def _note_damage(data: bytes | _FileBytes, run: MpegRun, end: int, found: int | None, coded: int) -> None:
    """Stray bytes from ``end`` (where the run's last frame ends, ``coded`` samples in) to a frame at
    ``found``: damage, frames may be lost there. Up to the end of the data (``found`` None: to the tags
    that end it, ``_end_tags_at``) or to tags that end it: damage at its end (``MpegLoss.ends``); up to a
    tag or a Xing/Info frame a file joined on begins with (the damage may have wiped its tag's header):
    damage at its file's end, the sound after it kept on time (``MpegLoss.before_join``). A lone header of
    another format at ``found`` resyncs on from it: the same damage, running on. A header in the data's
    last bytes (junk's, its frame past the data's end), where ``mpeg_runs`` reads no frame, is its end."""
    if found is not None and found >= len(data) - 6:
        found = None
    tag = found is not None and bool(_tag_bytes(data, found))
    ends = found is None or tag and _ends_stream(data, found)
    joined = not ends and found is not None and (tag or _begins_file(data, found))
    stop = max(_end_tags_at(data), end) if found is None else found
    if run.losses and run.losses[-1].start == end:
        loss = run.losses[-1]
        loss.end, loss.ends, loss.before_join = stop, ends, joined
    elif stop > end:
        run.losses.append(MpegLoss(end, stop, coded, ends=ends, before_join=joined))


def _begins_file(data: bytes | _FileBytes, pos: int) -> bool:
    """Whether the frame at ``pos`` is a file's Xing/Info or VBRI frame (``_is_file_header``): its side
    information zeros, no sound. ``mpeg_runs`` makes the same test inline, its frame at hand (once per frame:
    no call, no second parse of the header)."""
    frame = _mpeg_frame(data, pos)
    return (
        frame is not None
        and pos + frame[6] < len(data)  # a header at the data's end: no side information
        and not data[pos + frame[6]]
        and _is_file_header(data, pos, frame)
    )


def _end_tags_at(data: bytes | _FileBytes) -> int:
    """Where the tags at the end of an .mp3 start (an ID3v1 tag, the extended one before it, an APEv2 tag
    before them); its length when it ends in none."""
    end = len(data)
    if end >= 128 and data.startswith(b"TAG", end - 128):
        end -= 128
        end -= 227 if end >= 227 and data.startswith(b"TAG+", end - 227) else 0
    if end >= 32 and data.startswith(b"APETAGEX", end - 32):
        size, flags = struct.unpack("<4xI4xI", data[end - 24 : end - 8])
        end = max(end - size - 32 * (flags >> 31), 0)  # its items and footer, its header when it has one
    return end


def _starts_sync(data: bytes | _FileBytes, pos: int) -> bool:
    """Whether the bytes at ``pos`` start with a frame header's sync (11 bits set)."""
    head = data[pos : pos + 2]
    return len(head) == 2 and head[0] == 0xFF and head[1] >= 0xE0


def _count_lost(data: bytes | _FileBytes, runs: list[MpegRun]) -> None:
    """The frames lost at each damage of ``runs`` (``MpegRun.losses``), each estimated from the bytes
    damaged at its file's mean bytes per frame (frames overwritten at a constant bit rate: exact, up to the
    padding byte; running to the end of the data, its tags or a file joined on, only when they start with a
    frame's sync, a damaged header: else they are what follows the last frame, zeros, junk, a Lyrics3 tag,
    no frame lost, and before a file joined on what they could hold is said, ``MpegLoss.unsure``);
    then, in a file whose Xing/Info frame declares its frame count (not too low), set to the count less the
    frames found when the estimates agree with it (a file cut short as well: they do not), exact when
    damaged once or the estimates add up to it; damage at its end, to what the count misses."""
    starts = [i for i, run in enumerate(runs) if run.new_file] + [len(runs)]
    for a, b in zip(starts, starts[1:]):
        losses = [loss for run in runs[a:b] for loss in run.losses if not loss.junk]
        if not losses:
            continue
        overwritten = _overwritten(data, runs[a], max(runs[b - 1].end, losses[-1].end))
        # the file's mean bytes per frame (a run may be one frame: a lone header damage left of another
        # format); damage between a run's frames is within its bytes, at its end (before the next run) not
        per_frame = _frame_bytes(runs[a:b]) / sum(max(run.frames, 1) for run in runs[a:b])
        for loss in losses:
            # at a file's end, bytes that start as no frame does (zeros, junk, a Lyrics3 tag) are no
            # frames; before a file joined on, said as what they could hold
            estimate = round((loss.end - loss.start) / per_frame)
            if loss.end == runs[a].start:  # before its first frame
                estimate = _frames_before_first(data, loss, per_frame, estimate)
            seen = not loss.last or overwritten or _starts_sync(data, loss.start)
            loss.frames = estimate if seen else 0
            unknown = not (seen or _lone_tag(data, loss.start, loss.end))
            loss.unsure = estimate if loss.before_join and unknown else 0
        frame = _mpeg_frame(data, runs[a].start)
        if frame is None or runs[a].count_low or not _is_file_header(data, runs[a].start, frame):
            continue
        declared = _file_header_frames(data, runs[a].start, frame)
        lost = declared - (sum(run.frames for run in runs[a:b]) - 1)  # its header frame holds no sound
        if overwritten and lost < sum(loss.frames for loss in losses):
            # fewer than the bytes damaged held: the count is too low (a file edited after encoding), the
            # damage hid it from ``mpeg_runs``: read whole, its count set (``_counted_whole``)
            runs[a].count_low = True
            continue
        if declared and lost >= 0 and losses[-1].last:  # its end: what the count misses past the others
            end = losses.pop()
            end.frames, end.exact, end.unsure = max(lost - sum(loss.frames for loss in losses), 0), True, 0
            lost -= end.frames
            if not losses:
                continue
        estimated = sum(loss.frames for loss in losses)
        if not declared or lost < 0 or abs(lost - estimated) > max(1, estimated // 2):
            continue
        largest = max(losses, key=lambda loss: loss.end - loss.start)
        largest.frames = max(0, largest.frames + lost - estimated)
        for loss in losses:
            loss.exact = len(losses) == 1 or estimated == lost


def _frame_bytes(runs: list[MpegRun]) -> int:
    """The bytes of the frames of ``runs``: damage between a run's frames is within its bytes, at its end
    (before the next run) not."""
    within = sum(
        loss.end - loss.start
        for run in runs
        for loss in run.losses
        if run.start <= loss.start and loss.end <= run.end
    )
    return sum(run.end - run.start for run in runs) - within


def _refuse_no_mpeg_audio(path: Path, data: bytes | _FileBytes, runs: list[MpegRun]) -> None:
    """An ``InputError`` when the .mp3 ``data`` (its runs ``runs``) holds no MPEG audio: no run of 2 or more
    frames without damage starts where its audio would (after its leading tags; 0xFF-dense junk chains a
    frame or damaged frames there by chance, in 1 to 3 % of 100 KB of it), no run of its frames is sound
    (``_real_run``), fewer than ``_REAL_RUN_FRAMES`` of its frames may be sound (``_sound_frames``: a file
    wrecked by garbage over half its bytes, no 8 frames in a row left, has dozens) and its frames are under
    half its bytes (a short file damaged at its start is mostly frames): only frame headers that its bytes
    form by chance (junk, a picture named .mp3; decoded, 100 KB of it gave 768 samples of noise, 1 MB of
    random bytes 168 s of silence put back for the "damage" between them). The bytes of a file mostly
    frames are not read again (its first block, for its tags: 2 MB more read)."""
    frames = _frame_bytes(runs)
    if 2 * frames >= len(data):
        return
    start = 0
    while skip := _tag_bytes(data, start):
        start += skip
    span = _end_tags_at(data) - start
    first = runs[0] if runs else None
    at_start = first is not None and first.start == start and _clean_frames(first) == first.frames > 1
    if span <= 0 or 2 * frames >= span or at_start:
        return
    if any(_real_run(data, run, set()) for run in runs):
        return
    if sum(_sound_frames(data, run) for run in runs) >= _REAL_RUN_FRAMES:
        return
    most = max((_clean_frames(run) for run in runs), default=0)
    raise InputError(
        f"no MPEG audio found in its {len(data)} bytes: only frame headers its bytes form by chance (at "
        f"most {most} frame(s) in a row; sound has {_REAL_RUN_FRAMES} or more): junk, or not an .mp3?",
        path,
    )


def _sound_frames(data: bytes | _FileBytes, run: MpegRun) -> int:
    """How many frames of ``run`` may be sound, walked from frame to frame over the stretches between its
    damage: layer III frames whose side information a frame of sound has (``_holds_sound``), any layer II
    frame (none to tell by), no layer I frame (the headers 0xFF-dense junk chains by chance are of layer
    I: ``0xFFFx``)."""
    if run.layer == 1:
        return 0
    count, pos = 0, run.start
    for stop, resume in [*((loss.start, loss.end) for loss in run.losses), (run.end, run.end)]:
        while pos < stop and (frame := _mpeg_frame(data, pos)) is not None:
            count += run.layer == 2 or _holds_sound(data, pos, frame)
            pos += frame[0]
        pos = max(pos, resume)
    return count


def _frames_before_first(data: bytes | _FileBytes, loss: MpegLoss, per_frame: float, estimate: int) -> int:
    """The frames lost at ``loss``, before a file's first frame found (at its end), when the file's bit rate
    varies (its mean frame ``per_frame`` bytes, not its first frame's bit rate's, to the padding slot) and
    their bytes are not as long as ``estimate`` frames of that mean but as one frame of its format at some
    bit rate (with or without padding), whose bytes hold all the bit reservoir the first frame found begins
    its sound in (else bytes before them were lost: a file cut mid-frame): one. A VBR file's first frame,
    its header destroyed (LAME's first is its largest, at 44.1 kHz 835 bytes, or after silence its
    smallest, 104, the file's mean 460: 2 and 0 frames were estimated, the sound a frame late or early)."""
    length, pos = loss.end - loss.start, loss.end
    frame = _mpeg_frame(data, pos)
    slot = 4 if frame is not None and frame[3] == 1 else 1
    if (
        frame is None
        or estimate
        and abs(length - estimate * per_frame) <= slot
        or abs(per_frame - _mean_frame_bytes(data, pos, frame)) <= slot  # a constant bit rate: its mean tells
        or _reservoir_bytes(data, pos, frame) > length - (_xing_at(data, pos, frame) - pos)  # past them
    ):
        return estimate
    return 1 if any(f[4] == frame[4] and f[0] == length for f in _MPEG_FRAMES.values()) else estimate


def _lone_tag(data: bytes | _FileBytes, start: int, end: int) -> bool:
    """Whether the bytes from ``start`` to ``end`` (before a file joined on) are a tag ``_tag_bytes`` does
    not tell from its start: a Lyrics3 tag ("LYRICSBEGIN" first), or an APE tag without a header (its
    footer, ending them, counts them all)."""
    if data.startswith(b"LYRICSBEGIN", start):
        return True
    if end - start < 32 or not data.startswith(b"APETAGEX", end - 32):
        return False
    (size,) = struct.unpack("<4xI", data[end - 24 : end - 16])  # its items and footer
    return size == end - start


def _overwritten(data: bytes | _FileBytes, first: MpegRun, end: int) -> bool:
    """Whether the damage of the file whose first run is ``first``, its frames and damage ending at ``end``,
    overwrote its frames' bytes (none cut out nor put in), their bit rate constant: its Info frame (not
    Xing: LAME's mark of a constant bit rate) declares a byte count it ends at. The frames lost are then
    what the bytes damaged hold, exactly (``_count_lost``), bytes at its end that start no frame too."""
    frame = _mpeg_frame(data, first.start)
    return (
        frame is not None
        and _is_file_header(data, first.start, frame)
        and data.startswith(b"Info", _xing_at(data, first.start, frame))
        and bool(_file_header_bytes(data, first.start, frame))
        and _ends_as_declared(data, first, end)
    )


def _read_joined_mpeg(
    path: Path,
    data: bytes | _FileBytes,
    runs: list[MpegRun],
    repairs: list[dict[str, Any]] | None,
    sink_of: _SinkOf | None = None,
) -> Audio:
    """An .mp3 made of several files joined end to end (``cat a.mp3 b.mp3``), or whose channel count or
    layer changes mid-stream: each joined file decoded on its own, so each one's encoder delay and padding
    (its LAME tag) is dropped, and the later ones mixed to the first one's channel count (repair
    ``channels_changed``). libsndfile would stop at the first file's frame count or at the first change
    of channels, FFmpeg at the first tag in the middle. A later file that records no delay: see
    ``_JoinedPart``; a file whose Info frame counts too few frames: corrected (``_counted_whole``). A
    change of sample rate is an ``InputError``. ``sink_of``: the frames are written a block at a time into
    the scratch file it makes (``_streamed``), the audio a ``FileAudio`` of it; else into one array as they
    come (``_Samples``: held once)."""
    first = runs[0]
    coded = 0
    for run in runs:
        if run.sample_rate != first.sample_rate:
            raise InputError(
                f"the MP3's sample rate changes from {first.sample_rate} to {run.sample_rate} Hz at about "
                f"{coded / first.sample_rate:.3f} s (recordings joined into one file?): split it there and "
                "convert the parts to one rate",
                path,
            )
        coded += run.samples
    starts = [i for i, run in enumerate(runs) if run.new_file] + [len(runs)]
    kept = _Samples(coded) if sink_of is None else sink_of(lambda: first.sample_rate)
    sample_format, damaged, last = "flt", 0, len(starts) - 2
    for k, (a, b) in enumerate(zip(starts, starts[1:])):
        at = kept.used / first.sample_rate
        mended = _mended(data, runs[a:b], path, at, repairs)
        _counted_whole(mended, data, runs[a:b])
        part = _JoinedPart(kept)
        if k and _ends_as_declared(data, runs[starts[k - 1]], runs[a].start):
            part.drops_lame_delay(data, runs[a], runs[b - 1].end)
        try:
            # the note of an unknown encoder delay is about the start: the first file's
            decoded = _decode_frames(
                mended,
                path,
                0,
                repairs if k == 0 else None,
                skip_damaged=True,
                into=lambda _stream, part=part: part,
            )
        except InputError:
            if k == 0 or mended.failed is not None or isinstance(data, _FileBytes) and data.shrunk():
                raise  # the file, not the part: unread (cut short as it is read, unreadable)
            # too short for FFmpeg to open (a file cut short): silence in its place, unless it ends the audio
            damaged += sum(run.frames for run in runs[a:b])
            if k < last:
                lost = sum(run.samples for run in runs[a:b])
                kept.append(np.zeros((lost, kept.channels if kept else first.channels), np.float32))
            continue
        if part.delay_unknown and repairs is not None:
            repairs.append(
                {
                    "line": None,
                    "kind": "encoder_delay_unknown",
                    "message": f"{shown_name(path)}: the MP3 file joined on at {at:.3f} s does not record "
                    "its encoder's delay (no LAME tag) nor begins as LAME's output does: its priming "
                    "samples are kept there, so the sound after it may be up to "
                    f"~{_priming_ms(first.sample_rate)} ms late",
                }
            )
        if part.padding_unknown and k < last and repairs is not None:
            repairs.append(_padding_kept_note(path, at, kept.used / first.sample_rate, runs[a]))
        sample_format, damaged = decoded.sample_format, damaged + decoded.damaged
    if not kept:
        raise InputError("audio stream holds no samples", path)
    _note_channels_changed(path, repairs, kept.changed, kept.first_changed, first.sample_rate, kept.channels)
    if repairs is not None and damaged:
        repairs.append(
            {
                "line": None,
                "kind": "bad_audio",
                "message": f"{shown_name(path)}: {damaged} damaged MPEG audio frame(s) could not be decoded: "
                "silence in their place (at the end: left out)",
            }
        )
    if isinstance(kept, _DecodedToFile):
        return kept.finish(None, first.sample_rate, sample_format)
    return _in_recorded_format(kept.take(), first.sample_rate, sample_format)


# What FFmpeg decodes from a LAME-encoded MP3 that does not record its delay (no LAME tag) starts this many
# samples before the sound: the encoder's 576 of look-ahead and the synthesis filter bank's 528 + 1 (the
# decoder's). Measured on libmp3lame's output (FFmpeg's write_xing=0) at 8 to 48 kHz, mono and stereo:
# the encoded signal lies 1105 samples in, and 0 with the tag.
LAME_DELAY = 576 + 529
# LAME fills the bits a frame leaves unused (ancillary data: at least in its last frames, where it drains
# its bit reservoir) with its name and version, "LAME3.100UUUU...": what tells its output without a tag.
# Its name only: the version may be left out (too few bits) or cut by the next frame's header
_LAME_SIGNATURE = b"LAME"
# It lies in a file's last frames: looked for in its last bytes only (the frames before, the bit reservoir
# of the last one: a few KB at most), not in a whole hour of it
_LAME_SIGNATURE_SPAN = 1 << 14
# The encoder versions a LAME tag starts with whose delay and padding FFmpeg drops (LAME's, FFmpeg's own)
_GAPLESS_ENCODERS = (_LAME_SIGNATURE, b"Lavf", b"Lavc")


def _mended(
    data: bytes | _FileBytes, runs: list[MpegRun], path: Path, at: float, repairs: list[dict[str, Any]] | None
) -> _MendedPart:
    """One file of an .mp3 (``runs``: its runs; it starts ``at`` seconds in) as FFmpeg is to decode it,
    each damage where frames were lost (``MpegRun.losses``) replaced by as many silent frames: the sound
    after it keeps its time (damage at its end, ``MpegLoss.ends``, left out: no sound after it). Each noted
    in ``repairs`` (repair ``bad_audio``): where, how long, and when the frames lost were counted from the
    damaged bytes, by how much the sound after it may be shifted."""
    pieces: list[range | tuple[bytes, int]] = []
    pos = runs[0].start
    first = _mpeg_frame(data, pos) if _no_sound_first(data, runs[0]) else None
    if first is not None:  # no sound: left out (FFmpeg decodes a VBRI frame declaring no count as silence)
        pos += first[0]
        if repairs is not None and _header_destroyed(data, runs[0]):
            repairs.append(_header_destroyed_note(path, at))
    coded = -_dropped_at_start(data, runs[0], runs[0].count_low)  # samples (per channel) before the run's
    for run in runs:
        for loss in run.losses:
            if not (loss.frames or loss.unsure or loss.junk):
                continue
            if repairs is not None:
                # (lost in the encoder's delay FFmpeg drops: said at the file's start)
                start = max(at + (coded + loss.coded) / run.sample_rate, at)
                repairs.append(_loss_note(path, start, loss, run))
            if loss.ends or not loss.frames:  # nothing after it to keep on time, or none known lost
                continue
            # (damage before the file's first frame: the silence before it)
            silent = _silent_frame(data, run.start, loss.end)
            pieces += [range(pos, max(pos, loss.start)), (silent, loss.frames)]
            pos = loss.end
            coded += loss.frames * run.frame_samples
        coded += run.samples
    part = _MendedPart(data, [*pieces, range(pos, runs[-1].end)])
    if pieces:
        # damage up to a file joined on (``MpegLoss.before_join``) lies past the file's frames, over its
        # last ones and maybe the next file's tag: the byte count grows by the frames put in
        _move_bytes_declared(part, data, runs[0].start, part.size - (runs[-1].end - runs[0].start))
    return part


class _MendedPart:
    """One file of an .mp3 as FFmpeg is given it (``_mended``): ``pieces``, in order, each a range of the
    bytes of ``data`` (the file, read a block at a time: ``_FileBytes``) or a silent frame and how many
    times it is put in, and ``patches`` (where, bytes) written over them (its Xing/Info frame's counts).
    Read as FFmpeg asks for it (a file-like object), never held whole: a damaged or joined hour at 320
    kbit/s held its 144 MB twice. ``failed``: what a read raised (the file cut short as it is read,
    Ctrl-C), raised again once FFmpeg stops (``_decode_frames``): raised to FFmpeg, PyAV printed it and
    may drop it, the decoding ended there as if the file did (Ctrl-C: the audio returned short)."""

    def __init__(self, data: bytes | _FileBytes, pieces: list[range | tuple[bytes, int]]):
        self.data, self.pieces = data, pieces
        self.starts = list(accumulate((_piece_size(piece) for piece in pieces), initial=0))
        self.size, self.pos = self.starts[-1], 0
        self.patches: list[tuple[int, bytes]] = []
        self.failed: BaseException | None = None

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self.pos

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        self.pos = max(offset + (0, self.pos, self.size)[whence], 0)
        return self.pos

    def read(self, size: int = -1) -> bytes:
        if self.failed is None:
            try:
                return self._read(size)
            except BaseException as exc:  # raised again once FFmpeg stops
                self.failed = exc
        return b""  # the end, to FFmpeg

    def _read(self, size: int) -> bytes:
        start = self.pos
        end = self.size if size < 0 else min(start + size, self.size)
        out = bytearray()
        i = bisect.bisect_right(self.starts, start) - 1
        while start < end and i < len(self.pieces):
            piece, lo = self.pieces[i], start - self.starts[i]
            hi = min(end, self.starts[i + 1]) - self.starts[i]
            if isinstance(piece, range):
                out += self.data[piece.start + lo : piece.start + hi]
            else:  # frames lo // n to (hi - 1) // n of the silent ones
                n = len(piece[0])
                out += (piece[0] * ((hi - 1) // n - lo // n + 1))[lo % n : lo % n + hi - lo]
            start, i = self.starts[i] + hi, i + 1
        for at, value in self.patches:
            lo, hi = max(at, self.pos), min(at + len(value), self.pos + len(out))
            if lo < hi:
                out[lo - self.pos : hi - self.pos] = value[lo - at : hi - at]
        self.pos += len(out)
        return bytes(out)


def _piece_size(piece: range | tuple[bytes, int]) -> int:
    return len(piece) if isinstance(piece, range) else len(piece[0]) * piece[1]


def _move_bytes_declared(part: _MendedPart, data: bytes | _FileBytes, start: int, change: int) -> None:
    """Moves the byte count the Xing/Info frame of ``part`` (one file of an .mp3, from its first frame, at
    ``start`` in ``data``) declares by ``change``, the bytes its silent frames put in less the damaged ones
    they replace: FFmpeg trims no encoder padding from a file over 1/16 longer than it declares (a
    "concatenated file"; 6 frames put in a 1 s file at 32 kbit/s: 875 samples more, none said)."""
    frame = _mpeg_frame(data, start)
    at = (
        _byte_count_at(data, start, frame) if frame is not None and _is_file_header(data, start, frame) else 0
    )
    if at:
        declared = int.from_bytes(data[at : at + 4], "big") + change
        part.patches.append((at - start, min(max(declared, 0), 2**32 - 1).to_bytes(4, "big")))


def _loss_note(path: Path, start: float, loss: MpegLoss, run: MpegRun) -> dict[str, Any]:
    """The repair ``bad_audio`` of the frames of ``run`` lost at ``loss``, ``start`` seconds in."""
    lost = loss.frames * run.frame_samples
    if loss.junk:
        message = (
            f"{shown_name(path)}: {loss.end - loss.start} bytes after the MPEG audio's last frames (at about "
            f"{start:.3f} s) are no audio: headers of frames of other formats that their bytes form by "
            "chance, no run of them as long as sound (junk appended, a picture written after the audio?): "
            "left out"
        )
        return {"line": None, "kind": "bad_audio", "message": message}
    if loss.unsure:
        most = loss.unsure * run.frame_samples
        message = (
            f"{shown_name(path)}: {loss.end - loss.start} bytes that start no MPEG frame (damage, or a tag "
            f"not known here) lie between the file ending at {start:.3f} s and the file joined on after it: "
            f"if they were frames, up to {loss.unsure} frame(s) ({1000 * most / run.sample_rate:.0f} ms) of "
            "its sound are missing there, the sound after it that much early"
        )
        return {"line": None, "kind": "bad_audio", "message": message}
    if loss.ends:
        about = "up to" if loss.exact else "about"  # the encoder's padding may be in them
        message = (
            f"{shown_name(path)}: damaged MPEG audio at its end, from {start:.3f} s: {loss.frames} frame(s) "
            f"lost there{'' if loss.exact else ' (estimated from the bytes damaged)'}: the audio ends "
            f"{about} {1000 * lost / run.sample_rate:.0f} ms short (no sound after it to keep on time)"
        )
        return {"line": None, "kind": "bad_audio", "message": message}
    message = (
        f"{shown_name(path)}: damaged MPEG audio at {start:.3f} s: {loss.frames} frame(s) lost there ({lost} "
        f"samples, {1000 * lost / run.sample_rate:.0f} ms), put back as silence, so the sound after it "
        "keeps its time"
    )
    if not loss.exact:
        shift = (run.frame_samples if loss.frames == 1 else lost) / run.sample_rate
        message += (
            f"; their number is estimated from the bytes damaged: the sound after "
            f"{start + lost / run.sample_rate:.3f} s may be shifted by up to {1000 * shift:.0f} ms"
        )
    return {"line": None, "kind": "bad_audio", "message": message}


def _header_destroyed_note(path: Path, at: float) -> dict[str, Any]:
    """The repair ``bad_audio`` of a file (``at`` seconds in) whose Xing/Info frame damage destroyed
    (``_header_destroyed``)."""
    return {
        "line": None,
        "kind": "bad_audio",
        "message": f"{shown_name(path)}: the MP3 file at {at:.3f} s begins with a damaged frame that holds "
        "no sound its next frame uses: its Xing/Info header frame (LAME's tag: the encoder's delay and "
        "padding), destroyed: left out; the delay and padding it recorded are lost, so they are kept (the "
        "sound late by the encoder's delay, the end longer by its padding)",
    }


def _silent_frame(data: bytes | _FileBytes, pos: int, after: int | None = None) -> bytes:
    """A frame of silence of the format of the frame at ``pos``: its header without CRC nor padding, the
    rest zeros (no bits of sound: layer III side information of zeros, no layer I/II allocations); its
    channel mode and flags (the header's last byte) those of the frame at ``after`` when it is one of the
    same format (the frame after the damage). FFmpeg opens an .mp3 at the first frame after its Xing/Info
    frame whose header matches the next one's in those bits too: a silent frame there with the Info
    frame's (LAME's: no mode extension, no "original" flag) was skipped, the sound after it a frame early."""
    last = data[pos + 3]
    own, other = _mpeg_frame(data, pos), None if after is None else _mpeg_frame(data, after)
    if own and other and other[4] == own[4] and _mpeg_channels(data, after) == _mpeg_channels(data, pos):
        last = data[after + 3]
    head = bytes([0xFF, data[pos + 1] | 1, data[pos + 2] & ~2 & 0xFF, last])
    frame = _mpeg_frame(head, 0)
    assert frame is not None  # a confirmed frame's header, less CRC and padding
    return head + bytes(frame[0] - 4)


def _padding_kept_note(path: Path, at: float, end: float, first: MpegRun) -> dict[str, Any]:
    """The note (repair ``encoder_delay_unknown``) of a joined file (from ``at`` to ``end`` seconds, its
    first run ``first``) without a LAME tag, another after it: its end keeps its encoder's padding. LAME
    pads the samples it encodes after its 576 of delay to a whole frame, a frame more when that pads fewer
    than 576 (measured at 16 and 44.1 kHz): FFmpeg keeps up to a frame and 47 samples of it."""
    most = first.frame_samples + 576 - _MPG123_GAPLESS_DELAY
    return {
        "line": None,
        "kind": "encoder_delay_unknown",
        "message": f"{shown_name(path)}: the MP3 file joined on at {at:.3f} s does not record its encoder's "
        f"padding (no LAME tag): its end keeps it, so the file joined on after it at {end:.3f} s may be up "
        f"to {1000 * most / first.sample_rate:.0f} ms late",
    }


def _counted_whole(part: _MendedPart, data: bytes | _FileBytes, runs: list[MpegRun]) -> None:
    """One file of a joined .mp3 (``runs``: its runs, in ``data``; ``part``: as FFmpeg is given it), the
    frame count its Xing/Info frame declares set to the frames it holds when that count is low
    (``MpegRun.count_low``): FFmpeg trims the encoder's padding where the count ends. One with no field
    for a count gets one after its flags, the rest of its frame moved on by 4 bytes when they end it in
    zeros (LAME's tag leaves the rest of the frame empty)."""
    start = runs[0].start
    frame = _mpeg_frame(data, start)
    if not runs[0].count_low or frame is None:
        return
    filled = sum(loss.frames for run in runs for loss in run.losses if not loss.ends)  # silent, put in
    count = (sum(run.frames for run in runs) + filled - 1).to_bytes(4, "big")  # its Info frame: no sound
    flags_at, end = _xing_at(data, start, frame) + 7, start + frame[0]
    if data[flags_at] & 1:
        part.patches.append((flags_at + 1 - start, count))
    elif data[end - 4 : end] == bytes(4):
        part.seek(flags_at + 1 - start)  # through its patches: a byte count moved (``_move_bytes_declared``)
        moved = part.read(end - 4 - flags_at - 1)
        part.seek(0)
        part.patches.append((flags_at - start, bytes([data[flags_at] | 1]) + count + moved))


def _ends_as_declared(data: bytes, previous: MpegRun, start: int) -> bool:
    """Whether the file whose first run is ``previous`` ends at ``start`` (tags after it allowed) by the
    byte count its Xing/Info frame declares, or declares none. A file cut short mid-frame runs on into the
    frames of the file joined after it, and is split from them where its frame count ends: mid-sound, at
    a frame that may start as an encoder's first does (no bit reservoir: 320 kbit/s, quiet), which is no
    file's start, and has no priming to drop (1105 samples of sound were lost there)."""
    frame = _mpeg_frame(data, previous.start)
    if frame is None or not _is_file_header(data, previous.start, frame):
        return True
    declared = _file_header_bytes(data, previous.start, frame)
    if not declared:
        return True
    ends = [previous.start + declared]
    tag = start - declared  # some writers count the ID3v2 tag before the header frame too
    if 0 <= tag < previous.start and _tag_bytes(data, tag):
        ends.append(start)
    for end in ends:
        while end < start and _tag_bytes(data, end):
            end += _tag_bytes(data, end)
        if end == start:
            return True
    return False


class _JoinedPart:
    """The frames FFmpeg decodes of one file of a joined .mp3, handed on to ``kept`` (the array or the
    scratch file the files before it went into) as they come, the first ``drop`` samples left out.
    ``last_channels`` and ``last_dtype``: of its last frame, for ``_silence_of``."""

    def __init__(self, kept: _Samples | _DecodedToFile):
        self.kept, self.drop, self.delay_unknown, self.padding_unknown = kept, 0, False, False
        self.last_channels: int | None = None
        self.last_dtype: np.dtype | None = None
        self._later: tuple[bytes | _FileBytes, MpegRun, int] | None = None  # see drops_lame_delay

    def drops_lame_delay(self, data: bytes | _FileBytes, first: MpegRun, end: int) -> None:
        """A joined file after the first (``data[first.start:end]``): when FFmpeg has opened it to decode
        it (``opened``), its encoder delay is looked at."""
        self._later = (data, first, end)

    def opened(self, stream: Any, first_pts: int | None) -> None:
        """FFmpeg's ``stream`` of a later joined file (``drops_lame_delay``), ``first_pts`` its first
        packet's time, before that packet is decoded: when the file records no encoder delay
        (``_delay_known``), LAME's delay dropped, when its bytes are LAME's and start as an encoder's first
        frame does (no bit reservoir); any other encoder's priming kept, ``delay_unknown`` set (for the
        repair ``encoder_delay_unknown``, saying from which second). Its padding, at its end, is kept:
        ``padding_unknown``."""
        if self._later is None or _delay_known(stream, first_pts):  # recorded, or none to record
            return
        data, first, end = self._later
        self.padding_unknown = True  # not recorded either
        frame = _mpeg_frame(data, first.start)
        last = max(first.start, end - _LAME_SIGNATURE_SPAN)  # its last frames
        if (
            frame is not None
            and frame[3] == 3
            and _starts_reservoir(data, first.start, frame)
            and _LAME_SIGNATURE in (data[last:end] if isinstance(data, bytes) else data.aside(last, end))
        ):
            self.drop = LAME_DELAY  # it may span frames (576 samples each below 32 kHz)
        else:
            self.delay_unknown = True

    def append(self, arr: np.ndarray) -> None:
        self.last_channels, self.last_dtype = arr.shape[1], arr.dtype
        if self.drop:
            if len(arr) <= self.drop:
                self.drop -= len(arr)
                return
            arr, self.drop = arr[self.drop :], 0
        self.kept.append(arr)


WRITE_FRAMES = 1 << 16  # frames handed to libsndfile per write


def write_audio(path: str | Path, audio: Audio) -> None:
    """Write WAV with the audio's own subtype (RF64 past 4 GB), atomically. A write the system refuses
    (a full disk) is an ``OSError`` naming ``path``."""
    if isinstance(audio, FileAudio) and not audio.held:  # copied from its file a block at a time
        nbytes, channels, blocks = audio.nbytes, audio.channels, audio.blocks(WRITE_FRAMES)
    else:
        nbytes, channels = audio.samples.nbytes, 1 if audio.samples.ndim == 1 else audio.samples.shape[1]
        # a block at a time: soundfile's file callback copies each buffer libsndfile hands it into
        # bytes, and for a same-format write that buffer is the whole array (+230 MB an hour)
        blocks = (
            audio.samples[lo : lo + WRITE_FRAMES] for lo in range(0, max(audio.frames, 1), WRITE_FRAMES)
        )
    fmt = "RF64" if nbytes > 0xFFFF0000 else "WAV"
    with atomic_write(path, buffering=1 << 20) as f:
        sink = _WavSink(f)
        out: sf.SoundFile | None = None
        try:
            # Ctrl-C or SIGTERM waits for each call of libsndfile to return: met in its callback, it
            # would be lost there (soundfile's AssertionError instead, or a header never written); met
            # while it opens the file, it is closed all the same (else later, into the closed output)
            try:
                with stops_deferred():
                    out = sf.SoundFile(
                        sink, "w", audio.sample_rate, channels, subtype=audio.subtype, format=fmt
                    )
                _no_peak_chunk(out)
                for block in blocks:
                    with stops_deferred():
                        out.write(block)
            finally:
                if out is not None:
                    with stops_deferred():
                        out.close()
        except (AssertionError, sf.SoundFileError):  # soundfile's check that every frame was written
            if sink.error is None:
                raise
        sink.flush()
        if sink.error is not None:
            f.raw.close()  # drops what the buffer holds: closing the file would try the full disk again
            raise OSError(sink.error.errno, sink.error.strerror, str(path)) from None


class _WavSink:
    """The file libsndfile writes a WAV into. The first error of the system (a full disk) is kept in
    ``error`` and reported to libsndfile as nothing written: raised inside its C callback it would only
    be printed ("Exception ignored from cffi callback"), and soundfile would fail on a bare
    AssertionError."""

    def __init__(self, file: IO[bytes]):
        self.file = file
        self.error: OSError | None = None

    def _kept(self, call: Any, *args: Any) -> int:
        if self.error is None:
            try:
                return call(*args)
            except OSError as exc:
                self.error = exc
        return 0

    def write(self, data: bytes) -> int:
        return self._kept(self.file.write, data)

    def seek(self, offset: int, whence: int = 0) -> int:  # flushes what the buffer holds
        return self._kept(self.file.seek, offset, whence)

    def tell(self) -> int:
        return self._kept(self.file.tell)

    def flush(self) -> None:
        self._kept(self.file.flush)


# libsndfile's SFC_SET_ADD_PEAK_CHUNK: float WAVs otherwise carry a PEAK chunk stamped with the wall-clock
# second of writing, so the same samples written twice would differ in bytes (and in content hashes).
_SFC_SET_ADD_PEAK_CHUNK = 0x1050


def _no_peak_chunk(out: sf.SoundFile) -> None:
    """Switch the PEAK chunk off before the first sample is written (a documented libsndfile command,
    reached through soundfile's handle; without that handle the file is written with the chunk)."""
    try:
        sf._snd.sf_command(out._file, _SFC_SET_ADD_PEAK_CHUNK, sf._ffi.NULL, 0)
    except AttributeError:
        pass
