"""Clipping in the recorded audio, found on the raw samples before any resampling.

A recording driven past full scale holds its loudest sounds flat at the converter's limit: runs of
consecutive samples at exactly the channel's highest (or lowest) value. A natural waveform passes its
peak in one or two samples (the real samples checked never hold it for three), so only runs of at least
``CLIP_RUN`` samples count. The channel's own extreme stands for full scale: it is full scale for
integer PCM clipped by the converter, 1.0 for float audio clipped on export, and the flat top of audio
clipped first and scaled down afterwards. Resampling smears the flat tops into overshoots (a clipped
int16 take peaks at 1.21 after the 16 kHz resampler), so the raw samples are the place to look.
"""

from __future__ import annotations

from capture import Audio

from .grid import runs

CLIP_RUN = 3  # consecutive samples at the extreme value
CLIPPED_AUDIO_SHARE = 0.001  # of a channel's samples; above it the take is flagged ``clipped_audio``


def clipped_share(audio: Audio) -> float:
    """Share (0..1) of samples in runs of at least ``CLIP_RUN`` at their channel's highest or lowest
    value, for the most clipped channel (a silent channel does not dilute a clipped one)."""
    worst = 0
    for channel in audio.samples.T:
        flat = 0
        for extreme in {channel.max(), channel.min()} - {0}:
            flat += sum(stop - start for start, stop in runs(channel == extreme) if stop - start >= CLIP_RUN)
        worst = max(worst, flat)
    return worst / max(audio.frames, 1)
