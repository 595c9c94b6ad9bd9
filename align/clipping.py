"""Clipping in the recorded audio, found on the raw samples before any resampling.

A recording driven past full scale holds its loudest sounds flat at the converter's limit: runs of
consecutive samples at exactly the channel's highest (or lowest) value. A natural waveform passes its
peak in one or two samples (the real samples checked never hold it for three), so only runs of at least
``CLIP_RUN`` samples count. The channel's own extreme stands for full scale: it is full scale for
integer PCM clipped by the converter, 1.0 for float audio clipped on export, and the flat top of audio
clipped first and scaled down afterwards. Resampling smears the flat tops into overshoots (a clipped
int16 take peaks at 1.21 after the 16 kHz resampler), so the raw samples are the place to look. They are
read twice, a block at a time (the channels' extremes and resting values, then the runs at the extremes),
so that an hour of them need not be in memory (``recorded.RecordedAudio``).

Only an extreme that is a loud sound can be a clipped one: it must lie at least ``CLIP_MIN_LEVEL``
(-30 dBFS) from the channel's resting value (its median). An idle channel holding ±1 LSB of noise, a
channel holding a constant (a DC offset, -1 LSB of digital "silence") or nothing at all sits at its own
extremes most of the time and is not clipped; neither is a channel holding a timecode signal (LTC, a
square wave that lives at its two levels).
"""

from __future__ import annotations

import numpy as np

from capture import Audio
from capture.audio_io import full_scale
from capture.runs import run_bounds

from .recorded import RecordedAudio, recorded
from .resample import looks_like_timecode

CLIP_RUN = 3  # consecutive samples at the extreme value
CLIPPED_AUDIO_SHARE = 0.001  # of a channel's samples; above it the take is flagged ``clipped_audio``
CLIP_MIN_LEVEL = 10 ** (-30 / 20)  # flat tops nearer than this to the resting value are not clipping
_BLOCK = 1 << 18  # frames per block: an hour's channel as int64 run arrays took 2.5 GB
_MEDIAN_SAMPLES = 65536  # samples spread over a channel that its resting value is the median of


def clipped_share(audio: Audio | RecordedAudio) -> float:
    """Share (0..1) of samples in runs of at least ``CLIP_RUN`` at their channel's highest or lowest
    value, for the most clipped channel (a silent channel does not dilute a clipped one). Extremes
    within ``CLIP_MIN_LEVEL`` of the channel's median and channels holding timecode do not count."""
    source = recorded(audio)
    if source.frames == 0:
        return 0.0
    scale = full_scale(np.zeros(0, source.dtype))
    high, low, centre = _extremes_and_centres(source)
    # per channel, its extremes that are loud sounds, each with its run counter
    loud = [
        [_FlatRuns(e) for e in {high[k], low[k]} if abs(float(e) / scale - centre[k]) >= CLIP_MIN_LEVEL]
        for k in range(source.channels)
    ]
    if any(loud):
        for block in source.blocks(_BLOCK):
            for k, counters in enumerate(loud):
                for counter in counters:
                    counter.add(block[:, k])
    worst = 0
    for k, counters in enumerate(loud):
        flat = sum(counter.total() for counter in counters)
        # the timecode test (the costlier one) only where flat tops would flag the take: a timecode
        # signal lives at its two levels, far more than CLIPPED_AUDIO_SHARE of the time
        few = flat <= CLIPPED_AUDIO_SHARE * source.frames
        if flat > worst and (
            few or not looks_like_timecode(source.channel(k, _BLOCK), source.sample_rate, scale)
        ):
            worst = flat
    return worst / source.frames


def _extremes_and_centres(source: RecordedAudio) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Each channel's highest and lowest value, and its resting value (in full scale): the median of
    ``_MEDIAN_SAMPLES`` samples spread over it (every ``step``-th from the first), not a precise one."""
    step = max(1, source.frames // _MEDIAN_SAMPLES)
    high = low = None
    spread, at = [], 0
    for block in source.blocks(_BLOCK):
        high = block.max(axis=0) if high is None else np.maximum(high, block.max(axis=0))
        low = block.min(axis=0) if low is None else np.minimum(low, block.min(axis=0))
        spread.append(block[(-at) % step :: step].copy())  # the samples at multiples of step
        at += block.shape[0]
    picked = np.concatenate(spread)
    scale = full_scale(picked)
    assert high is not None and low is not None
    return high, low, [float(np.median(picked[:, k])) / scale for k in range(source.channels)]


class _FlatRuns:
    """Samples in runs of at least ``CLIP_RUN`` consecutive samples at ``extreme``, counted over a
    channel given block by block (as arrays: a timecode channel, a square wave, holds millions of runs).
    A run reaching the end of a block is carried into the next."""

    def __init__(self, extreme):
        self.extreme = extreme
        self.counted, self.carried = 0, 0  # carried: the length of the run that reached the last block's end

    def add(self, part: np.ndarray) -> None:
        starts, stops = run_bounds(part == self.extreme)
        lengths = stops - starts
        if self.carried and starts.size and starts[0] == 0:
            lengths[0] += self.carried  # the run goes on
        elif self.carried >= CLIP_RUN:
            self.counted += self.carried  # the run ended with the last block
        self.carried = 0
        if stops.size and stops[-1] == part.size:
            self.carried, lengths = int(lengths[-1]), lengths[:-1]
        self.counted += int(lengths[lengths >= CLIP_RUN].sum())

    def total(self) -> int:
        return self.counted + (self.carried if self.carried >= CLIP_RUN else 0)


def _flat_samples(channel: np.ndarray, extreme, block: int = _BLOCK) -> int:
    """Samples of ``channel`` in runs of at least ``CLIP_RUN`` at ``extreme``, ``block`` samples at a time."""
    runs = _FlatRuns(extreme)
    for lo in range(0, channel.size, block):
        runs.add(channel[lo : lo + block])
    return runs.total()
