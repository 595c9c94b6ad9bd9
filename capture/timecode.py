"""Live Link Face timecodes.

A timecode cell reads ``HH:MM:SS:FF.fff``: FF is the frame within the second at the timecode rate and
``.fff`` the fractional sub-frame (0..1 of a frame), not milliseconds. The app's CSV always uses a
60 fps timecode rate, also when it writes 30 rows/s, so ``seconds = H*3600 + M*60 + S + FF.fff/60``.
``frame_log.csv`` may also use the drop-frame separator ``;`` (iPhone timecode itself never drops).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

CSV_TIMECODE_RATE = 60.0
DAY_S = 86400.0

_TIMECODE = re.compile(r"^\s*(\d{1,2}):(\d{2}):(\d{2})[:;](\d{1,3}(?:\.\d*)?)\s*$")


@dataclass(frozen=True)
class Timecode:
    """A time of day as written by Live Link Face: hours, minutes, seconds, fractional frames."""

    hours: int
    minutes: int
    seconds: int
    frames: float
    rate: float = CSV_TIMECODE_RATE

    @classmethod
    def parse(cls, text: str, rate: float = CSV_TIMECODE_RATE) -> Timecode:
        """Parse ``HH:MM:SS:FF[.fff]``; raises ``ValueError`` naming the text if malformed."""
        m = _TIMECODE.match(text)
        if not m:
            raise ValueError(f"timecode {text!r} is not of the form HH:MM:SS:FF.fff")
        h, mi, s = int(m.group(1)), int(m.group(2)), int(m.group(3))
        f = float(m.group(4))
        if h > 23 or mi > 59 or s > 59 or f >= rate + 1e-6:
            raise ValueError(f"timecode {text!r} is out of range at {rate:g} fps")
        return cls(h, mi, s, f, rate)

    @property
    def seconds_of_day(self) -> float:
        """Seconds since midnight (float64)."""
        return self.hours * 3600 + self.minutes * 60 + self.seconds + self.frames / self.rate

    @classmethod
    def from_seconds(cls, seconds: float, rate: float = CSV_TIMECODE_RATE) -> Timecode:
        """The timecode of a time of day in seconds (wrapped at midnight)."""
        s = float(seconds) % DAY_S
        whole = int(np.floor(s))
        frames = (s - whole) * rate
        # Keep 3 decimals stable: 59.9996 frames must carry into the next second, not print "60.000".
        frames = round(frames, 3)
        if frames >= rate:
            frames -= rate
            whole = (whole + 1) % int(DAY_S)
        return cls(whole // 3600, whole // 60 % 60, whole % 60, frames, rate)

    def format(self, decimals: int = 3) -> str:
        """``HH:MM:SS:FF.fff`` as the app writes it (FF two digits, ``decimals`` sub-frame digits)."""
        width = 3 + decimals if decimals else 2
        return f"{self.hours:02d}:{self.minutes:02d}:{self.seconds:02d}:{self.frames:0{width}.{decimals}f}"

    def __str__(self) -> str:
        return self.format()


def parse_fixed_width(chars: np.ndarray) -> np.ndarray | None:
    """Seconds of day for an (n, 15) uint8 array of ``HH:MM:SS:FF.fff`` timecodes, vectorised.

    Returns ``None`` when any row is not in exactly that layout, so the caller can fall back to the
    general parser (which then names the offending line).
    """
    if chars.ndim != 2 or chars.shape[1] != 15:
        return None
    seps = chars[:, [2, 5, 8, 11]]
    if not (np.all(seps[:, :3] == ord(":")) and np.all(seps[:, 3] == ord("."))):
        return None
    d = chars[:, [0, 1, 3, 4, 6, 7, 9, 10, 12, 13, 14]].astype(np.int32) - ord("0")
    if d.size and (d.min() < 0 or d.max() > 9):
        return None
    h = d[:, 0] * 10 + d[:, 1]
    m = d[:, 2] * 10 + d[:, 3]
    s = d[:, 4] * 10 + d[:, 5]
    milli_frames = (d[:, 6] * 10 + d[:, 7]) * 1000 + d[:, 8] * 100 + d[:, 9] * 10 + d[:, 10]
    if h.size and (h.max() > 23 or m.max() > 59 or s.max() > 59 or milli_frames.max() >= 60000):
        return None
    return (h * 3600 + m * 60 + s).astype(np.float64) + milli_frames / (1000 * CSV_TIMECODE_RATE)


def unwrap_midnight(seconds_of_day: np.ndarray) -> np.ndarray:
    """Make times of day continuous across midnight: a backward jump of over 12 h adds a day."""
    t = np.asarray(seconds_of_day, dtype=np.float64)
    if t.size < 2:
        return t.copy()
    wraps = np.concatenate([[0], np.cumsum(np.diff(t) < -DAY_S / 2)])
    return t + wraps * DAY_S
