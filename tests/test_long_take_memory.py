"""Memory of align and predict on long takes: the audio is converted, resampled, filtered and searched
block by block, so that an hour of it needs a copy or two of its 16 kHz float32 samples, not a dozen
(``s2a-align`` peaked at 3.3 GB, ``s2a-train predict`` at 2.1 GB on an hour at 44.1 kHz). Each test
checks the traced peak of one step on two minutes of the real NeuroSync speech (44.1 kHz int16) against
a bound the whole-array code exceeded, and that the step's result is the same to the bit."""

from __future__ import annotations

import tracemalloc

import numpy as np
import parselmouth  # noqa: F401  imported before any peak is traced: a module's objects are no samples
import pytest
import scipy.signal  # noqa: F401
import soxr  # noqa: F401

from align.clipping import clipped_share
from align.resample import TARGET_RATE, mono_mean, remove_rumble, sum64, to_16k_mono
from align.transient import audio_claps
from capture import Audio, read_audio

MB = 1 << 20


@pytest.fixture(scope="module")
def two_minutes(samples) -> Audio:
    """Two minutes of real speech as recorded: the NeuroSync test set's 44.1 kHz int16, repeated."""
    speech = read_audio(samples / "paired" / "neurosync-trainer-lite-testset" / "audio.wav")
    frames = 120 * speech.sample_rate
    reps = -(-frames // speech.frames)
    return Audio(np.tile(speech.samples, (reps, 1))[:frames], speech.sample_rate, speech.subtype)


def _traced_peak(step, *args, **kwargs):
    """(result, peak bytes NumPy and Python allocated while ``step`` ran)."""
    tracemalloc.start()
    try:
        result = step(*args, **kwargs)
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_16k_audio_is_made_block_by_block_with_the_same_samples(two_minutes):
    """The whole-array code held the samples as float32 at 44.1 kHz three times over (mono, DC removed,
    a copy for the resampler): 63 MB here, 1.4 GB for an hour. Now the 16 kHz result and a block."""
    y, peak = _traced_peak(to_16k_mono, two_minutes)
    out = 120 * TARGET_RATE * 4  # the float32 result: 7.7 MB; the whole-array code peaked at 40 MB
    assert peak < 3 * out, f"traced peak {peak / MB:.1f} MB"
    x = two_minutes.mono_float()  # the whole-array way, for the comparison
    x = x - np.float32(np.sum(x, dtype=np.float64) / x.size)
    expected = remove_rumble(soxr.resample(x, two_minutes.sample_rate, TARGET_RATE, quality="VHQ"))
    assert y.dtype == np.float32 and np.array_equal(y, expected)


def test_the_mean_in_blocks_is_numpys_to_the_bit(two_minutes):
    """The DC offset is subtracted from every sample: summed in NumPy's own buffer order, its last bit
    is the whole array's."""
    x = two_minutes.mono_float()
    assert mono_mean(two_minutes) == float(np.mean(x, dtype=np.float64))
    odd = x[: 3 * (1 << 20) + 12_345]
    assert sum64(odd[i : i + (1 << 20)] for i in range(0, odd.size, 1 << 20)) == float(
        np.sum(odd, dtype=np.float64)
    )


def test_clipping_is_found_a_block_at_a_time(two_minutes):
    """The runs at a channel's extremes were found on the whole channel as int64 arrays: 2.5 GB for an
    hour. A flat top across a block boundary still counts whole."""
    samples = two_minutes.samples.copy()
    edge = 1 << 20
    samples[edge - 2 : edge + 2] = samples.max()  # 4 flat samples across the first block's end
    samples[5000:5003] = samples.min()
    audio = Audio(samples, two_minutes.sample_rate, two_minutes.subtype)
    share, peak = _traced_peak(clipped_share, audio)
    assert peak < samples.nbytes, f"traced peak {peak / MB:.1f} MB for {samples.nbytes / MB:.1f} MB"
    at_max = np.flatnonzero(np.diff(np.concatenate([[0], (samples[:, 0] == samples.max()), [0]])))
    at_min = np.flatnonzero(np.diff(np.concatenate([[0], (samples[:, 0] == samples.min()), [0]])))
    lengths = np.concatenate([np.diff(at_max)[::2], np.diff(at_min)[::2]])
    assert share == lengths[lengths >= 3].sum() / samples.shape[0] > 0


def test_claps_are_searched_without_float64_copies_of_the_audio(two_minutes):
    """The clap search held the high-passed audio in float64 with its float64 input and square (6 times
    the float32 audio, 1.4 GB an hour); a clap across a block boundary is still found."""
    x = to_16k_mono(two_minutes)
    quiet = np.zeros(x.size, np.float32)
    quiet[: 10 * TARGET_RATE] = 0.001 * x[: 10 * TARGET_RATE]
    clap = (1 << 20) - 40  # the high-passed samples of a clap straddle the first block's end
    quiet[clap : clap + 40] = 0.8 * np.hanning(40)
    found, peak = _traced_peak(audio_claps, quiet, 0.0)
    assert peak < 3 * quiet.nbytes, f"traced peak {peak / MB:.1f} MB for {quiet.nbytes / MB:.1f} MB of audio"
    assert len(found) == 1 and abs(found[0].time_s - clap / TARGET_RATE) < 0.003
