"""Leftovers of the .mp3 damage work (``capture/audio_io.py``).

A damaged or joined .mp3 was given to FFmpeg as bytes held whole (``s2a-capture import`` of a damaged hour
at 320 kbit/s: 377 MB peak, 114 MB undamaged): each file of it is now read from the file as FFmpeg asks
for it, silent frames put in at the damage (``_MendedPart``): 115 MB, the same audio.wav. A later joined
file was opened by FFmpeg twice (once for its encoder delay). Damage running to the end of an .mp3 left
it short with no repair. An Info frame declaring no frame count kept LAME's delay (the sound 1105 samples
late, unnoted). A big cover picture was read whole by FFmpeg (a raw .aac's decoding, an .mp3's delay
check).
"""

from __future__ import annotations

import io

import av
import numpy as np
import pytest
from test_audio_mp3_later_parts import frame_starts, lag, mp3_bytes
from test_import_mp3_damage import _damaged, _mp3, _peak_growth_kb, _speech_like, _write

from capture import read_audio
from capture.audio_io import _file_header_frames, _mpeg_frame, _xing_at, mpeg_runs

IMPORT = (
    "with aio.audio_left_in_files(sys.argv[2]):\n"
    "    aio.write_audio(Path(sys.argv[2]) / 'o.wav', aio.read_audio(Path(sys.argv[1]), []))"
)


def test_a_long_damaged_and_joined_mp3_is_decoded_without_holding_its_bytes(tmp_path):
    """7 MB at 320 kbit/s (3 min) damaged in the middle, a file joined on after it: an import's peak grows
    by what a 3 s damaged file's does, not by its bytes (12 MB more before: held, then copied)."""
    one = mp3_bytes(_speech_like(3.0, 44100), 44100, 1, 320000, write_xing="0")
    (run,) = mpeg_runs(one)
    long = one[: run.end] + one[run.start : run.end] * 60
    small = _peak_growth_kb(IMPORT, _write(tmp_path / "small.mp3", _damaged(one, (0.5, 3000))), tmp_path)
    path = _write(tmp_path / "long.mp3", _damaged(long, (0.5, 3000)) + one)
    assert _peak_growth_kb(IMPORT, path, tmp_path) < small + 6_000


def test_each_file_of_a_joined_mp3_is_opened_by_ffmpeg_once(tmp_path, monkeypatch):
    """A LAME file joined on without its tag: FFmpeg opened it twice, once to ask for its encoder delay and
    once to decode it; once now, its delay looked at as the decoding starts (still dropped: on time)."""
    rate = 16000
    first, later = _speech_like(1.0, rate), _speech_like(1.0, rate)[::-1].copy()
    path = _write(tmp_path / "joined.mp3", mp3_bytes(first, rate) + mp3_bytes(later, rate, write_xing="0"))
    opened = []
    real_open = av.open
    monkeypatch.setattr(av, "open", lambda *args, **kw: opened.append(args[0]) or real_open(*args, **kw))
    repairs: list = []
    audio = read_audio(path, repairs).mono_float()
    assert len(opened) == 2 and repairs == []
    assert lag(later, audio[rate:]) == 0


def _without_count(data: bytes, field: bool) -> bytes:
    """``data`` (LAME's .mp3) whose Info frame declares no frame count: 0 in its field, or (``field``
    False) no field for it, its flag cleared and the rest of the frame moved back 4 bytes."""
    pos = mpeg_runs(data)[0].start
    frame = _mpeg_frame(data, pos)
    flags_at, end = _xing_at(data, pos, frame) + 7, pos + frame[0]
    assert data[flags_at] & 1 and _file_header_frames(data, pos, frame)
    if field:
        return data[: flags_at + 1] + bytes(4) + data[flags_at + 5 :]
    return data[:flags_at] + bytes([data[flags_at] & ~1]) + data[flags_at + 5 : end] + bytes(4) + data[end:]


@pytest.mark.parametrize("damage", [(), ((0.5, 600),)], ids=["whole", "damaged"])
@pytest.mark.parametrize("field", [True, False], ids=["count_0", "no_count_field"])
def test_an_info_frame_without_a_frame_count_still_drops_lames_delay(tmp_path, field, damage):
    """Its LAME tag records the delay and padding, but with no frame count libsndfile's decoder kept them:
    the sound 1105 samples late (69 ms at 16 kHz), 1408 samples too many, no repair said so. Read whole,
    its count set: on time and of the signal's length, as with its count; damaged too (its count then
    holds the silent frames put in: without them FFmpeg ended the audio 4 frames early)."""
    rate = 16000
    signal = _speech_like(3.0, rate)
    data = mp3_bytes(signal, rate, 1, 32000)
    uncounted = _write(tmp_path / "uncounted.mp3", _damaged(_without_count(data, field), *damage))
    audio = read_audio(uncounted, []).mono_float()
    assert lag(signal, audio) == 0 and len(audio) == len(signal)
    whole = read_audio(_write(tmp_path / "counted.mp3", _damaged(data, *damage)), []).mono_float()
    assert np.abs(audio - whole).max() < 1e-5


@pytest.mark.parametrize(
    ("xing", "tail", "said"),
    [(True, b"", "up to 26 ms short"), (False, b"TAG" + bytes(125), "about 104 ms short")],
    ids=["counted", "estimated_before_id3v1"],
)
def test_damage_running_into_the_end_of_an_mp3_is_said(tmp_path, xing, tail, said):
    """Random bytes over its last frames, up to its end (700 bytes: the audio 925 samples, 21 ms, short) or
    to an ID3v1 tag (2000 bytes from a frame's header, its sync kept, its bit rate broken; no Xing frame:
    4608 samples short), with no repair. Nothing after it to keep on time, so it is not filled: a
    ``bad_audio`` repair says from where and by how much it is short (the frames its Info frame counts
    less those found, else estimated from the bytes damaged, when they start as a frame does: random
    bytes there, no sync, are junk after the last frame, no loss); the rest is as read before."""
    data = _mp3(44100, 1, 128000, xing)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    damaged = 700 if xing else 2000
    noise = np.random.default_rng(3).integers(0, 256, damaged, dtype=np.uint8).tobytes()
    if not xing:  # from the header of the frame the damage starts in: a sync with no frame after it
        at = min(pos for pos in frame_starts(data) if pos >= len(data) - damaged)
        damaged, noise = len(data) - at, b"\xff\xfb\xf0" + noise[3 : len(data) - at]
    repairs: list = []
    path = _write(tmp_path / "damaged.mp3", data[:-damaged] + noise + tail)
    audio = read_audio(path, repairs).mono_float()
    assert len(whole) - 4608 <= len(audio) < len(whole)
    assert np.abs(audio[:-2304] - whole[: len(audio) - 2304]).max() < 1e-5
    (note,) = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    assert "at its end" in note and said in note


def _cover(size: int) -> bytes:
    """An ID3v2.3 tag holding a JPEG cover picture of ``size`` bytes (its MIME type and picture type set:
    a picture FFmpeg reads, a tag of zeros it skips)."""
    body = b"\0image/jpeg\0\3\0\xff\xd8\xff\xe0" + bytes(size)
    frame = b"APIC" + len(body).to_bytes(4, "big") + b"\0\0" + body
    return b"ID3\3\0\0" + bytes(len(frame) >> shift & 0x7F for shift in (21, 14, 7, 0)) + frame


def _adts(signal, rate: int) -> bytes:
    out = io.BytesIO()
    with av.open(out, "w", format="adts") as container:
        stream = container.add_stream("aac", rate=rate, layout="mono")
        frame = av.AudioFrame.from_ndarray(signal[None], format="fltp", layout="mono")
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return out.getvalue()


@pytest.mark.parametrize("suffix", [".aac", ".mp3"])
def test_a_big_cover_picture_is_not_read_by_ffmpeg(tmp_path, suffix):
    """A 48 MB JPEG cover in the ID3v2 tag of a raw .aac (libsndfile cannot read it: FFmpeg decodes it) or
    of an .mp3 (FFmpeg asked for its encoder delay): FFmpeg read the picture whole, 50 MB more peak. It
    is given the file from after the tag: the peak of the file without it, the same audio and repairs."""
    signal = _speech_like(1.0, 44100)
    body = _adts(signal, 44100) if suffix == ".aac" else mp3_bytes(signal, 44100, write_xing="0")
    cover = _write(tmp_path / f"cover{suffix}", _cover(48 << 20) + body)
    plain = _write(tmp_path / f"plain{suffix}", body)
    read = "with aio.audio_left_in_files(sys.argv[2]): aio.read_audio(Path(sys.argv[1]), [])"
    assert _peak_growth_kb(read, cover, tmp_path) < _peak_growth_kb(read, plain, tmp_path) + 8_000
    with_cover: list = []
    without: list = []
    assert np.array_equal(read_audio(cover, with_cover).samples, read_audio(plain, without).samples)
    assert with_cover == [{**note, "message": note["message"].replace("plain", "cover")} for note in without]
