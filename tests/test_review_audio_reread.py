"""The review of the morning's changes to capture's audio: a .mov's tracks compared for the one to use
hold two tracks in memory at most (outside an import, where no scratch file takes them), a track's peak
is found without copies of its samples (an int16 track's peak took two float64 copies: 8 times the
track), and an .mp3 of joined files read outside an import is held once (its chunks and their join: 2.1
times the audio)."""

from __future__ import annotations

import numpy as np
from test_audio_decode_memory import _encoded
from test_long_take_memory import _traced_peak

from capture import Audio, write_reference_mov
from capture.audio_io import CHECK_FRAMES, finite_peak, read_audio
from capture.mov import choose_mov_audio


def _tone(rate: int, seconds: float) -> np.ndarray:
    t = np.arange(round(rate * seconds)) / rate
    return np.repeat((0.3 * np.sin(2 * np.pi * 220 * t)).astype(np.float32)[:, None], 2, axis=1)


def test_a_peak_is_found_without_a_copy_of_the_samples():
    rng = np.random.default_rng(3)
    pcm = rng.integers(-20000, 20000, (1 << 20, 2), dtype=np.int16)
    pcm[12345, 1] = -32768
    peak, traced = _traced_peak(finite_peak, Audio(pcm, 16000, "PCM_16"))
    assert peak == 1.0
    assert traced < pcm.nbytes / 8, f"traced {traced / 1e6:.1f} MB for a {pcm.nbytes / 1e6:.1f} MB track"

    x = rng.uniform(-0.5, 0.5, (16 * CHECK_FRAMES + 7, 2)).astype(np.float32)
    x[5, 0], x[CHECK_FRAMES + 1, 1], x[-1, 0] = np.nan, np.inf, -0.75  # the peak in the last block
    peak, traced = _traced_peak(finite_peak, Audio(x, 16000))
    assert peak == 0.75
    assert traced < x.nbytes / 4, f"traced {traced / 1e6:.1f} MB for a {x.nbytes / 1e6:.1f} MB track"
    assert finite_peak(Audio(np.zeros((0, 1), np.int16), 16000, "PCM_16")) == 0.0


def test_a_mov_of_three_tracks_holds_two_in_memory_at_most(tmp_path):
    """Outside an import each track is decoded into memory: the one chosen so far and the one decoded
    are held, not also the track let go before it (nor float64 copies for its peak)."""
    tone = _tone(16000, 30)
    tracks = [Audio(np.zeros_like(tone), 16000), Audio(tone, 16000), Audio(-tone, 16000)]
    mov = write_reference_mov(tmp_path / "take.mov", 30, 15, tracks)
    del tracks, tone
    (audio, choice), traced = _traced_peak(choose_mov_audio, mov)
    assert choice is not None and choice["track"] == 2 and audio.frames == 16000 * 30
    track = audio.samples.nbytes
    assert traced < 2.5 * track, f"traced {traced / track:.1f} tracks"


def test_joined_mp3_files_read_whole_are_held_once(tmp_path):
    part = _encoded("libmp3lame", "mp3", "fltp", 2, 5.0)
    joined = tmp_path / "joined.mp3"
    joined.write_bytes(part * 3)
    repairs: list = []
    audio, traced = _traced_peak(read_audio, joined, repairs)
    assert audio.channels == 2 and abs(audio.frames - 3 * 5 * 44100) < 3 * 1152 and repairs == []
    held = audio.samples.nbytes
    assert traced < 1.5 * held, f"traced {traced / held:.2f} times the audio"
