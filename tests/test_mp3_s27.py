"""The MP3 reader's last damage cases (``capture/audio_io.py``). Junk after an .mp3's audio (appended
garbage, a picture written after it) whose 0xFF-dense bytes chain frame headers of other sample rates was
refused as a file joined at another rate ("sample rate changes from 48000 to 32000 Hz"), or a traceback
(IndexError: a header in its last bytes); now left out, said. A damaged .mp3 libsndfile cannot open (its
first frame of sound wiped after an Info frame, at 8 to 24 kHz) was decoded by FFmpeg as it is: read a frame
early, unsaid; now it gets the MP3 repairs. A first frame lost where nothing else tells it (layer II; layer
III after silence at 320 kbit/s: no bit reservoir used) was missed: its bytes are as long as a frame at its
bit rate, now put back as silence, said.
"""

from __future__ import annotations

import io

import av
import numpy as np
import pytest
import soundfile as sf
from test_audio_mp3_later_parts import lag, mp3_bytes
from test_import_mp3_damage import _speech_like, _write
from test_mp3_s26 import _bad_audio, _first_frames, _junk

from capture import InputError, read_audio


def _on_time(whole: np.ndarray, got: np.ndarray, at: int) -> int:
    """How far the sound at ``at`` in ``whole`` lies from there in ``got`` (samples: 0 on time)."""
    return lag(whole[at : at + 4096], got[at - 2000 :], 3000) - 2000


@pytest.mark.parametrize(
    "rate, channels, seed, size",
    [(48000, 2, 0, 1 << 20), (44100, 2, 3, 3 << 20), (16000, 1, 2, 1 << 16), (8000, 1, 5, 1 << 20)],
)
def test_junk_after_the_audio_is_left_out_and_said(tmp_path, rate, channels, seed, size):
    """Old: an InputError "the MP3's sample rate changes from ... Hz" (the junk's chance frame headers taken
    for a file joined on at another rate; each run of them 3 frames at most, here), at 16 kHz an IndexError.
    Now: the audio read to its end, as long as without the junk, the junk said left out."""
    song = mp3_bytes(_speech_like(2.0, rate), rate, channels)
    whole = read_audio(_write(tmp_path / "song.mp3", song), [])
    repairs: list = []
    got = read_audio(_write(tmp_path / "junk.mp3", song + _junk(size, seed)), repairs)
    assert got.frames == whole.frames and got.channels == channels
    assert _on_time(whole.mono_float(), got.mono_float(), rate) == 0
    (note,) = _bad_audio(repairs)
    assert f"{size} bytes after the MPEG audio's last frames" in note and "left out" in note


def _bare(seconds: float, rate: int, channels: int) -> bytes:
    """An .mp3 of no tag nor Info frame: its frames only."""
    return mp3_bytes(_speech_like(seconds, rate), rate, channels, write_xing="0", id3v2_version="0")


def test_a_file_joined_on_at_another_rate_is_still_refused(tmp_path):
    """A bare file at another rate joined on (no tag, no Info frame between): a second of frames, no
    chance headers: refused as before, saying where."""
    path = _write(tmp_path / "joined.mp3", _bare(2.0, 48000, 2) + _bare(1.0, 32000, 2))
    with pytest.raises(InputError, match="sample rate changes from 48000 to 32000 Hz at about 2.0"):
        read_audio(path, [])


@pytest.mark.parametrize("rate, channels", [(8000, 1), (11025, 2), (12000, 1)])
def test_an_mp3_libsndfile_cannot_open_gets_the_mp3_repairs(tmp_path, rate, channels):
    """Its first frame of sound's sync wiped after the Info frame, at 8 kbit/s: libsndfile cannot open it.
    Old: FFmpeg decoded it as it is, the sound a frame (576 samples) early, the audio short, unsaid. Now: the
    frame put back as silence, on time, said."""
    data = mp3_bytes(_speech_like(2.0, rate), rate, channels, 8000)
    _, first = _first_frames(data)
    path = _write(tmp_path / "damaged.mp3", data[:first] + b"\x12\x34" + data[first + 2 :])
    with pytest.raises(sf.LibsndfileError):
        sf.info(str(path))
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    got = read_audio(path, repairs).mono_float()
    assert len(got) == len(whole) and _on_time(whole, got, rate) == 0
    (note,) = _bad_audio(repairs)
    assert "at 0.000 s: 1 frame(s) lost" in note and "put back as silence" in note


def _mp2_bytes(signal: np.ndarray, rate: int, channels: int) -> bytes:
    """``signal`` (mono float) as MPEG layer II, FFmpeg's encoder, on each of ``channels``, a raw .mp2."""
    out = io.BytesIO()
    with av.open(out, "w", format="mp2") as container:
        stream = container.add_stream("mp2", rate=rate, layout="mono" if channels == 1 else "stereo")
        pcm = (np.tile(signal, (channels, 1)) * 32767).astype(np.int16)
        frame = av.AudioFrame.from_ndarray(pcm, format="s16p", layout=stream.layout.name)
        frame.sample_rate = rate
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return out.getvalue()


@pytest.mark.parametrize("garble", ["sync", "frame"])
@pytest.mark.parametrize(
    "layer, rate, channels", [("II", 44100, 2), ("II", 22050, 1), ("III", 48000, 1), ("III", 32000, 2)]
)
def test_a_first_frame_lost_is_told_by_its_length(tmp_path, layer, rate, channels, garble):
    """The first frame's sync wiped, or the whole frame garbled, no Info frame; layer III after 0.5 s of
    silence at 320 kbit/s (its next frame uses no bit reservoir). Old: the sound a frame (1152 samples)
    early, the audio short, unsaid. Now: the bytes before the first frame found are a frame's at its bit
    rate: put back as silence, on time, said (layer II at 22.05 kHz: a frame of 1152 samples, not 576)."""
    signal = np.concatenate([np.zeros(rate // 2, np.float32), _speech_like(2.0, rate)])
    if layer == "II":
        data = _mp2_bytes(signal, rate, channels)
    else:
        data = mp3_bytes(signal, rate, channels, 320000, write_xing="0")
    first, second = _first_frames(data)
    if garble == "sync":
        damaged = data[:first] + b"\x12\x34" + data[first + 2 :]
    else:
        damaged = data[:first] + np.random.default_rng(4).bytes(second - first) + data[second:]
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    got = read_audio(_write(tmp_path / "damaged.mp3", damaged), repairs).mono_float()
    assert len(got) == len(whole) and _on_time(whole, got, rate + rate // 2) == 0
    (note,) = _bad_audio(repairs)
    assert "at 0.000 s: 1 frame(s) lost" in note and "put back as silence" in note
