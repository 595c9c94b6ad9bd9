"""Review of the MP3 reader's refusal of junk (``capture/audio_io.py``, ``_refuse_no_mpeg_audio``, 2c343ed).
Bytes dense in 0xFF chain a frame header, or a few damaged frames, at their very first byte in 1 to 3 % of
100 KB files: that alone let such junk be read as noise. Now only a run of 2 or more frames without damage
there counts as audio. And a real file wrecked by garbage (no 8 frames in a row left, its start lost) was
refused as junk: now its many frames of sound tell it is audio.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_audio_mp3_later_parts import mp3_bytes
from test_import_mp3_damage import _speech_like, _write
from test_mp3_s27 import _mp2_bytes

from capture import InputError, read_audio
from capture.audio_io import _mpeg_frame, _mpeg_frame_table, mpeg_runs


def _dense_junk(dense: float, seed: int) -> bytes:
    """100 KB of random bytes, ``dense`` of them 0xFF."""
    rng = np.random.default_rng(seed)
    junk = rng.integers(0, 256, 100_000, dtype=np.uint8)
    junk[rng.random(junk.size) < dense] = 0xFF
    return junk.tobytes()


@pytest.mark.parametrize("dense, seed", [(0.6, 1140), (0.75, 1017), (0.75, 1064), (0.9, 1126)])
def test_junk_whose_first_bytes_chain_frames_is_no_mpeg_audio(tmp_path, dense, seed):
    """Junk whose first bytes form frame headers by chance (3 to 7 layer I frames with damage between
    them, or a single one). Old (2c343ed): read as noise, damage said. Now: "no MPEG audio found"."""
    data = _dense_junk(dense, seed)
    _mpeg_frame_table()
    assert mpeg_runs(data)[0].start == 0  # the case: a chance frame at the first byte
    with pytest.raises(InputError, match="no MPEG audio found in its 100000 bytes"):
        read_audio(_write(tmp_path / "junk.mp3", data), [])


@pytest.mark.parametrize("layout", ["bare", "tagged"])
def test_a_short_clip_before_junk_is_still_read(tmp_path, layout):
    """A 0.1 s clip (no run of 8 frames), then 100 KB of 0xFF-dense junk: its undamaged frames start where
    the audio would, so it is read (the junk left out), not refused."""
    options = {"write_xing": "0", "id3v2_version": "0"} if layout == "bare" else {}
    clip = mp3_bytes(_speech_like(0.1, 44100), 44100, 1, **options)
    alone = read_audio(_write(tmp_path / "clip.mp3", clip), []).frames
    repairs: list = []
    got = read_audio(_write(tmp_path / "joined.mp3", clip + _dense_junk(0.9, 3)), repairs)
    assert got.frames == alone


def _wrecked(layer: str, keep: int, lose: int, start_lost: bool) -> bytes:
    """6 s at 44.1 kHz (layer III at 320 kbit/s, or layer II; no tag nor Info frame) of which ``lose``
    frames in every ``keep + lose`` were overwritten by random bytes (no 8 frames in a row left, garbage
    over half its bytes), its first 2000 bytes too when ``start_lost``."""
    signal = _speech_like(6.0, 44100)
    if layer == "III":
        data = mp3_bytes(signal, 44100, 2, 320_000, write_xing="0", id3v2_version="0")
    else:
        data = _mp2_bytes(signal, 44100, 2)
    _mpeg_frame_table()
    starts = [0]
    while (frame := _mpeg_frame(data, starts[-1])) is not None:
        starts.append(starts[-1] + frame[0])
    rng = np.random.default_rng(keep)
    wrecked = bytearray(data)
    for i in range(keep, len(starts) - lose, keep + lose):
        wrecked[starts[i] : starts[i + lose]] = rng.bytes(starts[i + lose] - starts[i])
    if start_lost:
        wrecked[:2000] = rng.bytes(2000)
    return bytes(wrecked)


@pytest.mark.parametrize("start_lost", [False, True], ids=["start_kept", "start_lost"])
@pytest.mark.parametrize(
    "layer, keep, lose", [("III", 3, 4), ("III", 2, 3), ("III", 7, 8), ("II", 3, 4), ("II", 7, 8)]
)
def test_a_file_wrecked_by_garbage_is_still_read(tmp_path, layer, keep, lose, start_lost):
    """Garbage over most of a real file's bytes (a disk's bad sectors), no 8 frames in a row left. Old
    (2c343ed): with its start lost, refused as "no MPEG audio found". Now: read as before that change, its
    frames that may be sound counted (dozens; junk has none or one), about its length, the damage said."""
    data = _wrecked(layer, keep, lose, start_lost)
    repairs: list = []
    audio = read_audio(_write(tmp_path / "wrecked.mp3", data), repairs)
    assert abs(audio.duration_s - 6.0) < 0.5
    assert any(r["kind"] == "bad_audio" for r in repairs)
