"""Memory of the dataset build on long takes, from an end-to-end review: an hour of paired speech (16 kHz)
with 52 ARKit channels at 60 fps peaked at 1.44 GB of resident memory in ``s2a-dataset build``; the audio
was held four times over (the take's samples, ``mono_float``'s two copies, the scaled copy) and the channel
histograms binned every frame at once. Now 0.83 GB, with the same shard bytes."""

from __future__ import annotations

import tracemalloc

import numpy as np

from capture import Audio
from dataset.build import mono_padded
from dataset.normalize import ChannelAccumulator


def test_channel_statistics_of_a_long_take_bin_a_block_at_a_time():
    rng = np.random.default_rng(0)
    values = (rng.random((120_000, 32), np.float32) * 1.2 - 0.1).astype(
        np.float32
    )  # over half an hour at 60 fps
    whole = values.astype(np.float64).nbytes
    tracemalloc.start()
    try:
        acc = ChannelAccumulator(32)
        acc.add(values)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # the float64 copy the sums need, and bins of a block of frames; before, six copies of every frame
    assert peak < 2.5 * whole, peak / whole
    # the statistics are those of every frame
    assert acc.count.tolist() == [120_000] * 32 and int(acc.hist.sum()) == values.size
    median = acc.percentile(50)
    assert np.all(np.abs(median - np.median(values, axis=0)) <= 5e-4 + 1e-6)


def test_a_takes_audio_is_mixed_to_mono_a_block_at_a_time():
    """The build's mono copy of a take's audio is the only full-length one it makes from the take's
    samples (the take's own are then let go): ``Audio.mono_float`` held three at once."""
    rng = np.random.default_rng(1)
    stereo = Audio(rng.integers(-9000, 9000, (2_000_000, 2), np.int16), 16000, "PCM_16")
    mono = Audio(rng.random(2_000_000, np.float32) * 2 - 1, 16000)
    for audio in (stereo, mono):
        out_bytes = 4 * (audio.frames + 1000)
        tracemalloc.start()
        try:
            padded = mono_padded(audio, audio.frames + 1000)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 2 * out_bytes, peak / out_bytes  # mono_float: 3 (int16 stereo) or 2 (float mono)
        assert np.array_equal(padded[: audio.frames], audio.mono_float()) and not padded[audio.frames :].any()
