"""Review of the MP3 junk and lost-first-frame change (``capture/audio_io.py``). Zeros a tagger wrote after
an ID3v2 tag, past the size it declares, exactly as long as whole frames at the audio's bit rate, were taken
for frames lost before its first (put back as silence: the sound late by them, a false note); before a
Xing/Info frame, which a file begins with, no frames can be lost. A real clip of 0.3 s joined on at another
sample rate without a tag (over 8 frames) was left out as junk (said to be chance headers); it is refused, as
any file joined on at another rate is.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_audio_mp3_later_parts import mp3_bytes
from test_import_mp3_damage import _speech_like, _write
from test_mp3_s26 import _bad_audio, _first_frames

from capture import InputError, read_audio


@pytest.mark.parametrize("xing", [True, False], ids=["info_frame", "no_info_frame"])
@pytest.mark.parametrize(
    "rate, channels, bit_rate, zeros",
    [(44100, 2, 128000, 417), (44100, 2, 128000, 418), (48000, 1, 64000, 576), (48000, 2, 128000, 1536)],
)
def test_zeros_after_an_id3_tag_are_no_lost_frames(tmp_path, xing, rate, channels, bit_rate, zeros):
    """Zeros after the tag exactly as long as 1 to 4 frames (128 kbit/s at 44.1 kHz: 417.96 bytes a frame;
    64 kbit/s at 48 kHz: 192). Old: that many frames of silence put back at 0.000 s, the sound late by them,
    said as damage. Now: the same samples as without the zeros, no damage said."""
    options = {} if xing else {"write_xing": "0"}
    data = mp3_bytes(_speech_like(2.0, rate), rate, channels, bit_rate, **options)
    first, _ = _first_frames(data)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    padded = data[:first] + bytes(zeros) + data[first:]
    got = read_audio(_write(tmp_path / "padded.mp3", padded), repairs).mono_float()
    assert _bad_audio(repairs) == []
    assert len(got) == len(whole) and np.array_equal(got, whole)


def _bare(seconds: float, rate: int) -> bytes:
    """An .mp3 of no tag nor Info frame, stereo: its frames only."""
    return mp3_bytes(_speech_like(seconds, rate), rate, 2, write_xing="0", id3v2_version="0")


@pytest.mark.parametrize("rate", [44100, 32000, 22050, 16000])
def test_a_short_clip_joined_on_at_another_rate_is_refused(tmp_path, rate):
    """A real 0.3 s clip (9 to 14 frames: chance headers in junk chain 5 at most) joined on bare at another
    rate. Old: left out as junk, "headers ... that their bytes form by chance", the clip lost. Now: refused
    as any file joined on at another rate, saying where."""
    path = _write(tmp_path / "joined.mp3", _bare(2.0, 48000) + _bare(0.3, rate))
    with pytest.raises(InputError, match=f"sample rate changes from 48000 to {rate} Hz at about 2.0"):
        read_audio(path, [])


@pytest.mark.parametrize("rate, channels", [(11025, 2), (32000, 1), (44100, 2)])
def test_junk_ending_in_a_frame_header_is_no_frames_lost(tmp_path, rate, channels):
    """Junk after the audio (no 0xFF in it) whose last 4 bytes are a frame header of the audio's format (its
    frame would run past the data's end). Old: the junk taken for damage inside the audio, as many frames
    as its bytes could hold put back as silence at its end (an IndexError before that). Now: the audio as
    long as without the junk, no frames said put back."""
    song = mp3_bytes(_speech_like(2.0, rate), rate, channels)
    _, second = _first_frames(song)
    junk = np.random.default_rng(1).integers(0, 255, 1200, dtype=np.uint8).tobytes()
    whole = read_audio(_write(tmp_path / "song.mp3", song), [])
    repairs: list = []
    got = read_audio(_write(tmp_path / "junk.mp3", song + junk + song[second : second + 4]), repairs)
    assert got.frames == whole.frames
    assert not [note for note in _bad_audio(repairs) if "put back" in note]


def test_junk_chaining_frames_of_another_layer_at_the_audio_rate_is_left_out(tmp_path):
    """Junk after 44.1 kHz stereo layer III audio in which three layer I mono frame headers at 44.1 kHz chain
    (as 0xFF-dense junk forms them by chance). Old: the junk decoded as a file joined on, 1152 samples of
    noise mixed to stereo after the audio ("channel count changes"). Now: left out as other-rate junk is."""
    rate = 44100
    song = mp3_bytes(_speech_like(2.0, rate), rate, 2)
    rng = np.random.default_rng(2)

    def stray(size: int) -> bytes:
        return rng.integers(0, 255, size, dtype=np.uint8).tobytes()  # no 0xFF: no header of their own

    layer_1 = b"\xff\xff\x10\xc0"  # MPEG-1 layer I, 32 kbit/s, 44.1 kHz, mono: 32-byte frames
    junk = stray(500) + b"".join(layer_1 + stray(28) for _ in range(3)) + stray(900)
    whole = read_audio(_write(tmp_path / "song.mp3", song), [])
    repairs: list = []
    got = read_audio(_write(tmp_path / "junk.mp3", song + junk), repairs)
    assert got.frames == whole.frames and got.channels == 2
    assert not [r for r in repairs if r["kind"] == "channels_changed"]
    (note,) = _bad_audio(repairs)
    assert f"{len(junk)} bytes after the MPEG audio's last frames" in note and "left out" in note
