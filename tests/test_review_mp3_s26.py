"""Review of c01114f (MP3 damage at a file's start). A clean MP3 cut from a longer one at a frame (an
editor's cut, a stream recorded from its middle) begins with a frame whose sound starts in reservoir bytes
cut off; when the frame after it starts its sound in its own bytes, the destroyed-Info-frame rule took that
first frame for a garbled Info frame: left out (the sound a frame early, the audio a frame short) and the
file said damaged. Its side information is a frame of sound's, as garbled bytes' seldom is: kept now.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_audio_mp3_later_parts import lag, mp3_bytes
from test_import_mp3_damage import _speech_like, _write

from capture import read_audio
from capture.audio_io import _mpeg_frame, _mpeg_frame_table, _starts_reservoir, _tag_bytes


def _frame_starts(data: bytes) -> list[int]:
    _mpeg_frame_table()
    starts, pos = [], _tag_bytes(data, 0)
    while (frame := _mpeg_frame(data, pos)) is not None:
        starts.append(pos)
        pos += frame[0]
    return starts


def _cuts_before_a_fresh_start(data: bytes) -> list[int]:
    """Frame indices ``k`` (not the first two) whose frame uses reservoir bytes while frame ``k + 1`` starts
    its sound in its own bytes: a file cut there begins as a destroyed Info frame's file may."""
    starts = _frame_starts(data)
    fresh = [_starts_reservoir(data, pos, _mpeg_frame(data, pos)) for pos in starts]
    return [k for k in range(2, len(starts) - 2) if fresh[k + 1] and not fresh[k]]


@pytest.mark.parametrize(
    "rate, channels, bit_rate", [(11025, 1, 160000), (44100, 2, 320000), (22050, 2, 160000), (8000, 1, 64000)]
)
def test_a_clean_mp3_cut_at_a_frame_keeps_its_first_frame(tmp_path, rate, channels, bit_rate):
    """c01114f: the cut file's first frame left out, the sound a frame early (576 samples at 11025 Hz),
    and "begins with a damaged frame ... Xing/Info header frame" said; before it and now: on time, nothing
    said damaged."""
    signal = _speech_like(6.0, rate)
    signal[np.arange(len(signal)) % rate > 0.6 * rate] = 0  # pauses: frames after them start afresh
    data = mp3_bytes(signal, rate, channels, bit_rate, write_xing="0", id3v2_version="0")
    starts, samples = _frame_starts(data), _mpeg_frame(data, _tag_bytes(data, 0))[1]
    cuts = [k for k in _cuts_before_a_fresh_start(data) if k * samples < 2 * rate]
    assert cuts, "no cut of the kind in the encoded file"
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    at, window = round(3.05 * rate), rate // 2  # sound, between pauses
    for k in cuts[:3]:
        repairs: list = []
        cut = read_audio(_write(tmp_path / f"cut{k}.mp3", data[starts[k] :]), repairs).mono_float()
        assert [r for r in repairs if r["kind"] == "bad_audio"] == []
        # where the whole file's sound at ``at`` lies in the cut file: k frames earlier
        assert lag(whole[at : at + window], cut[at - k * samples - 2000 :], 3000) == 2000
