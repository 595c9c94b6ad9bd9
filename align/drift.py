"""Clock drift between the phone (face) and the sound card (audio), from how the content lag moves
along a long take; and, for live captures, between the phone and the recorder from packet arrivals.

Model: the face trails the audio by ``lag(t) = lag0 + drift * (t - t0)`` (s), ``t`` take time, ``t0``
the first audio sample; ``drift_ppm = drift * 1e6``. Align corrects it by moving each frame by the
lag at its own time, so the audio stays the reference clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .content import ANALYSIS_RATE, LagEstimate, cross_correlation_lag

# 20 s windows: shorter ones (5-10 s) give lag tracks too noisy to tell a drift from articulation
# (straight-line fits over 5 windows of a 30 s simulated take without drift reached t = 4.5).
WINDOW_S = 20.0


@dataclass
class WindowLags:
    """Content lags (s) of windows centred at ``centre_s`` (take time, s) with their peak correlations."""

    centre_s: np.ndarray
    lag_s: np.ndarray
    peak: np.ndarray


def window_lags(
    env: np.ndarray,
    face: np.ndarray,
    weight: np.ndarray,
    grid_t0: float,
    around_s: float,
    search_s: float = 0.1,
    window_s: float = WINDOW_S,
) -> WindowLags:
    """Lag per ``window_s`` window (half-window hop) within ``around_s ± search_s``; signals on the
    analysis grid starting at take time ``grid_t0``."""
    win = int(window_s * ANALYSIS_RATE)
    hop = max(1, win // 2)
    centres, lags, peaks = [], [], []
    if env.size < win:
        win = env.size
    for start in range(0, max(env.size - win, 0) + 1, hop):
        sl = slice(start, start + win)
        if weight[sl].mean() < 0.5:
            continue
        est: LagEstimate | None = cross_correlation_lag(env[sl], face[sl], weight[sl], search_s, around_s)
        if est is None or est.at_edge or est.peak <= 0.1:
            continue
        centres.append(grid_t0 + (start + win / 2) / ANALYSIS_RATE)
        lags.append(est.lag_s)
        peaks.append(est.peak)
    return WindowLags(np.asarray(centres), np.asarray(lags), np.asarray(peaks))


@dataclass
class DriftFit:
    """Fitted lag line: ``lag0_s`` at take time ``t0_s``, slope ``drift`` (s/s), its standard error."""

    lag0_s: float
    drift: float
    drift_se: float
    windows: int
    residual_s: float

    @property
    def ppm(self) -> float:
        return self.drift * 1e6


def fit_drift(w: WindowLags, t0_s: float) -> DriftFit | None:
    """Weighted straight-line fit of window lags against time; None with fewer than 4 windows."""
    if w.lag_s.size < 4:
        return None
    x = w.centre_s - t0_s
    wt = np.clip(w.peak, 0.05, None) ** 2
    A = np.stack([np.ones_like(x), x], axis=1)
    W = np.sqrt(wt)[:, None]
    coef, *_ = np.linalg.lstsq(A * W, w.lag_s * W[:, 0], rcond=None)
    resid = w.lag_s - A @ coef
    dof = max(w.lag_s.size - 2, 1)
    sigma2 = float(np.sum(wt * resid**2) / np.sum(wt) * w.lag_s.size / dof)
    sxx = float(np.sum(wt * (x - np.average(x, weights=wt)) ** 2) / np.mean(wt))
    se = float(np.sqrt(sigma2 / sxx)) if sxx > 0 else float("inf")
    return DriftFit(float(coef[0]), float(coef[1]), se, int(w.lag_s.size), float(np.sqrt(np.mean(resid**2))))


def arrival_drift_ppm(time: np.ndarray, arrival_s: np.ndarray | None) -> float | None:
    """Rate difference (ppm) of the phone's frame clock against the recorder's clock, from the
    fastest packet in each second (network delay only adds, so the minima trace the clock line)."""
    if arrival_s is None:
        return None
    ok = np.isfinite(arrival_s)
    if ok.sum() < 600:
        return None
    t, d = time[ok], arrival_s[ok] - time[ok]
    bins = np.floor((t - t[0]) / 1.0).astype(np.int64)
    idx = np.flatnonzero(np.diff(np.concatenate([[-1], bins])))
    mins = np.minimum.reduceat(d, idx)
    centres = t[idx]
    if mins.size < 10:
        return None
    slope = np.polyfit(centres - centres[0], mins, 1)[0]
    return float(slope * 1e6)
