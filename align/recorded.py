"""A take's audio as recorded (its own rate, channels and sample format), read a block of frames at a time.

Align needs the recorded samples only to make its 16 kHz mono copy and to look for clipping (``clipping``),
each a pass or two through them in order. Read from the take's WAV a block at a time, an hour of audio at
44.1 kHz (317 MB as int16 mono, 635 MB stereo) is never in memory whole, and nothing of it is left once
the 16 kHz copy is made. The blocks are the samples ``capture.read_audio`` gives, in the same format.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

import numpy as np
import soundfile as sf

from capture import Audio, InputError, Take
from capture.take import AudioInfo

# The WAV sample formats read as read_audio reads them (PCM_24 widened to int32): the subtypes write_take
# writes. Anything else (an edited take holding an MP3, a WAV of 8-bit or A-law samples) is read whole.
_NATIVE = {"PCM_16": "int16", "PCM_24": "int32", "PCM_32": "int32", "FLOAT": "float32"}


_CHECK_FRAMES = 1 << 16  # frames per block of the check for NaN in float samples


class RecordedAudio:
    """Recorded samples (frames x channels, ``capture.Audio``'s format) given block by block, from an
    ``Audio`` in memory (``of``) or from the take's WAV file (``from_take_file``)."""

    def __init__(self, sample_rate: int, channels: int, frames: int, subtype: str, dtype: str):
        self.sample_rate, self.channels, self.frames = sample_rate, channels, frames
        self.subtype, self.dtype = subtype, np.dtype(dtype)
        self._audio: Audio | None = None
        self._file: sf.SoundFile | None = None

    @classmethod
    def of(cls, audio: Audio) -> RecordedAudio:
        held = cls(audio.sample_rate, audio.channels, audio.frames, audio.subtype, audio.samples.dtype.name)
        held._audio = audio
        return held

    @classmethod
    def from_take_file(cls, path: Path, info: AudioInfo) -> RecordedAudio | None:
        """The take's audio file ``path`` kept open to be read block by block, or None when it is not a
        WAV ``write_take`` writes, or does not hold what ``info`` (its record in meta.json) says, or holds
        NaN or infinite samples: ``read_take`` then reads it whole and says what is wrong with it."""
        try:
            f = sf.SoundFile(str(path))
        except (sf.LibsndfileError, RuntimeError, TypeError, OSError):
            return None
        held = cls(f.samplerate, f.channels, f.frames, f.subtype, _NATIVE.get(f.subtype, "float32"))
        held._file = f
        expected = (info.sample_rate, info.channels, info.samples)
        if (
            f.format not in ("WAV", "RF64", "WAVEX")
            or f.subtype not in _NATIVE
            or (f.samplerate, f.channels, f.frames) != expected
            or f.frames < 1
            or (held.dtype.kind == "f" and not all(np.isfinite(b).all() for b in held.blocks(_CHECK_FRAMES)))
        ):
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
                raise InputError(f"audio is unreadable: {exc}", self._file.name) from None
            if block.shape[0] != min(size, self.frames - lo):  # cut short or rewritten while being read
                raise InputError(
                    f"audio ends after {lo + block.shape[0]} of its {self.frames} samples (changed while it "
                    "was read?)",
                    self._file.name,
                )
            yield block

    def mono_blocks(self, size: int) -> Iterator[np.ndarray]:
        """``Audio.mono_float`` of each block: the same float32 samples as of the whole (it works frame by
        frame). Each block goes through a shallow copy of one ``Audio``: a new one would check its samples
        again, and refuse the last block of a file of more than 64 channels (``MAX_AUDIO_CHANNELS``)
        holding fewer frames than channels, as (channels, samples)."""
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
        return Audio(np.zeros((1, self.channels), self.dtype), self.sample_rate, self.subtype)


def recorded(audio: Audio | RecordedAudio) -> RecordedAudio:
    """``audio`` as blocks: an ``Audio`` in memory is sliced, never copied."""
    return audio if isinstance(audio, RecordedAudio) else RecordedAudio.of(audio)


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
