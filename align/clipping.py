"""Clipping in the recorded audio, found on the raw samples before any resampling.

A recording driven past full scale holds its loudest sounds flat at the converter's limit: runs of
consecutive samples at exactly the channel's highest (or lowest) value. A natural waveform passes its
peak in one or two samples (the real samples checked never hold it for three), so only runs of at least
``CLIP_RUN`` samples count. The channel's own extreme stands for full scale: it is full scale for
integer PCM clipped by the converter, 1.0 for float audio clipped on export, and the flat top of audio
clipped first and scaled down afterwards. Resampling smears the flat tops into overshoots (a clipped
int16 take peaks at 1.21 after the 16 kHz resampler), so the raw samples are the place to look.

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

from .resample import looks_like_timecode

CLIP_RUN = 3  # consecutive samples at the extreme value
CLIPPED_AUDIO_SHARE = 0.001  # of a channel's samples; above it the take is flagged ``clipped_audio``
CLIP_MIN_LEVEL = 10 ** (-30 / 20)  # flat tops nearer than this to the resting value are not clipping


def clipped_share(audio: Audio) -> float:
    """Share (0..1) of samples in runs of at least ``CLIP_RUN`` at their channel's highest or lowest
    value, for the most clipped channel (a silent channel does not dilute a clipped one). Extremes
    within ``CLIP_MIN_LEVEL`` of the channel's median and channels holding timecode do not count."""
    worst = 0
    for channel in audio.samples.T:
        scale = full_scale(channel)
        high, low = channel.max(), channel.min()
        # the resting value from 64k samples spread over the channel: a median, not a precise one
        centre = float(np.median(channel[:: max(1, channel.size // 65536)])) / scale
        loud = [e for e in {high, low} if abs(float(e) / scale - centre) >= CLIP_MIN_LEVEL]
        flat = sum(_flat_samples(channel, extreme) for extreme in loud)
        # the timecode test (the costlier one) only where flat tops would flag the take: a timecode
        # signal lives at its two levels, far more than CLIPPED_AUDIO_SHARE of the time
        few = flat <= CLIPPED_AUDIO_SHARE * channel.size
        if flat > worst and (few or not looks_like_timecode(channel, audio.sample_rate, scale)):
            worst = flat
    return worst / max(audio.frames, 1)


def _flat_samples(channel: np.ndarray, extreme, block: int = 1 << 18) -> int:
    """Samples of ``channel`` in runs of at least ``CLIP_RUN`` consecutive samples at ``extreme`` (as
    arrays: a timecode channel, a square wave, holds millions of runs), ``block`` samples at a time: the
    run arrays of a whole hour-long channel took 2.5 GB. A run reaching the end of a block is carried
    into the next."""
    total, carried = 0, 0  # carried: the length of the run that reached the end of the last block
    for lo in range(0, channel.size, block):
        part = channel[lo : lo + block]
        starts, stops = run_bounds(part == extreme)
        lengths = stops - starts
        if carried and starts.size and starts[0] == 0:
            lengths[0] += carried  # the run goes on
        elif carried >= CLIP_RUN:
            total += carried  # the run ended with the last block
        carried = 0
        if stops.size and stops[-1] == part.size:
            carried, lengths = int(lengths[-1]), lengths[:-1]
        total += int(lengths[lengths >= CLIP_RUN].sum())
    return total + (carried if carried >= CLIP_RUN else 0)
