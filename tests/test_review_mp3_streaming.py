"""Review of MP3 audio decoded block-wise at import (``_read_mpeg``): MP3s of other encoders and layers.

A joined .mp3 whose later file is MPEG layer II (an .mp2 renamed, after an ID3 tag or another layer's
frames) was said to keep that file's encoder priming (repair ``encoder_delay_unknown``, "the sound after
it may be up to ~50 ms late"): the check of a later file's recorded delay asked FFmpeg of any codec, where
the whole read before asked it only of codecs that prime (layer II has no priming to record), so a
spurious repair came with the same samples, read whole or within an import.

libsndfile reads an .mp3 no further than the length its decoder (mpg123) estimates from the first frame's
bit rate when no header frame counts the frames: a VBR file without a Xing header, or a 320 kbit/s file
with a 32 kbit/s one joined on without a tag, lost most of its audio (1.5 s of 5 s kept), with no repair.
Such a file is decoded by FFmpeg as joined files are, and so is one whose damaged frame ended
libsndfile's read (8 s read as 0.29 s, a mono file with one stereo header as 0.73 s of 3 s): the
import's block-wise read went on after a read ended short (7535 samples, not the whole read's 4655).
"""

from __future__ import annotations

import io
import struct

import av
import numpy as np
import pytest
from test_audio_mp3_later_parts import mp3_bytes

from capture import read_audio
from capture.audio_io import _mpeg_frame, _tag_bytes, audio_left_in_files, mpeg_runs, write_audio


def _tone(seconds: float, rate: int, seed: int = 0) -> np.ndarray:
    t = np.arange(round(seconds * rate)) / rate
    noise = np.random.default_rng(seed).standard_normal(len(t)) * 0.05
    return (np.sin(2 * np.pi * 220 * t) * 0.3 + noise).astype(np.float32)


def _mp2_bytes(signal: np.ndarray, rate: int) -> bytes:
    """``signal`` (mono float) as MPEG-1 layer II, FFmpeg's encoder, in a raw .mp2 stream."""
    out = io.BytesIO()
    with av.open(out, "w", format="mp2") as container:
        stream = container.add_stream("mp2", rate=rate, layout="mono")
        pcm = (signal * 32767).astype(np.int16)[None, :]
        frame = av.AudioFrame.from_ndarray(pcm, format=stream.codec_context.format.name, layout="mono")
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return out.getvalue()


def _id3(size: int) -> bytes:
    body = b"TIT2" + struct.pack(">I", size - 10) + b"\0\0" + bytes(size - 10)
    return b"ID3\x03\0\0" + bytes((size >> s) & 127 for s in (21, 14, 7, 0)) + body


def _joined() -> dict[str, bytes]:
    rate = 44100
    later = _mp2_bytes(_tone(0.5, rate, 2), rate)
    return {
        "mp2_tag_mp2.mp3": _mp2_bytes(_tone(1.0, rate, 1), rate) + _id3(200) + later,
        "mp3_then_mp2.mp3": mp3_bytes(_tone(1.0, rate, 1), rate, 1) + later,
    }


def _read_both_ways(path):
    """(the audio and repairs read whole, those of an import's block-wise read), both written as WAV."""
    folder = path.parent
    whole: list = []
    audio = read_audio(path, whole)
    write_audio(folder / "whole.wav", audio)
    left: list = []
    (folder / "out").mkdir()
    with audio_left_in_files(folder / "out"):
        write_audio(folder / "left.wav", read_audio(path, left))
    assert (folder / "left.wav").read_bytes() == (folder / "whole.wav").read_bytes()
    return audio, whole, left


@pytest.mark.parametrize("name", list(_joined()))
def test_a_joined_layer_ii_file_is_not_said_to_keep_an_encoder_delay(tmp_path, name):
    """Layer II has no priming: no ``encoder_delay_unknown`` for it, read whole or in an import, the same
    samples both ways."""
    path = tmp_path / name
    path.write_bytes(_joined()[name])
    _, whole, left = _read_both_ways(path)
    assert [r["kind"] for r in whole] == [] and left == whole


def test_bit_rates_joined_without_a_header_are_read_to_their_end(tmp_path):
    """1 s at 320 kbit/s, then 4 s at 32 kbit/s, no tag or header frame: libsndfile's length, estimated
    from the first frame, ended the audio at 1.45 s. All 5 s now (and the priming, noted), both ways."""
    rate = 44100
    bare = {"write_xing": "0", "id3v2_version": "0"}
    path = tmp_path / "joined_bit_rates.mp3"
    loud = mp3_bytes(_tone(1.0, rate, 1), rate, 1, bit_rate=320000, **bare)
    path.write_bytes(loud + mp3_bytes(_tone(4.0, rate, 2), rate, 1, bit_rate=32000, **bare))
    audio, whole, left = _read_both_ways(path)
    assert audio.frames >= 5 * rate and left == whole
    assert [r["kind"] for r in whole] == ["encoder_delay_unknown"]


def _damaged(data: bytes, frame: int, damage) -> bytes:
    """``data`` (an .mp3) with its ``frame``-th frame (counted from 0 after the ID3 tag) damaged:
    ``damage(data, at)`` gives the bytes from that frame's start on."""
    at = _tag_bytes(data, 0)
    for _ in range(frame):
        at += _mpeg_frame(data, at)[0]
    return data[:at] + damage(data, at)


def _cut_frame(rate: int) -> bytes:
    """8 s of 16 kHz mono whose 10th frame lost 50 bytes (libsndfile's decoder ends a read at it: 4655
    samples, and read on, 2880 more, at the next)."""
    t = np.arange(8 * rate) / 8000
    noise = np.random.default_rng(4).standard_normal(len(t)) * 0.06
    data = mp3_bytes((np.sin(2 * np.pi * 220 * t) * 0.3 + noise).astype(np.float32), rate, 1, 32000)
    return _damaged(data, 10, lambda d, at: d[at : at + 20] + d[at + 70 :])


def _stereo_frame(rate: int) -> bytes:
    """3 s of 44.1 kHz mono whose 30th frame's header says stereo (libsndfile stopped there: 0.73 s)."""
    data = mp3_bytes(_tone(3.0, rate), rate, 1)
    return _damaged(data, 30, lambda d, at: d[at : at + 3] + bytes([d[at + 3] ^ 0xC0]) + d[at + 4 :])


@pytest.mark.parametrize(("make", "rate", "seconds"), [(_cut_frame, 16000, 8.0), (_stereo_frame, 44100, 3.0)])
def test_an_mp3_libsndfile_stops_reading_at_damage_is_read_on_past_it(tmp_path, make, rate, seconds):
    """One file (not joined) whose damaged frame ended libsndfile's read, the rest of the audio lost with
    no repair; the import's block-wise read went on past the cut frame (7535 samples, not 4655): another
    take folder. Decoded by FFmpeg now, as joined files are: all but the damaged frame, noted, both ways."""
    path = tmp_path / "damaged.mp3"
    path.write_bytes(make(rate))
    assert len(mpeg_runs(path.read_bytes())) == 1
    audio, whole, left = _read_both_ways(path)
    assert audio.frames > (seconds - 0.2) * rate and left == whole
    assert [r["kind"] for r in whole] == ["bad_audio"]
