"""Audio to the stage's working format: 16 kHz mono float32.

The rate conversion uses python-soxr (libsoxr's "very high quality" polyphase resampler): it is a
well-kept C library, handles any ratio (44.1 kHz -> 16 kHz is 160/441, awkward for polyphase filters
built from the reduced fraction), keeps the passband flat to 0.9 of Nyquist with >140 dB stopband, and
runs at thousands of times real time, so resampling never dominates an align run. ``scipy.signal.
resample_poly`` would do for the same ratio, but needs a 441-phase filter designed per call and is
slower; soxr is also what the other speech toolkits use.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from capture import Audio, InputError

TARGET_RATE = 16000


# A mix this far (dB) below its loudest channel has cancelled: the channels hold the same sound with
# opposite polarity (a miswired or phase-inverted stereo pair). Two independent channels mix to about
# 3 dB below the louder, one live channel and one silent to 6 dB below, so normal audio never comes
# near it.
CANCELLED_MIX_DB = 20.0


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.einsum("i,i->", x, x, dtype=np.float64) / max(x.size, 1)))


def mono_mix(audio: Audio) -> tuple[np.ndarray, dict[str, Any] | None]:
    """Mono float32 samples of ``audio`` (channels averaged) and ``None``; when the average is more
    than ``CANCELLED_MIX_DB`` below the loudest channel (phase-inverted copies cancel to silence),
    that channel alone, with a note saying so (``channel`` counts from 1)."""
    x = audio.mono_float()
    if audio.channels < 2:
        return x, None
    channels = [
        Audio(audio.samples[:, k : k + 1], audio.sample_rate, audio.subtype).mono_float()
        for k in range(audio.channels)
    ]
    levels = [_rms(c) for c in channels]
    loud = int(np.argmax(levels))
    if levels[loud] <= 0:
        return x, None
    mix = _rms(x)
    below_db = 20.0 * math.log10(levels[loud] / mix) if mix > 0 else None  # None: the mix is silent
    if below_db is not None and below_db <= CANCELLED_MIX_DB:
        return x, None
    how = (
        "the mix is silent" if below_db is None else f"the mix is {below_db:.1f} dB below channel {loud + 1}"
    )
    note = {
        "method": "louder_channel",
        "channel": loud + 1,
        "channels": audio.channels,
        "mix_below_channel_db": None if below_db is None else round(below_db, 1),
        "message": f"the {audio.channels} audio channels cancel when mixed ({how}; phase-inverted "
        f"copies?): channel {loud + 1} alone is used",
    }
    return channels[loud], note


def to_16k_mono(
    audio: Audio, path: str | None = None, notes: list[dict[str, Any]] | None = None
) -> np.ndarray:
    """The audio as mono float32 samples at 16 kHz (values in [-1, 1)): channels averaged, or the
    loudest channel alone when they cancel in the average (``mono_mix``; its note is appended to
    ``notes`` when given)."""
    import soxr

    x, note = mono_mix(audio)
    if note is not None and notes is not None:
        notes.append(note)
    if audio.sample_rate < 8000:
        raise InputError(
            f"audio sample rate {audio.sample_rate} Hz is too low for speech (need ≥ 8 kHz)", path
        )
    if audio.sample_rate == TARGET_RATE:
        return np.ascontiguousarray(x, dtype=np.float32)
    y = soxr.resample(x.astype(np.float32), audio.sample_rate, TARGET_RATE, quality="VHQ")
    return np.ascontiguousarray(y, dtype=np.float32)
