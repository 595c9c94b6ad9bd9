"""The MP3 reader's last misreads (``capture/audio_io.py``). A VBR file without a Xing/Info frame whose
first frame's header was destroyed had its lost frames counted at the file's mean frame size: LAME's first
frame is its largest (2 frames put back, the sound a frame late) or, after silence, its smallest (none, the
sound a frame early, unsaid). Zeros a tagger padded an ID3v2 tag with hid a LAME tag from FFmpeg: a false
"encoder_delay_unknown" note. A clip of under 8 frames joined on bare at another rate was left out as junk
(its frame headers said to be chance); now its frames' side information tells it is sound. 100 KB of junk
alone was read as noise (768 samples of it, with damage notes); now refused as no MPEG audio.
"""

from __future__ import annotations

import io

import av
import numpy as np
import pytest
from test_audio_mp3_later_parts import lag, mp3_bytes
from test_import_mp3_damage import _speech_like, _write
from test_mp3_s26 import _bad_audio, _first_frames, _junk

from capture import InputError, read_audio
from capture.audio_io import audio_left_in_files


def _vbr_bytes(signal: np.ndarray, rate: int, channels: int, **options: str) -> bytes:
    """``signal`` (mono float) encoded by LAME in VBR (quality 4) through FFmpeg, on each of ``channels``;
    FFmpeg's muxer ``options``."""
    out = io.BytesIO()
    with av.open(out, "w", format="mp3", options=options) as container:
        stream = container.add_stream("libmp3lame", rate=rate, layout="mono" if channels == 1 else "stereo")
        stream.codec_context.qscale = 4
        frame = av.AudioFrame.from_ndarray(
            np.tile(signal.astype(np.float32), (channels, 1)), format="fltp", layout=stream.layout.name
        )
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return out.getvalue()


@pytest.mark.parametrize("garble", ["sync", "frame"])
@pytest.mark.parametrize(
    "rate, channels, silence", [(44100, 2, 0.5), (48000, 1, 0.0), (16000, 1, 0.5), (32000, 2, 0.0)]
)
def test_a_vbr_file_s_lost_first_frame_is_put_back_as_one(tmp_path, rate, channels, silence, garble):
    """No Info frame; its first frame's sync wiped, or the whole frame garbled. Old: from sound, LAME's first
    frame (256 kbit/s at 44.1 kHz: 835 bytes) counted as 2 frames at the file's mean, the sound a frame
    late, the audio a frame long; after silence (its first frame 104 bytes) none, the sound a frame early,
    unsaid. Now: one frame put back, on time, said; the same within an import (decoded into a scratch
    file)."""
    signal = np.concatenate([np.zeros(round(rate * silence), np.float32), _speech_like(2.0, rate)])
    data = _vbr_bytes(signal, rate, channels, write_xing="0")
    first, second = _first_frames(data)
    if garble == "sync":
        damaged = data[:first] + b"\x12\x34" + data[first + 2 :]
    else:
        damaged = data[:first] + np.random.default_rng(4).bytes(second - first) + data[second:]
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    at = round(rate * (silence + 1.0))
    path = _write(tmp_path / "damaged.mp3", damaged)
    for scratch in (None, tmp_path / "scratch"):
        repairs: list = []
        with audio_left_in_files(scratch):
            got = read_audio(path, repairs).mono_float()
        assert len(got) == len(whole)
        assert lag(whole[at : at + 4096], got[at - 2000 :], 3000) == 2000
        (note,) = _bad_audio(repairs)
        assert "at 0.000 s: 1 frame(s) lost" in note and "put back as silence" in note


@pytest.mark.parametrize("zeros", [1, 417, 4096])
@pytest.mark.parametrize("rate, channels", [(44100, 2), (16000, 1)])
def test_zeros_after_the_id3_tag_of_a_lame_file_give_no_delay_note(tmp_path, rate, channels, zeros):
    """An ID3v2 tag padded with zeros past the size it declares, then LAME's Info frame and tag. Old: the
    same samples, but "encoder_delay_unknown" noted (FFmpeg, asked, did not find the LAME tag after the
    zeros; libsndfile's decoder had dropped the delay it records). Now: no repair, the same samples."""
    data = mp3_bytes(_speech_like(2.0, rate), rate, channels)
    first, _ = _first_frames(data)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    padded = _write(tmp_path / "padded.mp3", data[:first] + bytes(zeros) + data[first:])
    got = read_audio(padded, repairs).mono_float()
    assert repairs == []
    assert np.array_equal(got, whole)


def _bare(signal: np.ndarray, rate: int, channels: int) -> bytes:
    """An .mp3 of no tag nor Info frame: its frames only."""
    return mp3_bytes(signal, rate, channels, write_xing="0", id3v2_version="0")


@pytest.mark.parametrize(
    "rate, channels, frames", [(44100, 2, 4), (32000, 1, 2), (16000, 1, 3), (24000, 2, 3)]
)
def test_a_clip_of_under_8_frames_joined_on_at_another_rate_is_refused(tmp_path, rate, channels, frames):
    """A real clip of 2 to 4 frames of sound (3 to 5 frames with LAME's delay and padding: 0.07 to 0.18 s)
    joined on bare after 2 s at 48 kHz. Old: left out as
    junk ("headers ... that their bytes form by chance"), the clip lost. Now: its first frame begins its
    sound in its own bytes and each frame's side information is a frame of sound's: refused as any file
    joined on at another rate is, saying where."""
    per_frame = 1152 if rate >= 32000 else 576
    clip = _bare(_speech_like(frames * per_frame / rate, rate), rate, channels)
    path = _write(tmp_path / "joined.mp3", _bare(_speech_like(2.0, 48000), 48000, 2) + clip)
    with pytest.raises(InputError, match=f"sample rate changes from 48000 to {rate} Hz at about 2.0"):
        read_audio(path, [])


def test_a_short_mono_clip_joined_on_at_the_same_rate_is_decoded(tmp_path):
    """A 3-frame mono clip joined on bare after 2 s of stereo at 44.1 kHz. Old: left out as junk. Now:
    decoded after it, mixed to stereo (said)."""  # 0.07 s: 3 frames with LAME's delay and padding
    rate = 44100
    song = _bare(_speech_like(2.0, rate), rate, 2)
    whole = read_audio(_write(tmp_path / "song.mp3", song), []).frames
    repairs: list = []
    got = read_audio(
        _write(tmp_path / "joined.mp3", song + _bare(_speech_like(0.07, rate), rate, 1)), repairs
    )
    assert got.channels == 2 and got.frames >= whole + 2 * 1152
    assert [r["kind"] for r in repairs].count("channels_changed") == 1
    assert not [note for note in _bad_audio(repairs) if "no audio" in note]


@pytest.mark.parametrize("seed, dense", [(0, 0.3), (1, 0.6), (1, 0.9), (2, 0.99)])
def test_junk_alone_is_no_mpeg_audio(tmp_path, seed, dense):
    """100 KB of bytes, ``dense`` of them 0xFF (a picture or junk named .mp3). Old: read as noise from the
    frame headers its bytes chain by chance (768 to 3072 samples, damage said). Now: an InputError saying
    no MPEG audio was found."""
    rng = np.random.default_rng(seed)
    junk = rng.integers(0, 256, 100_000, dtype=np.uint8)
    junk[rng.random(junk.size) < dense] = 0xFF
    path = _write(tmp_path / "junk.mp3", junk.tobytes())
    with pytest.raises(InputError, match="no MPEG audio found in its 100000 bytes"):
        read_audio(path, [])


@pytest.mark.parametrize("lead", [0, 300])
def test_a_tiny_mp3_is_still_read(tmp_path, lead):
    """A 2-frame file (no tag nor Info frame), alone or after 300 stray bytes (a header not known here): no
    run of 8 frames, but its frames are most of its bytes: read, not refused."""
    data = _bare(_speech_like(0.03, 44100), 44100, 1)
    stray = np.random.default_rng(5).integers(1, 255, lead, dtype=np.uint8).tobytes()
    audio = read_audio(_write(tmp_path / "tiny.mp3", stray + data), [])
    assert audio.frames >= 1152


def test_junk_after_the_audio_is_still_left_out(tmp_path):
    """1 MB of 0xFF-dense junk after 2 s at 16 kHz: its chance frame headers are still no file joined on."""
    song = _bare(_speech_like(2.0, 16000), 16000, 1)
    whole = read_audio(_write(tmp_path / "song.mp3", song), []).frames
    repairs: list = []
    got = read_audio(_write(tmp_path / "junk.mp3", song + _junk(1 << 20, 3)), repairs)
    assert got.frames == whole
    assert any("left out" in note for note in _bad_audio(repairs))
