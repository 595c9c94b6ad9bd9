"""The Live Link Face reference video (``.mov``: JPEG frames, PCM audio, a timecode track).

Reading gives the audio at its own rate, the start timecode and the video timing. Writing produces
the same kind of file; the simulated iPhone and the tests use it to stand in for the phone.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from .audio_io import (
    SILENT_PEAK,
    Audio,
    FileAudio,
    check_samples,
    decode_with_pyav,
    ffmpeg_name,
    finite_peak,
)
from .errors import InputError


@dataclass
class MovInfo:
    """What a take's ``.mov`` holds. Times in seconds from the start of the file."""

    path: Path
    timecode: str | None  # start timecode of the video, HH:MM:SS:FF as in the timecode track
    video_fps: float | None
    video_frames: int | None
    width: int | None
    height: int | None
    audio_start_s: float  # presentation time of the first audio sample relative to the video's
    audio_tracks: int = 0  # audio streams in the file (the app writes one; 0: a video-only file)

    @property
    def timecode_rate(self) -> int | None:
        """The rate the video's timecode counts frames at: its frame rate, whole (iPhone timecode is 30
        or 60 fps and never drop-frame, formats doc §0.11), or None when the file gives no rate."""
        return round(self.video_fps) if self.video_fps else None


@contextmanager
def opencv_name(path: str | Path) -> Iterator[str]:
    """A name OpenCV opens as ``path``, held while the block runs: ``/proc/self/fd/N`` of the file opened
    here (OpenCV crashed, segmentation fault, on a name that is not UTF-8, and its FFmpeg reads a relative
    name with a colon as a protocol); the absolute name where there is no ``/proc``."""
    if not os.path.isdir("/proc/self/fd"):
        yield str(Path(path).absolute())
        return
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a named pipe: not waited on
    except OSError:
        yield str(Path(path).absolute())  # not there or unreadable: OpenCV says it does not open
        return
    try:
        yield f"/proc/self/fd/{fd}"
    finally:
        os.close(fd)


def probe_mov(path: str | Path) -> MovInfo:
    """Timecode and stream timing of a ``.mov`` without decoding it; no width and height for a video
    stream of a codec FFmpeg does not know."""
    import av

    path = Path(path)
    if not path.is_file():
        raise InputError("video file not found", path)
    try:
        with av.open(ffmpeg_name(path)) as c:
            timecode = c.metadata.get("timecode")
            fps = frames = width = height = None
            v_start = a_start = 0.0
            tracks = 0
            for s in c.streams:
                timecode = timecode or s.metadata.get("timecode")
                if s.type == "video" and fps is None:
                    rate = s.average_rate or s.guessed_rate
                    fps = float(rate) if rate else None
                    frames = s.frames or None
                    if s.codec_context is not None:  # None: a codec FFmpeg does not know (damaged)
                        width, height = s.codec_context.width, s.codec_context.height
                    if s.start_time is not None:
                        v_start = float(s.start_time * s.time_base)
                if s.type == "audio":
                    tracks += 1
                if s.type == "audio" and s.start_time is not None and tracks == 1:
                    a_start = float(s.start_time * s.time_base)
    except (av.FFmpegError, OSError) as exc:
        raise InputError(f"video could not be opened (a truncated or damaged file?): {exc}", path) from None
    except UnicodeDecodeError:  # PyAV decodes the container's and streams' metadata as UTF-8
        raise InputError(
            "video could not be opened (a damaged file?): its metadata is not UTF-8", path
        ) from None
    return MovInfo(path, timecode, fps, frames, width, height, a_start - v_start, tracks)


def read_mov_audio(path: str | Path, repairs: list[dict[str, Any]] | None = None) -> Audio:
    """The ``.mov``'s audio track at its own rate and sample format (non-finite float samples as in
    ``read_audio``); of several tracks, the first that is not silent (``choose_mov_audio``)."""
    return choose_mov_audio(path, repairs)[0]


def choose_mov_audio(
    path: str | Path, repairs: list[dict[str, Any]] | None = None, tracks: int | None = None
) -> tuple[Audio, dict[str, Any] | None]:
    """The ``.mov``'s audio and, for a file of several audio tracks, which one was used: the first that
    is not silent (peak at or above -70 dBFS; the first track when all are), with repair ``audio_track``
    naming every track's peak. The second value is ``{"track", "tracks", "peaks_dbfs"}`` (tracks
    counted from 1) or None for a file of one track. ``tracks``: the number of audio tracks, when the
    caller has probed the file already."""
    path = Path(path)
    count = tracks
    if count is None:
        try:
            count = probe_mov(path).audio_tracks
        except InputError:
            count = 1  # a damaged file: decoding says what is wrong with it
    if count <= 1:
        return check_samples(decode_with_pyav(path), path, repairs), None
    # each track decoded in turn, the one chosen so far kept and every other let go once its peak is
    # known: two tracks at most on the disk (a scratch file each, 1.4 GB an hour) or in memory, not all
    peaks: list[float] = []
    chosen, kept = 0, None
    for i in range(count):
        track = decode_with_pyav(path, i)
        peaks.append(finite_peak(track))
        if kept is None or (peaks[chosen] < SILENT_PEAK <= peaks[i]):
            track, kept, chosen = kept, track, i
        if isinstance(track, FileAudio):
            track.discard()  # decoded into a scratch file: not kept on the disk until the import ends
        del track  # let go before the next is decoded
    assert kept is not None
    described = ", ".join(f"{i + 1}: {_describe_peak(p)}" for i, p in enumerate(peaks))
    if peaks[chosen] >= SILENT_PEAK:
        why = "the first that is not silent" if chosen else "the first, which carries sound"
    else:
        why = "all are silent: the first"
    if repairs is not None:
        repairs.append(
            {
                "line": None,
                "kind": "audio_track",
                "message": f"{path.name} holds {count} audio tracks ({described}): track {chosen + 1} "
                f"is used ({why})",
            }
        )
    choice = {
        "track": chosen + 1,
        "tracks": count,
        "peaks_dbfs": [round(20 * np.log10(p), 1) if p > 0 else None for p in peaks],
    }
    return check_samples(kept, path, repairs), choice


def _describe_peak(peak: float) -> str:
    if peak <= 0:
        return "silent (all zero)"
    level = f"peak {20 * np.log10(peak):.1f} dBFS"
    return f"silent ({level})" if peak < SILENT_PEAK else level


def write_reference_mov(
    path: str | Path,
    fps: float,
    n_frames: int,
    audio: Audio | Sequence[Audio] | None = None,
    timecode: str | None = None,
    frame_image: Callable[[int], np.ndarray] | None = None,
    size: tuple[int, int] = (160, 120),
) -> Path:
    """Write a ``.mov`` like the app's: MJPEG video, 16-bit PCM audio, a timecode track. ``audio`` may be
    several tracks (a camera's second microphone, an editor's extra track), written in that order.

    ``frame_image(i)`` returns an RGB uint8 image (height x width x 3) for video frame ``i``; by default
    frames are grey.
    """
    import av

    path = Path(path)
    width, height = size
    rate = Fraction(fps).limit_denominator(1001)
    with av.open(ffmpeg_name(path), "w", format="mov") as c:
        v = c.add_stream("mjpeg", rate=rate)
        v.width, v.height, v.pix_fmt = width, height, "yuvj420p"
        if timecode:
            v.metadata["timecode"] = timecode
        tracks = [] if audio is None else [audio] if isinstance(audio, Audio) else list(audio)
        layouts = ["mono" if t.channels == 1 else "stereo" for t in tracks]
        streams = [
            c.add_stream("pcm_s16le", rate=t.sample_rate, layout=lay) for t, lay in zip(tracks, layouts)
        ]
        for i in range(n_frames):
            img = frame_image(i) if frame_image else np.full((height, width, 3), 128, np.uint8)
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            frame = frame.reformat(format="yuvj420p")
            frame.pts, frame.time_base = i, 1 / rate
            for packet in v.encode(frame):
                c.mux(packet)
        for packet in v.encode():
            c.mux(packet)
        for a, track, layout in zip(streams, tracks, layouts):
            samples = track.pcm16()
            block = 1024
            for pos in range(0, samples.shape[0], block):
                chunk = np.ascontiguousarray(samples[pos : pos + block].T.reshape(1, -1))
                frame = av.AudioFrame.from_ndarray(chunk, format="s16", layout=layout)
                frame.sample_rate, frame.pts = track.sample_rate, pos
                frame.time_base = Fraction(1, track.sample_rate)
                for packet in a.encode(frame):
                    c.mux(packet)
            for packet in a.encode():
                c.mux(packet)
    return path
