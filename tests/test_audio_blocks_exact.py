"""The block-by-block audio work of align and features, exact to the whole-array code: to_16k_mono (soxr
streaming, blockwise DC mean, rumble filter in place), the clipping and clap searches, and the level gain
applied per pitch piece."""

from __future__ import annotations

import numpy as np
import pytest
import soxr
from scipy.signal import butter, sosfilt, sosfilt_zi

import dataset.pitch as pitch_mod
from align import resample
from align.clipping import CLIP_RUN, _flat_samples
from align.resample import HIGHPASS_HZ, TARGET_RATE, mono_mean, to_16k_mono
from capture import Audio
from capture.runs import run_bounds
from dataset.pitch import PitchSettings, track_pitch


def _old_to_16k_mono(audio: Audio) -> np.ndarray:
    """The whole-array conversion before it went block by block (mono input): mean, one-shot soxr,
    rumble filter."""
    x = audio.mono_float()
    dc = float(np.sum(x, dtype=np.float64)) / max(x.size, 1)
    if dc != 0.0:
        x = x - np.float32(dc)
    if audio.sample_rate != TARGET_RATE:
        x = soxr.resample(x.astype(np.float32), audio.sample_rate, TARGET_RATE, quality="VHQ")
    if x.size == 0:
        return np.zeros(0, np.float32)
    if x.size < 64:
        return np.ascontiguousarray(x - np.mean(x, dtype=np.float64), dtype=np.float32)
    sos = butter(2, HIGHPASS_HZ, btype="highpass", fs=TARGET_RATE, output="sos")
    y = sosfilt(sos, x.astype(np.float64), zi=sosfilt_zi(sos) * float(x[0]))[0].astype(np.float32)
    return sosfilt(sos, y[::-1].astype(np.float64))[::-1].astype(np.float32)


@pytest.mark.parametrize("rate", [8000, 16000, 44100])
def test_to_16k_mono_blocks_match_the_whole_array_conversion(monkeypatch, rate):
    """Small blocks (a multiple of NumPy's buffer, as sum64 needs) over inputs shorter than one block,
    exactly one, and with a last partial one: the same samples to the bit, the caller's untouched."""
    monkeypatch.setattr(resample, "_CHUNK", 8192)
    rng = np.random.default_rng(rate)
    for n in (0, 10, 8191, 8192, 8192 * 3 + 17):
        pcm = np.round(rng.normal(0.05, 0.1, n) * 32767).clip(-32768, 32767).astype(np.int16)
        audio = Audio(pcm, rate, "PCM_16")
        kept = audio.samples.copy()
        got = to_16k_mono(audio)
        assert np.array_equal(audio.samples, kept)
        assert got.dtype == np.float32 and got.tobytes() == _old_to_16k_mono(audio).tobytes(), n


def test_mono_mean_of_many_channels_with_a_short_last_block(monkeypatch):
    """A file of more than 64 channels whose last block holds fewer frames than channels: mono_mean
    (predict's DC offset) made each block a new Audio, which refused it as (channels, samples)."""
    monkeypatch.setattr(resample, "_CHUNK", 8192)
    x = np.random.default_rng(1).normal(0.01, 0.1, (8192 + 10, 70)).astype(np.float32)
    audio = Audio(x, 48000)
    assert mono_mean(audio) == float(np.mean(audio.mono_float(), dtype=np.float64))


def test_flat_samples_runs_across_blocks():
    """Runs that reach a block's end, span whole blocks or end the channel: counted as on the whole."""
    rng = np.random.default_rng(3)
    for _ in range(3000):
        x = (rng.random(int(rng.integers(0, 40))) < rng.random()).astype(np.int8)
        starts, stops = run_bounds(x == 1)
        lengths = stops - starts
        assert _flat_samples(x, 1, block=int(rng.integers(1, 7))) == int(lengths[lengths >= CLIP_RUN].sum())


def _captured_pieces(monkeypatch) -> list[tuple[np.ndarray, float]]:
    seen: list[tuple[np.ndarray, float]] = []

    def fake(parselmouth, audio, start_s, sample_rate, hop_s, settings, peak):
        seen.append((np.array(audio), peak))
        t = start_s + np.arange(int(audio.size / sample_rate / hop_s)) * hop_s
        return t, np.full(t.size, 120.0)

    monkeypatch.setattr(pitch_mod, "_praat_pitch", fake)
    return seen


def test_track_pitch_scales_float64_audio_as_float32(monkeypatch):
    """The pieces given to Praat are float32 ``audio * np.float32(gain)``, as the whole scaled copy
    was: float64 audio was scaled in float64 piece by piece."""
    seen = _captured_pieces(monkeypatch)
    audio = np.random.default_rng(5).normal(0, 0.1, 16000 * 2)  # float64, not float32 values
    track_pitch(audio, 16000, 100, 0.02, PitchSettings(), gain=0.37)
    scaled = np.asarray(audio, np.float32) * np.float32(0.37)
    ((piece, peak),) = seen
    assert piece.dtype == np.float32 and np.array_equal(piece, scaled)
    assert peak == float(np.max(np.abs(scaled)))


def test_track_pitch_peak_with_a_negative_gain(monkeypatch):
    """A negative gain (a polarity flip) keeps the peak the largest magnitude: it was the negative of
    the smaller extreme, and Praat's silence threshold with it."""
    seen = _captured_pieces(monkeypatch)
    audio = np.random.default_rng(6).normal(0, 0.1, 16000 * 2).astype(np.float32)
    audio[100] = 0.9  # extremes of unequal size
    track_pitch(audio, 16000, 100, 0.02, PitchSettings(), gain=-0.5)
    ((_, peak),) = seen
    assert peak == float(np.max(np.abs(audio * np.float32(-0.5)))) == pytest.approx(0.45)
