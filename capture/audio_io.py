"""Reading and writing a take's audio, keeping the recorded sample rate and sample format.

WAV/FLAC/OGG (and MP3 where libsndfile supports it) are read with soundfile; everything else a phone or
editor produces (M4A/AAC, the Live Link Face ``.mov``) is decoded with PyAV. Integer PCM stays integer so
a take's audio round-trips exactly.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import soundfile as sf

from .atomic import atomic_write
from .errors import InputError
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
    without a LAME tag) keeps it at its start: noted as repair ``encoder_delay_unknown``."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder, not an audio file", path)
    if not path.exists():
        raise InputError("audio file not found", path)
    if not path.is_file():
        raise InputError("not a regular file (a device or a pipe?): give an audio file", path)
    try:
        info = sf.info(str(path))
    except (sf.LibsndfileError, RuntimeError, TypeError):
        info = None
    if info is not None:
        dtype = _NATIVE.get(info.subtype, "float32")
        subtype = info.subtype if info.subtype in _NATIVE else "FLOAT"
        try:
            data, rate = sf.read(str(path), dtype=dtype, always_2d=True)
        except (sf.LibsndfileError, RuntimeError) as exc:
            raise InputError(f"audio is unreadable: {exc}", path) from None
        if data.shape[0] == 0:
            return _read_unfinished_wav(path, repairs)
        audio = check_samples(Audio(data, rate, subtype), path, repairs)
        declared = wav_declared_frames(path)
        if repairs is not None and declared is not None and declared > audio.frames:
            repairs.append(
                {
                    "line": None,
                    "kind": "truncated_audio",
                    "message": f"{path.name}: header declares {declared / rate:.3f} s of audio, the file "
                    f"holds {audio.duration_s:.3f} s (cut short?): the samples present are used",
                }
            )
        if repairs is not None and info.subtype.startswith("MPEG_LAYER"):  # mpg123 drops a recorded delay
            note_unknown_delay(path, repairs)
        return audio
    return check_samples(decode_with_pyav(path, repairs=repairs), path, repairs)


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
            "message": f"{path.name}: the WAV header declares no samples (a recorder that did not finish the "
            f"file?): the {audio.duration_s:.3f} s of samples after it are used",
        }
    )
    return audio


def check_samples(audio: Audio, path: Path, repairs: list[dict[str, Any]] | None) -> Audio:
    """Damaged float samples, set right and recorded in ``repairs`` (repair ``bad_audio``): NaN or
    infinite samples are set to 0 (without ``repairs``: an ``InputError``), and isolated samples far past
    full scale (``damaged_samples``) are replaced by the interpolation of their neighbours (without
    ``repairs`` they are left as they are)."""
    if audio.samples.dtype.kind != "f":
        return audio
    bad = ~np.isfinite(audio.samples)
    count = int(bad.sum())
    if count:
        if repairs is None:
            raise InputError(f"audio holds {count} NaN or infinite sample(s)", path)
        audio.samples[bad] = 0.0
        repairs.append(
            {
                "line": None,
                "kind": "bad_audio",
                "message": f"{path.name}: {count} NaN or infinite samples set to 0",
            }
        )
    if repairs is None:
        return audio
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
                "message": f"{path.name}: {found} isolated sample(s) up to {worst:.3g}, past full scale and "
                f"over {SPIKE_FACTOR:g} times the signal around them (damaged), replaced by the "
                "interpolation of their neighbours",
            }
        )
    return audio


# A damaged float sample: past full scale, and over SPIKE_FACTOR times both the take's level (its 99.9th
# percentile of |x|; speech peaks at 1.3-2.0 times it in every real sample) and every sample 4 to 32
# samples away (a band-limited sound, even a click, spreads over its neighbours; a flipped bit does
# not): runs of up to 4 damaged samples, a few per take.
SPIKE_FACTOR = 10.0
_SPIKE_RING = np.concatenate([np.arange(-32, -3), np.arange(4, 33)])


def damaged_samples(x: np.ndarray) -> np.ndarray:
    """Indices of the isolated damaged samples of one channel of finite float audio (see SPIKE_FACTOR):
    impulses far above the signal around them, which no microphone or converter produces."""
    a = np.abs(x)
    if a.size == 0 or float(a.max()) <= 1.0:  # within full scale: a legal value of every format
        return np.zeros(0, np.int64)
    level = float(np.percentile(a, 99.9))
    cand = np.flatnonzero(a > max(1.0, SPIKE_FACTOR * level))  # by construction under 0.1 % of samples
    if cand.size == 0:
        return cand
    ring = cand[:, None] + _SPIKE_RING[None, :]
    inside = (ring >= 0) & (ring < a.size)
    ring = np.clip(ring, 0, a.size - 1)
    neighbours = np.where(inside, a[ring], 0.0)
    return cand[a[cand] > SPIKE_FACTOR * neighbours.max(axis=1)]


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
        import av

        try:
            with av.open(str(path)) as container:
                stream = container.streams.audio[0]
                note_unknown_delay(path, repairs, stream, next(container.demux(stream)).pts)
        except (av.FFmpegError, OSError, ValueError, IndexError, StopIteration):
            pass  # FFmpeg cannot tell: libsndfile read it, and nothing is known of a delay
        return
    codec = stream.codec_context.name
    if codec not in PRIMED_CODECS or (first_pts or 0) < 0 or (stream.start_time or 0) > 0:
        return
    repairs.append(
        {
            "line": None,
            "kind": "encoder_delay_unknown",
            "message": f"{path.name}: {codec.removesuffix('float').upper()} audio whose file does not record "
            "the encoder's delay (raw ADTS .aac, an MP3 without a LAME tag): its priming samples are kept, "
            "so the audio may start up to ~50 ms late; s2a-align measures the offset",
        }
    )


def _to_channels(samples: np.ndarray, channels: int) -> np.ndarray:
    """Frames x channels samples mixed to ``channels``: their mean on each channel (mono to stereo
    copies the channel, stereo to mono averages the two)."""
    mixed = samples.mean(axis=1, keepdims=True, dtype=np.float64).astype(samples.dtype)
    return np.repeat(mixed, channels, axis=1)


def decode_with_pyav(
    path: str | Path, stream_index: int = 0, repairs: list[dict[str, Any]] | None = None
) -> Audio:
    """The first audio stream of any container FFmpeg reads (.mov, .m4a, .mp3, ...).

    FFmpeg drops the encoder's priming samples at the start (the edit list); the padding that fills the
    last coded frame (AAC: up to 1023 samples) is cut here, where the container's stream duration ends
    inside that frame (AAC only: other codecs trim their own padding, and an MP3's duration may be an
    estimate). A file that records no delay keeps it: noted in ``repairs`` (``note_unknown_delay``)."""
    import av  # imported here: only needed for containers soundfile cannot read

    path = Path(path)
    try:
        with av.open(str(path)) as container:
            streams = container.streams.audio
            if not streams:
                raise InputError("file has no audio stream", path)
            stream = streams[stream_index]
            chunks = []
            fmt = None
            last_frame = 0
            first_pts = None
            changed = 0  # samples decoded with another channel count than the first frame's
            for packet in container.demux(stream):
                first_pts = packet.pts if first_pts is None else first_pts
                for frame in packet.decode():
                    fmt, last_frame = frame.format, frame.samples
                    arr = frame.to_ndarray()
                    if fmt.is_planar:
                        arr = arr.T
                    else:
                        arr = arr.reshape(-1, len(frame.layout.channels))
                    if chunks and arr.shape[1] != chunks[0].shape[1]:
                        changed += len(arr)
                        arr = _to_channels(arr, chunks[0].shape[1])
                    chunks.append(arr)
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
                if changed:
                    repairs.append(
                        {
                            "line": None,
                            "kind": "channels_changed",
                            "message": f"{path.name}: the audio's channel count changes mid-stream: "
                            f"{changed} samples were mixed to the first frame's "
                            f"{chunks[0].shape[1]} channel(s)",
                        }
                    )
    except InputError:
        raise
    except (av.FFmpegError, OSError, ValueError) as exc:
        # FFmpeg's errors carry its own negative error code ("[Errno 1094995529] Invalid data found ..."):
        # the text is what tells the user something
        why = getattr(exc, "strerror", None) or str(exc)
        raise InputError(f"audio could not be decoded (a truncated or damaged file?): {why}", path) from None
    if not chunks:
        raise InputError("audio stream holds no samples", path)
    data = np.concatenate(chunks, axis=0)
    if declared is not None and 0 < data.shape[0] - declared < last_frame:
        data = data[:declared]  # the last frame's padding
    name = fmt.name.rstrip("p") if fmt is not None else "flt"
    if name == "s16":
        return Audio(data.astype(np.int16, copy=False), rate, "PCM_16")
    if name == "s32":
        return Audio(data.astype(np.int32, copy=False), rate, "PCM_32")
    if name == "u8":
        return Audio((data.astype(np.float32) - 128.0) / 128.0, rate, "FLOAT")
    return Audio(data.astype(np.float32, copy=False), rate, "FLOAT")


def write_audio(path: str | Path, audio: Audio) -> None:
    """Write WAV with the audio's own subtype (RF64 past 4 GB), atomically. A write the system refuses
    (a full disk) is an ``OSError`` naming ``path``."""
    fmt = "RF64" if audio.samples.nbytes > 0xFFFF0000 else "WAV"
    channels = 1 if audio.samples.ndim == 1 else audio.samples.shape[1]
    with atomic_write(path, buffering=1 << 20) as f:
        sink = _WavSink(f)
        try:
            with sf.SoundFile(
                sink, "w", audio.sample_rate, channels, subtype=audio.subtype, format=fmt
            ) as out:
                _no_peak_chunk(out)
                out.write(audio.samples)
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
