"""Content evidence: the audio's energy envelope against the face's mouth opening.

Both streams become one signal each on a common analysis grid (``ANALYSIS_RATE`` on the take clock):
the audio's log energy in the sonorant band ``AUDIO_BAND_HZ`` (20 ms Hann windows, centred), and a
mouth-opening composite of the face (jawOpen, minus mouthClose, plus the lower lip; rig controls such
as ``mouth_stretch_c`` for other rigs). Both pass the same zero-phase band-pass filter (``BAND_HZ``),
so filtering adds no lag to one and not the other. Their cross-correlation peaks at the lag by which
the face trails the audio (``content_lag_s``); the peak is refined below the analysis step by
evaluating the correlation's Fourier series on a fine grid around it (the matrix-multiply DFT
upsampling of Guizar-Sicairos et al. that scikit-image's ``phase_cross_correlation`` uses, here on the
plain cross-power spectrum and only over the pass band).

Why these signals and this band: the lag the mouth-energy relation shows depends on the modulation
rate (the face runs ahead of the sound in the slow, phrase-level modulations and behind it in the fast
ones), so the band sets the bias; docs/align.md, "Content evidence", gives the measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
from numpy.lib.stride_tricks import sliding_window_view

ANALYSIS_RATE = 100.0  # Hz: 10 ms steps; the pass band ends at BAND_HZ[1]
BAND_HZ = (1.0, 12.0)  # syllable-rate and faster envelope modulations (see docs/align.md, "Content evidence")
AUDIO_BAND_HZ = (300.0, 3000.0)  # sonorant band of the audio whose energy is correlated
UPSAMPLE = 100  # refinement step = 1 / (ANALYSIS_RATE * UPSAMPLE) = 0.1 ms

# Mouth-opening channels and their signs (lower-case names; ARKit first, then other rigs' controls).
MOUTH_OPENING = {
    "jawopen": 1.0,
    "mouthclose": -1.0,
    "mouthlowerdownleft": 1.0,
    "mouthlowerdownright": 1.0,
    "mouth_stretch_c": 1.0,
    "jaw_open": 1.0,
    "mouth_lowerlipdepress_l": 0.5,
    "mouth_lowerlipdepress_r": 0.5,
}
# Viseme curves of the MPEG-4 set lip-sync generators write (CRI LipSync's "Mpeg4-Visemes Animation Curve
# File": time,PP,FF,TH,DD,kk,CH,SS,nn,RR,aa,E,ih,oh,ou,...; Oculus OVRLipSync's visemes, named viseme_aa,
# viseme_PP on avatars): aa is the open jaw, PP the closed lips. Only for a take with none of the channels
# above (an avatar's take may hold both: ARKit's 52 beside viseme_*, VRM's aa beside jawOpen): the jaw's
# own curve is then the evidence, as before visemes counted.
VISEME_OPENING = {"aa": 1.0, "pp": -1.0, "viseme_aa": 1.0, "viseme_pp": -1.0}


def mouth_channels(channels: list[str]) -> list[tuple[int, float]]:
    """(column, sign weight) of the mouth-opening channels a take has; empty when it has none."""
    lowered = [c.lower() for c in channels]
    found = [(lowered.index(n), w) for n, w in MOUTH_OPENING.items() if n in lowered]
    if not found:
        found = [(i, 1.0) for i, c in enumerate(lowered) if "jaw" in c and "open" in c]
    if not found:
        found = [(lowered.index(n), w) for n, w in VISEME_OPENING.items() if n in lowered]
    return found


def mouth_opening(values: np.ndarray, valid: np.ndarray, picks: list[tuple[int, float]]) -> np.ndarray:
    """Per-frame mouth opening: the weighted sum of the picked channels, each scaled to unit spread
    over the valid frames (channels that do not move are left out). NaN where a frame is not valid."""
    out = np.zeros(values.shape[0])
    used = 0
    for col, weight in picks:
        x = values[valid, col].astype(np.float64)
        if x.size < 2:
            continue
        spread = float(np.std(x))
        if not np.isfinite(spread) or spread < 1e-6:
            continue
        out[valid] += weight * (x - np.mean(x)) / spread  # not frames of NaN or inf: noise on stderr
        used += 1
    out[~valid] = np.nan
    return out if used else np.full(values.shape[0], np.nan)


def energy_envelope(x: np.ndarray, rate: int, start_s: float, grid: np.ndarray) -> np.ndarray:
    """Log energy (dB) of audio ``x`` (``rate`` Hz, first sample at take time ``start_s``) in the
    sonorant band ``AUDIO_BAND_HZ``, in Hann windows of ``2 / ANALYSIS_RATE`` s centred on the analysis
    steps, interpolated at the take times ``grid`` (s); floored 60 dB below the loudest window.

    The band keeps the formant region whose level follows the opening of the mouth, and leaves out
    frication (loud while the jaw is nearly shut), the voice bar of closures and room rumble. The
    windows are symmetric about their centres, so the envelope has no delay of its own."""
    hop = int(round(rate / ANALYSIS_RATE))
    win = 2 * hop
    n = (x.size - win) // hop + 1
    if n < 2:
        return np.zeros(grid.size)
    freqs = np.fft.rfftfreq(win, 1.0 / rate)
    band = slice(
        int(np.searchsorted(freqs, AUDIO_BAND_HZ[0])), int(np.searchsorted(freqs, AUDIO_BAND_HZ[1], "right"))
    )
    window = np.hanning(win + 2)[1:-1].astype(np.float32)  # symmetric, no zero taps
    x32 = np.asarray(x, dtype=np.float32)
    e = np.empty(n)
    block = 4096  # frames per block: bounded memory on hour-long takes
    for lo in range(0, n, block):
        hi = min(n, lo + block)
        frames = sliding_window_view(x32[lo * hop : (hi - 1) * hop + win], win)[::hop] * window
        spec = scipy.fft.rfft(frames, axis=1)[:, band]  # float32 in, complex64 out: twice numpy's speed
        e[lo:hi] = np.einsum("ij,ij->i", spec.real, spec.real, dtype=np.float64) + np.einsum(
            "ij,ij->i", spec.imag, spec.imag, dtype=np.float64
        )
    db = 10.0 * np.log10(e / win + 1e-12)
    db = np.maximum(db, db.max() - 60.0)
    centres = start_s + (np.arange(n) * hop + hop) / rate  # centre of samples [k*hop, k*hop + win)
    return np.interp(grid, centres, db)


def band_pass(x: np.ndarray) -> np.ndarray:
    """The zero-phase band-pass both content signals go through (``BAND_HZ`` at ``ANALYSIS_RATE``)."""
    if x.size < 30:
        return x - x.mean()
    from scipy.signal import butter, sosfiltfilt  # here: scipy.signal adds 0.5 s to every command's start

    return sosfiltfilt(butter(2, BAND_HZ, btype="band", fs=ANALYSIS_RATE, output="sos"), x - x.mean())


@dataclass
class LagEstimate:
    """The lag (s) at which the face best matches the audio, with how clearly it stands out."""

    lag_s: float
    peak: float  # normalised correlation at the peak (-1..1)
    runner_up: float  # highest correlation at least ``MAIN_LOBE_S`` away from the peak
    seconds: float  # length of signal the estimate rests on (weighted: where the face is present)
    at_edge: bool  # the peak sits at the edge of the search range


MAIN_LOBE_S = 0.08


class CrossCorrelation:
    """``sum audio(t) face(t + k)`` at every lag ``k`` of the analysis grid, computed once (one FFT) for
    the peaks of several search ranges; signals on the analysis grid, ``weight`` (0..1) masks where the
    face is missing."""

    def __init__(self, audio_sig: np.ndarray, face_sig: np.ndarray, weight: np.ndarray):
        a = audio_sig * weight
        f = face_sig * weight
        self.n = a.size
        self.norm = float(np.sqrt(np.dot(a, a) * np.dot(f, f)))
        self.seconds = float(np.sum(weight)) / ANALYSIS_RATE  # where the face is there to compare
        self.size = 1 << int(np.ceil(np.log2(2 * max(self.n, 1))))
        self.spec = np.conj(np.fft.rfft(a, self.size)) * np.fft.rfft(f, self.size)
        # corr[k] = sum a(t) f(t + k), k negative wraps around
        self.corr = np.fft.irfft(self.spec, self.size) / self.norm if self.norm > 0 else None

    def peak(self, max_lag_s: float, centre_s: float = 0.0) -> LagEstimate | None:
        """Lag (s) that maximises the correlation within ``centre_s ± max_lag_s``, refined to 0.1 ms."""
        n, size = self.n, self.size
        if n < 20 or self.corr is None:
            return None
        max_k = int(np.ceil(max_lag_s * ANALYSIS_RATE))
        c0 = int(round(centre_s * ANALYSIS_RATE))
        lags = np.arange(c0 - max_k, c0 + max_k + 1)
        lags = lags[np.abs(lags) < n - 10]
        if lags.size < 3:
            return None
        values = self.corr[lags % size]
        best = int(np.argmax(values))
        at_edge = best in (0, lags.size - 1)
        k_best = int(lags[best])
        lobe = int(round(MAIN_LOBE_S * ANALYSIS_RATE))
        far = np.abs(lags - k_best) > lobe
        runner_up = float(values[far].max()) if far.any() else float("nan")
        if at_edge:  # the true peak may lie outside the range: no refinement
            return LagEstimate(k_best / ANALYSIS_RATE, float(values[best]), runner_up, self.seconds, True)
        refined, value = self._refine(k_best)
        return LagEstimate(refined / ANALYSIS_RATE, value, runner_up, self.seconds, False)

    def widened(self, max_lag_s: float, step_s: float) -> tuple[float, LagEstimate | None]:
        """``peak`` over ``±max_lag_s`` widened ``step_s`` at a time while its highest value lies at the
        edge of the range (the flank of a peak further out: followed to its top), up to the take's length
        (``n`` lags): (the range searched last, its ``peak``). The same as calling ``peak`` on each wider
        range, at the cost of one: whether a range's highest value is at its edge is read from running
        maxima of the correlation outwards from lag 0 (a flank rising over half an hour of lags, 7,200
        ranges, took 10 s of CPU searched one by one, 0.5 s so)."""
        limit = self.n / ANALYSIS_RATE
        if self.n < 20 or self.corr is None or max_lag_s >= limit:
            return max_lag_s, self.peak(max_lag_s)
        side = np.arange(self.n - 10)  # lags 0..n-11 each way, the most ``peak`` searches
        right, left = self.corr[side], self.corr[-side % self.size]
        right_top, left_top = np.maximum.accumulate(right), np.maximum.accumulate(left)
        reach = max_lag_s
        while reach < limit:
            reach += step_s
            k = min(int(np.ceil(reach * ANALYSIS_RATE)), self.n - 11)
            # ``peak``'s argmax takes the first of equal values: the lowest lag's edge wins a tie
            at_low = left[k] >= max(left_top[k - 1], right_top[k])
            if not (at_low or right[k] > max(left_top[k], right_top[k - 1])):
                break
        return reach, self.peak(reach)

    def _refine(self, k_best: int) -> tuple[float, float]:
        """Band-limited refinement: evaluate the correlation's Fourier series at fractional lags around
        the integer peak, using only the bins the band-pass lets through; first on a 1 ms grid over ±1
        step, then on the 0.1 ms grid around the best point (the series is smooth at this scale)."""
        size = self.size
        freqs = np.arange(self.spec.size)
        keep = freqs <= int(np.ceil(2.0 * BAND_HZ[1] / ANALYSIS_RATE * size)) + 2
        bins = freqs[keep]
        weighted = self.spec[keep] * np.where(bins == 0, 1.0, 2.0) / (size * self.norm)

        def series(points: np.ndarray) -> np.ndarray:
            out = np.zeros(points.size)
            for lo in range(0, bins.size, 4096):  # blocks keep memory small on hour-long takes
                kernel = np.exp(2j * np.pi * np.outer(points, bins[lo : lo + 4096]) / size)
                out += (
                    kernel.real @ weighted[lo : lo + 4096].real - kernel.imag @ weighted[lo : lo + 4096].imag
                )
            return out

        coarse_step = 10
        coarse = k_best + np.arange(-UPSAMPLE, UPSAMPLE + 1, coarse_step) / UPSAMPLE
        centre = coarse[int(np.argmax(series(coarse)))]
        fine = centre + np.arange(-coarse_step, coarse_step + 1) / UPSAMPLE
        fine_values = series(fine)
        return float(fine[int(np.argmax(fine_values))]), float(fine_values.max())


def cross_correlation_lag(
    audio_sig: np.ndarray, face_sig: np.ndarray, weight: np.ndarray, max_lag_s: float, centre_s: float = 0.0
) -> LagEstimate | None:
    """Lag (s) that maximises ``sum audio(t) face(t + lag)`` within ``centre_s ± max_lag_s``, refined
    to 0.1 ms (``CrossCorrelation.peak`` of one range)."""
    return CrossCorrelation(audio_sig, face_sig, weight).peak(max_lag_s, centre_s)
