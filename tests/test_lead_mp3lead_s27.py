"""Stray bytes before a bare .mp3's first frame (a header not known here) that happen to be as long as many
whole frames at its bit rate are no frames lost: a wiped first frame or a few are told by their length,
seconds of frames are not (stray bytes of some length match whole frames about 1 in 200 times)."""

from __future__ import annotations

import numpy as np
import pytest
from test_import_mp3_damage import _write
from test_mp3_s26 import _bad_audio
from test_review_mp3junk_s27 import _bare

from capture import read_audio

FRAME_BYTES = 417.96  # 128 kbit/s at 44.1 kHz: 1152 samples a frame


@pytest.mark.parametrize("frames", [6, 10, 20])
def test_stray_bytes_as_long_as_many_frames_put_back_nothing(tmp_path, frames):
    data = _bare(2.0, 44100)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    stray = np.random.default_rng(frames).integers(1, 255, size=round(frames * FRAME_BYTES), dtype=np.uint8)
    repairs: list = []
    got = read_audio(_write(tmp_path / "stray.mp3", stray.tobytes() + data), repairs).mono_float()
    assert _bad_audio(repairs) == []  # was: that many frames put back at 0.000 s, the sound late by them
    assert len(got) == len(whole) and np.array_equal(got, whole)
