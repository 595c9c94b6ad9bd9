"""Animation onto a uniform frame grid: interpolation between measured frames, short gaps filled and
flagged, long gaps left as holes that split the take into segments (no motion is invented there)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from capture import FrameStatus

INTERPOLATED = FrameStatus.INTERPOLATED  # a frame filled across a short gap
UNCOVERED = 255  # inside a long gap or outside the measured frames: not part of any segment
# Above this share of a segment's frames interpolated rather than tracked, its motion is mostly made up
# (the dataset stage warns at the same share).
MOSTLY_INTERPOLATED_SHARE = 0.5


def frame_period(time: np.ndarray, fps: float) -> float:
    """Measured frame period (s): the median step of the frame times, else 1/fps."""
    if time.size < 2:
        return 1.0 / fps
    return float(np.median(np.diff(time)))


def interpolated_share(interpolated: int, frames: int) -> float:
    """Share (0..1, 4 decimals) of ``frames`` grid frames that are ``interpolated``."""
    return round(interpolated / frames, 4) if frames else 0.0


def usable_frames(status: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Frames whose values can be used: tracked (or already interpolated) and finite in every channel."""
    ok = (status == FrameStatus.TRACKED) | (status == INTERPOLATED)
    return ok & np.isfinite(values).all(axis=1)


def cover(frame_t: np.ndarray, period: float, grid_t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Status of each grid time (s) given the times (s) of the usable measured frames.

    TRACKED: between two consecutive measured frames (or within half a period of the first/last one);
    INTERPOLATED: across a gap of at most ``max_gap_s`` of missing frames; UNCOVERED otherwise.
    """
    out = np.full(grid_t.size, UNCOVERED, dtype=np.uint8)
    if frame_t.size == 0:
        return out
    j = np.searchsorted(frame_t, grid_t, side="right")  # frame_t[j-1] <= g < frame_t[j]
    inside = (j > 0) & (j < frame_t.size)
    jj = np.clip(j, 1, max(frame_t.size - 1, 1))
    step = frame_t[jj] - frame_t[jj - 1] if frame_t.size > 1 else np.full(grid_t.size, np.inf)
    missing = step - period
    out[inside & (step <= 1.5 * period)] = FrameStatus.TRACKED
    out[inside & (step > 1.5 * period) & (missing <= max_gap_s + 1e-9)] = INTERPOLATED
    # Exactly on a frame, or just past the ends by at most half a period.
    edge = (np.abs(grid_t - frame_t[0]) <= period / 2) | (np.abs(grid_t - frame_t[-1]) <= period / 2)
    out[edge & (out == UNCOVERED)] = FrameStatus.TRACKED
    return out


def resample_values(
    frame_t: np.ndarray, values: np.ndarray, grid_t: np.ndarray, src_fps: float, dst_fps: float
) -> np.ndarray:
    """Values (grid x channels, float32) at the grid times (s), linear between measured frames.

    Going to a lower rate, the frames are first smoothed (Gaussian, sigma 0.4 source frames per
    output frame) so that motion faster than the new Nyquist rate does not alias."""
    v = values  # np.interp takes each channel as float64 itself: no float64 copy of all of them
    if dst_fps < 0.9 * src_fps and v.shape[0] > 3:
        v = gaussian_filter1d(v.astype(np.float64), sigma=0.4 * src_fps / dst_fps, axis=0, mode="nearest")
    out = np.empty((grid_t.size, v.shape[1]), dtype=np.float32)
    for c in range(v.shape[1]):
        out[:, c] = np.interp(grid_t, frame_t, v[:, c])
    return out
