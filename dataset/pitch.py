"""Pitch: log-F0 with a voicing flag from Praat's autocorrelation tracker (praat-parselmouth).

The tracker runs on the preprocessor's own frame grid (hop 20 ms, centres at ``k * hop``), so pitch
shares one analysis setting with every other feature. Unvoiced frames get log-F0 linearly interpolated
between the neighbouring voiced frames (held flat at the ends), and a voicing flag says which were
measured. Per-speaker normalisation happens at read time from statistics in the manifest.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from capture.errors import InputError

CHUNK_S = 60.0  # longer audio is tracked a minute at a time ...
MARGIN_S = 2.0  # ... with this much context either side
PRAAT_SILENCE = 0.03  # Praat's default silence threshold, a fraction of the sound's peak


@dataclass(frozen=True)
class PitchSettings:
    """Praat pitch tracker limits in Hz. A 75 Hz floor gives Praat's 3-period window of 40 ms."""

    floor_hz: float = 75.0
    ceiling_hz: float = 600.0
    method: str = "praat-ac"


def pitch_pieces(n_samples: int, sample_rate: int) -> list[int]:
    """The first samples of the pieces ``track_pitch`` tracks ``n_samples`` of audio in."""
    chunk, margin = int(CHUNK_S * sample_rate), int(MARGIN_S * sample_rate)
    return [0] if n_samples <= chunk + 2 * margin else list(range(0, n_samples, chunk))


def track_pitch(
    audio: np.ndarray,
    sample_rate: int,
    n_frames: int,
    hop_s: float,
    settings: PitchSettings,
    tick: Callable[[], None] | None = None,
    gain: float = 1.0,
) -> np.ndarray:
    """(n_frames, 2) float32: natural-log F0 (log Hz, interpolated through unvoiced frames) and the
    voicing flag (1 voiced, 0 not), at frame centres ``k * hop_s`` seconds, of ``audio`` scaled by
    ``gain`` (float32 ``audio * np.float32(gain)``, piece by piece). ``tick``: called after each piece
    (``pitch_pieces``) of a long audio is tracked."""
    import parselmouth

    out = np.zeros((n_frames, 2), np.float32)
    if audio.size < int(3 * sample_rate / settings.floor_hz) + 1:
        return out  # too short for one analysis window: all unvoiced, log-F0 0
    # Long audio is tracked in pieces of CHUNK_S seconds, each with MARGIN_S of context either side
    # whose frames are dropped, so that Praat's memory (about 16 bytes per sample) stays bounded; audio
    # up to CHUNK_S + 2 MARGIN_S is tracked in one piece, as before.
    chunk, margin, total = int(CHUNK_S * sample_rate), int(MARGIN_S * sample_rate), audio.size
    starts = pitch_pieces(total, sample_rate)
    # max |x * gain| without a copy of the audio: the scaled samples are float32 (as a whole scaled copy
    # was, whatever the audio's float type), and float32 rounding and scaling keep or reverse the order
    # of samples, so the extremes of x * gain are those of x scaled (a negative gain swaps them)
    g = np.float32(gain)
    high, low = audio.max(), audio.min()
    if gain != 1.0:
        high, low = np.float32(high) * g, np.float32(low) * g
    peak = float(max(abs(high), abs(low)))
    pieces = []
    for start in starts:
        end = total if len(starts) == 1 else min(total, start + chunk)
        lo, hi = max(0, start - margin), min(total, end + margin)
        if hi - lo >= int(3 * sample_rate / settings.floor_hz) + 1:  # else a sliver: frames from the margin
            piece = audio[lo:hi] if gain == 1.0 else np.asarray(audio[lo:hi], np.float32) * g
            t, f = _praat_pitch(parselmouth, piece, lo / sample_rate, sample_rate, hop_s, settings, peak)
            keep = (t >= start / sample_rate) & (t < end / sample_rate) if len(starts) > 1 else slice(None)
            pieces.append((t[keep], f[keep]))
        if tick is not None:
            tick()
    times = np.concatenate([t for t, _ in pieces])
    f0 = np.concatenate([f for _, f in pieces])
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


def _praat_pitch(parselmouth, audio, start_s: float, sample_rate: int, hop_s: float, settings, peak: float):
    """(frame times in s, F0 in Hz, 0 unvoiced) of Praat's autocorrelation tracker on ``audio``, a piece
    of a longer signal whose absolute peak is ``peak``, starting at ``start_s``. Praat judges silence
    against the peak of the sound it is given: the threshold is scaled so that a piece is judged
    against the whole signal's peak."""
    sound = parselmouth.Sound(
        audio.astype(np.float64), sampling_frequency=float(sample_rate), start_time=float(start_s)
    )
    own = float(np.max(np.abs(audio)))
    silence = PRAAT_SILENCE * (peak / own if own > 0 else 1.0)
    try:
        pitch = sound.to_pitch_ac(
            time_step=hop_s,
            pitch_floor=settings.floor_hz,
            pitch_ceiling=settings.ceiling_hz,
            silence_threshold=silence,
        )
    except parselmouth.PraatError as exc:  # pragma: no cover - Praat rejects only odd inputs
        raise InputError(f"pitch tracking failed: {exc}") from None
    return np.asarray(pitch.xs(), np.float64), pitch.selected_array["frequency"].astype(np.float64)
