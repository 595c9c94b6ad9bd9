"""Pitch: log-F0 with a voicing flag from Praat's autocorrelation tracker (praat-parselmouth).

The tracker runs on the preprocessor's own frame grid (hop 20 ms, centres at ``k * hop``), so pitch
shares one analysis setting with every other feature. Unvoiced frames get log-F0 linearly interpolated
between the neighbouring voiced frames (held flat at the ends), and a voicing flag says which were
measured. Per-speaker normalisation happens at read time from statistics in the manifest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture.errors import InputError


@dataclass(frozen=True)
class PitchSettings:
    """Praat pitch tracker limits in Hz. A 75 Hz floor gives Praat's 3-period window of 40 ms."""

    floor_hz: float = 75.0
    ceiling_hz: float = 600.0
    method: str = "praat-ac"


def track_pitch(
    audio: np.ndarray, sample_rate: int, n_frames: int, hop_s: float, settings: PitchSettings
) -> np.ndarray:
    """(n_frames, 2) float32: natural-log F0 (log Hz, interpolated through unvoiced frames) and the
    voicing flag (1 voiced, 0 not), at frame centres ``k * hop_s`` seconds."""
    import parselmouth

    out = np.zeros((n_frames, 2), np.float32)
    if audio.size < int(3 * sample_rate / settings.floor_hz) + 1:
        return out  # too short for one analysis window: all unvoiced, log-F0 0
    sound = parselmouth.Sound(audio.astype(np.float64), sampling_frequency=float(sample_rate))
    try:
        pitch = sound.to_pitch_ac(
            time_step=hop_s, pitch_floor=settings.floor_hz, pitch_ceiling=settings.ceiling_hz
        )
    except parselmouth.PraatError as exc:  # pragma: no cover - Praat rejects only odd inputs
        raise InputError(f"pitch tracking failed: {exc}") from None
    f0 = pitch.selected_array["frequency"].astype(np.float64)
    times = np.asarray(pitch.xs(), np.float64)
    centres = np.arange(n_frames) * hop_s
    voiced_src = f0 > 0
    # Nearest tracker frame decides voicing; log-F0 is interpolated over voiced tracker frames only.
    idx = np.clip(np.searchsorted(times, centres), 0, len(times) - 1)
    prev = np.clip(idx - 1, 0, len(times) - 1)
    nearest = np.where(np.abs(times[prev] - centres) <= np.abs(times[idx] - centres), prev, idx)
    voiced = voiced_src[nearest]
    if voiced_src.any():
        out[:, 0] = np.interp(centres, times[voiced_src], np.log(f0[voiced_src]))
    out[:, 1] = voiced
    return out
