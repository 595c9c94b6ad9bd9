"""MP3 damage at a file's start, and junk (``capture/audio_io.py``). The first frame of sound's header wiped
was read a frame early: after an Info frame the silent frame put back for it was skipped by FFmpeg (its
header's channel mode and flags were the Info frame's, not the next frame's: FFmpeg opens a stream where two
headers agree in those), and without one the lost frame went unseen (the frame after it begins its sound in
the bytes of the lost one, as no file's first frame does). A destroyed Info frame (its bytes garbled, its
header valid) was decoded as a frame of sound: the sound a frame and the encoder's delay late, the note's
bound short of it. Damage in a free-format stream (no frame scan: FFmpeg cannot decode free format to put
lost frames back) left the sound after it early, unsaid. 5 MB of bytes dense in 0xFF took 32 s to scan (each
look for the next 0xFF read 2 MB again).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from test_audio_mp3_later_parts import lag, mp3_bytes
from test_audiofile_s25 import _free_format
from test_import_mp3_damage import _damaged, _speech_like, _write

from capture import read_audio
from capture.audio_io import LAME_DELAY, _FileBytes, _mpeg_frame, _mpeg_frame_table, _tag_bytes, mpeg_runs


def _first_frames(data: bytes) -> tuple[int, int]:
    """Where the first frame (after the ID3v2 tag) and the one after it start."""
    _mpeg_frame_table()
    pos = _tag_bytes(data, 0)
    frame = _mpeg_frame(data, pos)
    assert frame is not None
    return pos, pos + frame[0]


def _bad_audio(repairs: list) -> list[str]:
    return [r["message"] for r in repairs if r["kind"] == "bad_audio"]


@pytest.mark.parametrize("xing", [True, False], ids=["info_frame", "no_info_frame"])
@pytest.mark.parametrize("rate, channels", [(44100, 2), (16000, 1)])
def test_a_first_frame_whose_sync_was_wiped_is_put_back_as_silence(tmp_path, xing, rate, channels):
    """Old: the sound a frame early (1152 samples at 44.1 kHz, 576 at 16 kHz), the audio that much short;
    with an Info frame the loss said "at -0.0xx s", without one not said. Now: on time, the same length,
    the frame said lost at 0.000 s."""
    data = mp3_bytes(_speech_like(2.0, rate), rate, channels, **({} if xing else {"write_xing": "0"}))
    info, first = _first_frames(data)
    at = first if xing else info  # the first frame of sound
    damaged = data[:at] + b"\x12\x34" + data[at + 2 :]
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    got = read_audio(_write(tmp_path / "damaged.mp3", damaged), repairs).mono_float()
    assert len(got) == len(whole)
    assert lag(whole[rate : rate + 4096], got[rate - 2000 :], 3000) == 2000
    (note,) = _bad_audio(repairs)
    assert "at 0.000 s: 1 frame(s) lost" in note and "put back as silence" in note


@pytest.mark.parametrize("garble", ["zeros", "random"])
@pytest.mark.parametrize("rate, channels", [(44100, 2), (22050, 1)])
def test_a_destroyed_info_frame_is_left_out_and_said(tmp_path, garble, rate, channels):
    """Old: the garbled Info frame decoded as a frame of sound, the encoder's delay kept: the sound 1105 +
    1152 samples late at 44.1 kHz (2257, past the 2112 the delay note allows). Now: left out, said
    (bad_audio), the delay said unknown: the sound late by LAME's delay only."""
    data = mp3_bytes(_speech_like(2.0, rate), rate, channels)
    info, first = _first_frames(data)
    body = first - info - 4
    garbled = bytearray(body) if garble == "zeros" else bytearray(np.random.default_rng(3).bytes(body))
    if garble == "random":
        garbled[0] |= 0x80  # its sound begun in bytes before it (main_data_begin), as no first frame's is
    damaged = data[: info + 4] + bytes(garbled) + data[first:]
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    got = read_audio(_write(tmp_path / "damaged.mp3", damaged), repairs).mono_float()
    assert lag(whole[rate : rate + 4096], got[rate:], 4000) == LAME_DELAY
    (note,) = _bad_audio(repairs)
    assert "Xing/Info header frame" in note and "left out" in note
    assert [r["kind"] for r in repairs].count("encoder_delay_unknown") == 1


@pytest.mark.parametrize("xing", ["1", "0"])
def test_damage_in_a_free_format_mp3_is_said(tmp_path, xing):
    """Old: 600 damaged bytes of 48 kHz free format at 128 kbit/s: the sound after them 2 frames (2304
    samples, 48 ms) early, nothing said. Now said, with how much; the undamaged file says nothing of it."""
    rate = 48000
    signal = _speech_like(3.0, rate)
    free = _free_format(mp3_bytes(signal, rate, 1, 128000, write_xing=xing))
    whole_repairs: list = []
    whole = read_audio(_write(tmp_path / "whole.mp3", free), whole_repairs).mono_float()
    assert _bad_audio(whole_repairs) == []
    repairs: list = []
    got = read_audio(_write(tmp_path / "damaged.mp3", _damaged(free, (0.5, 600))), repairs).mono_float()
    at = round(rate * 2.2)
    assert lag(whole[at : at + 4096], got[at - 3000 :], 6000) == 3000 - 2304
    (note,) = _bad_audio(repairs)
    assert "about 2 frame(s) lost there (48 ms); free format" in note and "at about 1.5" in note


def _junk(size: int, seed: int) -> bytes:
    """``size`` bytes, 90 % of them 0xFF, the others random (a picture's bytes mislabelled as audio)."""
    rng = np.random.default_rng(seed)
    junk = rng.integers(0, 256, size, dtype=np.uint8)
    junk[rng.random(size) < 0.9] = 0xFF
    return junk.tobytes()


def test_junk_dense_in_0xff_is_scanned_in_about_linear_time(tmp_path):
    """Old: 5 MB took 32 s (128 s on a busy machine); now about 1 s. A loose bound: 10 s of CPU time (not
    wall-clock time, which a busy machine stretches)."""
    path = _write(tmp_path / "junk.mp3", _junk(5 << 20, 7))
    start = time.process_time()
    with _FileBytes.of(path) as data:
        mpeg_runs(data)
    assert time.process_time() - start < 10


def test_the_scan_finds_the_same_frames_in_a_file_read_a_block_at_a_time(tmp_path):
    """Frames between junk that spans the scan's 2 MB blocks are found alike in the bytes held whole and
    read a block at a time (the search for the next header moves from block to block)."""
    song = mp3_bytes(_speech_like(2.0, 16000), 16000, 1)
    data = song + _junk(3 << 20, 1) + song + _junk(1 << 20, 2) + song
    path = _write(tmp_path / "joined.mp3", data)
    with _FileBytes.of(path) as blocks:
        assert mpeg_runs(blocks) == mpeg_runs(data)
    assert sum(run.new_file for run in mpeg_runs(data)) >= 3
