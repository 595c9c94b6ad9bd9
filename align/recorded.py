"""A take's audio as recorded (its own rate, channels and sample format), read a block of frames at a time.

Align needs the recorded samples only to make its 16 kHz mono copy and to look for clipping (``clipping``),
each a pass or two through them in order. Read from the take's WAV a block at a time, an hour of audio at
44.1 kHz (317 MB as int16 mono, 635 MB stereo) is never in memory whole, and nothing of it is left once
the 16 kHz copy is made. The blocks are the samples ``capture.read_audio`` gives, in the same format.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

import numpy as np
import soundfile as sf

from capture import Audio, InputError, Take
from capture.audio_io import FileAudio, libsndfile_name
from capture.take import AudioInfo

# The WAV sample formats read as read_audio reads them (PCM_24 widened to int32): the subtypes write_take
# writes. Anything else (an edited take holding an MP3, a WAV of 8-bit or A-law samples) is read whole.
_NATIVE = {"PCM_16": "int16", "PCM_24": "int32", "PCM_32": "int32", "FLOAT": "float32"}


_CHECK_FRAMES = 1 << 16  # frames per block of the check for NaN in float samples


class RecordedAudio:
    """Recorded samples (frames x channels, ``capture.Audio``'s format) given block by block, from an
    ``Audio`` in memory (``of``), from the take's WAV file (``from_take_file``) or from audio left in its
    file (``recorded``)."""

    def __init__(self, sample_rate: int, channels: int, frames: int, subtype: str, dtype: str):
        self.sample_rate, self.channels, self.frames = sample_rate, channels, frames
        self.subtype, self.dtype = subtype, np.dtype(dtype)
        self._audio: Audio | None = None
        self._file: sf.SoundFile | None = None
        self._path: Path | None = None  # the file's name (``_file.name`` is the bytes it was opened by)
        self._stamp: tuple[int, int, int] | None = None  # the file's (inode, size, mtime) when opened

    @classmethod
    def of(cls, audio: Audio) -> RecordedAudio:
        held = cls(audio.sample_rate, audio.channels, audio.frames, audio.subtype, audio.samples.dtype.name)
        held._audio = audio
        return held

    @classmethod
    def from_take_file(cls, path: Path, info: AudioInfo) -> RecordedAudio | None:
        """The take's audio file ``path`` kept open to be read block by block, or None when it is not a
        WAV ``write_take`` writes, or does not hold what ``info`` (its record in meta.json) says, or holds
        NaN or infinite samples: ``read_take`` then reads it whole and says what is wrong with it. Only
        a regular file is opened: libsndfile would wait forever on a named pipe with no writer. A pass
        through the blocks that ends with the file rewritten or replaced since it was opened is an
        ``InputError``: the passes (measuring the channels, mixing them, looking for clipping) must
        all read one recording."""
        if not path.is_file():
            return None
        try:
            f = sf.SoundFile(libsndfile_name(path))
        except (sf.LibsndfileError, RuntimeError, TypeError, OSError):
            return None
        held = cls(f.samplerate, f.channels, f.frames, f.subtype, _NATIVE.get(f.subtype, "float32"))
        held._file, held._path = f, path
        try:
            held._stamp = _stamp(path)
        except OSError:
            held.close()
            return None
        expected = (info.sample_rate, info.channels, info.samples)
        try:
            usable = (
                f.format in ("WAV", "RF64", "WAVEX")
                and f.subtype in _NATIVE
                and (f.samplerate, f.channels, f.frames) == expected
                and f.frames >= 1
                and (held.dtype.kind != "f" or all(np.isfinite(b).all() for b in held.blocks(_CHECK_FRAMES)))
            )
        except InputError:  # cut short or changed while checked: read_take says what it holds now
            usable = False
        if not usable:
            held.close()
            return None
        return held

    def blocks(self, size: int) -> Iterator[np.ndarray]:
        """The samples in order, ``size`` frames (the last block fewer) x channels at a time."""
        if self._audio is not None:
            samples = self._audio.samples
            for lo in range(0, self.frames, size):
                yield samples[lo : lo + size]
            return
        assert self._file is not None, "the audio file was closed"
        self._file.seek(0)
        for lo in range(0, self.frames, size):
            try:
                block = self._file.read(size, dtype=self.dtype.name, always_2d=True)
            except (sf.LibsndfileError, RuntimeError) as exc:
                raise InputError(f"audio is unreadable: {exc}", self._path) from None
            if block.shape[0] != min(size, self.frames - lo):  # cut short or rewritten while being read
                raise InputError(
                    f"audio ends after {lo + block.shape[0]} of its {self.frames} samples (changed while it "
                    "was read?)",
                    self._path,
                )
            yield block
        # each pass ends here: one through the file rewritten in place since it was opened (an editor
        # saving over it) would mix two recordings into one result, each pass deciding on another
        try:
            same = _stamp(self._path) == self._stamp
        except OSError:
            same = False
        if not same:
            raise InputError(
                "audio changed while it was read (rewritten or replaced?): align it again", self._path
            )

    def mono_blocks(self, size: int) -> Iterator[np.ndarray]:
        """``Audio.mono_float`` of each block: the same float32 samples as of the whole (it works frame by
        frame). Each block goes through a shallow copy of one ``Audio``: a new one would check its samples
        again, and refuse the last block of a file of more than 64 channels (``MAX_AUDIO_CHANNELS``)
        holding fewer frames than channels, as (channels, samples). For a file, that ``Audio`` is made
        once of as many frames of zeros as channels, which that check lets pass."""
        part = copy.copy(self._audio) if self._audio is not None else self._template()
        for block in self.blocks(size):
            part.samples = block
            yield part.mono_float()

    def channel(self, k: int, size: int) -> np.ndarray:
        """Channel ``k`` (from 0) whole, in its recorded format, read ``size`` frames at a time."""
        if self._audio is not None:
            return self._audio.samples[:, k]
        out = np.empty(self.frames, self.dtype)
        at = 0
        for block in self.blocks(size):
            out[at : at + block.shape[0]] = block[:, k]
            at += block.shape[0]
        return out

    def close(self) -> None:
        if self._file is not None:
            self._file.close()

    def _template(self) -> Audio:
        # as many rows as channels: a row of more than MAX_AUDIO_CHANNELS looks like (channels, samples)
        return Audio(np.zeros((self.channels, self.channels), self.dtype), self.sample_rate, self.subtype)


def _stamp(path: Path) -> tuple[int, int, int]:
    """What changes when the file at ``path`` is rewritten or replaced: its inode, size and mtime."""
    st = os.stat(path)
    return st.st_ino, st.st_size, st.st_mtime_ns


class _LeftInFile(RecordedAudio):
    """A ``FileAudio`` (audio left in its file: ``capture.audio_io.audio_left_in_files``) as recorded
    samples, its blocks read from the file (``FileAudio.blocks``: checked to be the samples read)."""

    def __init__(self, audio: FileAudio):
        super().__init__(audio.sample_rate, audio.channels, audio.frames, audio.subtype, audio.dtype.name)
        self._left = audio

    def blocks(self, size: int) -> Iterator[np.ndarray]:
        return self._left.blocks(size)


def recorded(audio: Audio | RecordedAudio) -> RecordedAudio:
    """``audio`` as blocks: an ``Audio`` in memory is sliced, never copied; audio left in its file is read
    from the file a block at a time (its ``samples`` would read all of it into memory, and keep it)."""
    if isinstance(audio, RecordedAudio):
        return audio
    if isinstance(audio, FileAudio) and not audio.held:
        return _LeftInFile(audio)
    return RecordedAudio.of(audio)


# The take being aligned and its audio file, for a take read without its audio (``reading_from_file``)
_READING: ContextVar[tuple[Take, RecordedAudio] | None] = ContextVar("align_reading_from_file", default=None)


@contextmanager
def reading_from_file(take: Take, file: RecordedAudio | None) -> Iterator[None]:
    """Within it, the audio of ``take`` (read without it, ``read_take(folder, audio=False)``) is ``file``
    (``audio_of``); ``file`` None: the take's own. The aligner's signature stays the library's."""
    token = _READING.set(None if file is None else (take, file))
    try:
        yield
    finally:
        _READING.reset(token)


def audio_of(take: Take) -> Audio | RecordedAudio | None:
    """The audio to align ``take`` to: its own, or the file given for it by ``reading_from_file``."""
    held = _READING.get()
    if take.audio is None and held is not None and held[0] is take:
        return held[1]
    return take.audio
