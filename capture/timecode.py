"""Live Link Face timecodes.

A timecode cell reads ``HH:MM:SS:FF.fff``: FF is the frame within the second at the timecode rate and
``.fff`` the fractional sub-frame (0..1 of a frame), not milliseconds. The app's CSV always uses a
60 fps timecode rate, also when it writes 30 rows/s, so ``seconds = H*3600 + M*60 + S + FF.fff/60``.
The app's FF runs 0..59.999; FF equal to the rate (``60.000``, from a writer rounding 59.9996 up) is
read as the next second's frame 0, as the sum says (``is_whole_second``: the CSV reader notes it);
beyond the rate the timecode is out of range.
Other writers of the format count FF at the take's own rate (formats doc §8): ``timecode_rate_of``
recognises them and ``at_timecode_rate`` re-reads their times.
``frame_log.csv`` may also use the drop-frame separator ``;`` (iPhone timecode itself never drops).
Rows whose every timecode is written ``HH:MM:SS;FF`` at 30 or 60 fps are taken at the separator's word
(SMPTE's mark of a drop-frame count): frames counted at 29.97 or 59.94 fps from the first row's label,
unless a label is one such a count skips (``drop_frame_seconds``). Within a minute drop-frame and plain
labels are the same, so a take that crosses no minute start where the count skips cannot show it either way.
NeuroSync Player writes the milliseconds of the second after the dot (``00:00:01:03.050`` is 1.050 s):
``millisecond_seconds`` recognises its rows, whose FF agrees with them, and re-reads their times.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property

import numpy as np

CSV_TIMECODE_RATE = 60.0
DAY_S = 86400.0
# Lower rates other writers of the app's CSV format count FF at (the app itself always counts at 60).
OTHER_TIMECODE_RATES = (24.0, 25.0, 30.0, 48.0, 50.0)
# Whole seconds a take must cover before its FF values tell the rate they count at.
MIN_WHOLE_SECONDS = 2

# ASCII digits only: a bare \d also matches other scripts' digits, which int() and float() read. Fields of
# one digit are read too: scripts write f"{h}:{m}:{s}:{ff}" (``12:28:1:03.060``); ``is_zero_padded`` tells.
_TIMECODE = re.compile(r"^\s*(\d{1,2}):(\d{1,2}):(\d{1,2})[:;](\d{1,3}(?:\.\d*)?)\s*$", re.ASCII)
_PADDED = re.compile(r"^\s*\d{1,2}:\d{2}:\d{2}[:;]", re.ASCII)
# A time of day as other tools write it in the Timecode column: seconds with a decimal fraction, no frames.
_CLOCK_TIME = re.compile(r"^\s*(\d{1,2}):(\d{2}):(\d{2}\.\d+)\s*$", re.ASCII)


def clock_seconds(text: str) -> float | None:
    """Seconds since midnight of a time written ``HH:MM:SS.fff`` (seconds and their fraction, as other
    writers of the app's CSV layout put a clock time in its Timecode column), or None for other text."""
    m = _CLOCK_TIME.match(text)
    if not m:
        return None
    h, mi, s = int(m.group(1)), int(m.group(2)), float(m.group(3))
    return h * 3600 + mi * 60 + s if h <= 23 and mi <= 59 and s < 60 else None


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
        if h > 23 or mi > 59 or s > 59 or f > rate:
            raise ValueError(f"timecode {text!r} is out of range at {rate:g} fps")
        return cls(h, mi, s, f, rate)

    @staticmethod
    def is_zero_padded(text: str) -> bool:
        """Whether a timecode ``parse`` reads writes its minutes and seconds with two digits, as the app
        does (``12:28:01:03.060``, not ``12:28:1:03.060``; hours of one digit were always read as such)."""
        return _PADDED.match(text) is not None

    @property
    def is_whole_second(self) -> bool:
        """FF equals the rate (``12:28:01:60.000``): no writer that counts frames within the second writes
        it (the app's FF stops at 59.999), one rounding 59.9996 to 3 decimals does."""
        return self.frames >= self.rate

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


def fixed_width_seconds(chars: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Seconds of day for an (n, 15) uint8 array of ``HH:MM:SS:FF.fff`` timecodes, vectorised, and which
    rows are in exactly that layout and in range (FF below 60: ``60.000`` is for the general parser, which
    notes it). Rows that are not hold meaningless seconds.

    The sum is ``Timecode.parse``'s to the bit: whole seconds plus FF.fff (the decimal, correctly rounded:
    milli-frames / 1000) / 60, so that both parsers give one time for one cell.
    """
    d = chars[:, [0, 1, 3, 4, 6, 7, 9, 10, 12, 13, 14]].astype(np.int32) - ord("0")
    seps = chars[:, [2, 5, 8, 11]]
    ok = np.all((d >= 0) & (d <= 9), axis=1) & np.all(seps == np.frombuffer(b":::.", np.uint8), axis=1)
    h = d[:, 0] * 10 + d[:, 1]
    m = d[:, 2] * 10 + d[:, 3]
    s = d[:, 4] * 10 + d[:, 5]
    milli_frames = (d[:, 6] * 10 + d[:, 7]) * 1000 + d[:, 8] * 100 + d[:, 9] * 10 + d[:, 10]
    ok &= (h <= 23) & (m <= 59) & (s <= 59) & (milli_frames < 60000)
    frames = milli_frames / 1000
    return (h * 3600 + m * 60 + s).astype(np.float64) + frames / CSV_TIMECODE_RATE, ok


def unwrap_midnight(seconds_of_day: np.ndarray) -> np.ndarray:
    """Make times of day continuous across midnight: a backward jump of over 12 h adds a day."""
    t = np.asarray(seconds_of_day, dtype=np.float64)
    if t.size < 2:
        return t.copy()
    wraps = np.concatenate([[0], np.cumsum(np.diff(t) < -DAY_S / 2)])
    return t + wraps * DAY_S


@dataclass(frozen=True, eq=False)
class TimecodeFields:
    """Times of day read at the app's 60 fps timecode rate, split into whole seconds and the FF.fff field
    (``timecode_frames``): split once for one CSV read, and what its timecodes are judged (in
    milliseconds? counted at which rate?) and re-read with."""

    whole: np.ndarray
    frames: np.ndarray

    @cached_property
    def whole_seconds(self) -> int:
        """How many timecode seconds the rows cover from start to end: every second but the last, and the
        first only when it starts at frame 0."""
        covered = np.unique(self.whole).size - 1
        return covered if self.frames.size and self.frames[0] < 1 else max(covered - 1, 0)


Times = np.ndarray | TimecodeFields  # times of day (s), or their fields already split


def timecode_frames(seconds_of_day: Times) -> TimecodeFields:
    """Whole seconds and the FF.fff field of times of day read at the app's 60 fps timecode rate (fields
    given are returned as they are)."""
    if isinstance(seconds_of_day, TimecodeFields):
        return seconds_of_day
    t = np.asarray(seconds_of_day, dtype=np.float64)
    whole = np.floor(t)
    return TimecodeFields(whole, (t - whole) * CSV_TIMECODE_RATE)


def at_timecode_rate(seconds_of_day: Times, rate: float) -> np.ndarray:
    """Times of day read with FF at 60 fps, re-read with FF counted at ``rate`` frames per second."""
    fields = timecode_frames(seconds_of_day)
    return fields.whole + fields.frames / rate


# Drop-frame counts (``HH:MM:SS;FF``): at these nominal rates the labels of the first frames of each minute
# are skipped, but of every tenth minute, so that the labels keep up with the NTSC rate (N * 1000/1001).
DROP_FRAME_LABELS = {30.0: 2, 60.0: 4}


def drop_frame_seconds(label_seconds: np.ndarray, rate: float) -> np.ndarray | None:
    """Times (s) of frames labelled with drop-frame timecodes, given their labels read as seconds at the
    nominal ``rate`` (30 or 60): the first frame at its label as written (where the take folder's
    ``frame_log.csv`` and ``.mov`` timecodes, read as written, put it too), each later one frames counted
    at the NTSC rate after it. None when a label is one a drop-frame count skips (a writer using ``;``
    without counting so): the labels are then read as they stand. Labels that cross no minute start where
    the count skips (every minute's but every tenth's) are the same in either count: the ``;`` decides.
    """
    drop = DROP_FRAME_LABELS.get(rate)
    if drop is None:
        return None
    labels = np.asarray(label_seconds, dtype=np.float64) * rate
    minutes = np.floor(labels / (60 * rate) + 1e-9)
    frame_in_minute = labels - minutes * 60 * rate
    skipped = (frame_in_minute < drop - 1e-6) & (minutes % 10 != 0)
    if skipped.any():
        return None
    frames = labels - drop * (minutes - minutes // 10)
    return float(label_seconds[0]) + (frames - frames[0]) / (rate * 1000 / 1001)


# Rows a take must hold before the part of its timecodes after the dot may be read as milliseconds: a row of
# the app's may look so by chance (about 1 in 30), ten in a row cannot (its sub-frame creeps 0.0016 a row).
MIN_MILLISECOND_ROWS = 10


def millisecond_seconds(seconds_of_day: Times) -> np.ndarray | None:
    """Times of day of timecodes written ``HH:MM:SS:FF.mmm`` with ``.mmm`` the milliseconds of the second,
    not the sub-frame (NeuroSync Player's CSVs), from their times read as the app's (sorted); None unless
    at least ``MIN_MILLISECOND_ROWS`` rows all read so: three decimals, whose milliseconds put the row
    within a frame of its FF at 60 fps. (The app's sub-frame stays near one value while FF runs through the
    second, so that its rows agree with FF one in about 30, never ten in a row.)"""
    fields = timecode_frames(seconds_of_day)
    whole, frames = fields.whole, fields.frames
    if frames.size < MIN_MILLISECOND_ROWS:
        return None
    milli_frames = np.rint(frames * 1000)
    if np.abs(frames * 1000 - milli_frames).max() > 1e-3:
        return None  # not three decimals
    ff, milliseconds = np.divmod(milli_frames, 1000)
    if np.abs(milliseconds * CSV_TIMECODE_RATE / 1000 - ff).max() > 1:
        return None
    return whole + milliseconds / 1000


def timecode_rate_of(seconds_of_day: Times) -> float | None:
    """The rate a CSV's FF field counts at, from its times of day read at 60 fps (sorted).

    60 when FF reaches what it must at 60 fps (within 1.5 row steps of 60), or when the rows cover
    fewer than ``MIN_WHOLE_SECONDS`` whole seconds or come less than once a second (too few to tell).
    Else the lowest of ``OTHER_TIMECODE_RATES`` that FF stays below and reaches (within 1.5 row steps
    of it, and the median second within 2.5, allowing for dropped rows); None when none fits.
    """
    fields = timecode_frames(seconds_of_day)
    whole, frames = fields.whole, fields.frames
    same_second = np.diff(whole) == 0
    if fields.whole_seconds < MIN_WHOLE_SECONDS or not same_second.any():
        return CSV_TIMECODE_RATE  # too short, or under a row a second: FF cannot tell
    step = float(np.median(np.diff(frames)[same_second]))
    top = float(frames.max())
    if top >= CSV_TIMECODE_RATE - 1.5 * step:
        return CSV_TIMECODE_RATE
    starts = np.flatnonzero(np.diff(whole, prepend=whole[0] - 1))
    second_tops = np.maximum.reduceat(frames, starts)[1:-1]  # the seconds between the first and last
    for rate in OTHER_TIMECODE_RATES:
        if top < rate:
            reached = top >= rate - 1.5 * step and np.median(second_tops) >= rate - 2.5 * step
            return rate if reached else None
    return None
