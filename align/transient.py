"""Claps and other sharp sync transients, found separately in the audio, the blendshapes and the
take's reference video (OpenCV), so their times can be compared.

Audio: a clap is a broadband impulse: the energy above 2 kHz jumps within a few milliseconds far above
what came just before, dies away within tens of milliseconds, and stands far above every other sound in
the half second around it. Speech bursts (the release of a "t" or "k" after its silent closure) can jump
as far and die as fast, but the speech around them is nearly as loud: at most 12 dB below the burst in
the real and simulated speech checked, against 30 dB and more for a clap in the pause before speech.
Face: a sync gesture (a jaw snap, a "pa" after closed lips) is a jump of the mouth-opening signal much
larger than any articulation step in the take. Video: a hand clap or clapper in front of the camera is a
burst of frame-to-frame change, largest at the moment of contact.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import maximum_filter1d

from capture.mov import opencv_name

from .resample import TARGET_RATE

# Above 2 kHz; causal, but its group delay there is a fraction of a millisecond (onsets stay put).
CLAP_HIGH_PASS_HZ = 2000.0
# How far (dB) a clap stands above the loudest other sound within CLAP_SURROUNDINGS_S of it, and how far
# that reaches: a speech burst is at most 12 dB above the speech around it (see above).
CLAP_ABOVE_SURROUNDINGS_DB = 20.0
CLAP_SURROUNDINGS_S = 0.5


@dataclass
class Transient:
    """One transient: take time (s) and strength (how many times above the threshold)."""

    time_s: float
    strength: float


def audio_claps(x: np.ndarray, start_s: float, min_jump_db: float = 30.0) -> list[Transient]:
    """Clap-like impulses in 16 kHz mono audio whose first sample is at take time ``start_s`` (s); the
    strength is how far (dB) an impulse stands above the sound around it, over ``min_jump_db``."""
    hop = 32  # 2 ms
    n = x.size // hop
    if n < 100:
        return []
    high = _HighBand(x)
    e = high.energy(hop)
    db = 10 * np.log10(e + 1e-12)
    loud = db.max()
    # Loudest 2 ms window 12-100 ms before each window, and 40-60 ms after it.
    wide = maximum_filter1d(db, size=45)  # centred: covers [j - 22, j + 22]
    before = np.full(n, np.inf)
    before[50:] = wide[22:-28]
    near = maximum_filter1d(db, size=11)
    after = np.full(n, np.inf)
    after[: n - 25] = near[25:]
    jump = db - before
    decay = db - after
    candidates = np.flatnonzero((jump >= min_jump_db) & (decay >= 20.0) & (db >= loud - 12.0))
    reach = int(CLAP_SURROUNDINGS_S * TARGET_RATE / hop)
    out: list[Transient] = []
    last = -1_000_000
    for i in candidates:
        if i - last < 50:  # one event per 100 ms
            continue
        # The loudest sound around the impulse, outside its own onset and 60 ms decay.
        around = np.concatenate([db[max(i - reach, 0) : i - 6], db[i + 30 : i + reach]])
        above = db[i] - around.max()
        if above < CLAP_ABOVE_SURROUNDINGS_DB:
            continue
        last = i
        seg = np.abs(high.samples(i * hop - hop, (i + 2) * hop))
        k = int(np.flatnonzero(seg >= 0.3 * seg.max())[0]) + i * hop - hop
        out.append(Transient(start_s + k / TARGET_RATE, float(above / min_jump_db)))
    return out


class _HighBand:
    """The audio through the clap high-pass (4th-order Butterworth above ``CLAP_HIGH_PASS_HZ``, causal),
    computed a block at a time: an hour of it in float64 (with its float64 input and its square) took
    1.4 GB. The filter's state at each block's start is kept, so that the few stretches a clap needs
    again are filtered anew from the block they lie in, sample for sample the same."""

    BLOCK = 1 << 18  # samples (16 s), a multiple of the energy hop

    def __init__(self, x: np.ndarray):
        from scipy.signal import butter  # here: scipy.signal adds 0.5 s to every command's start

        self.x = x
        self.sos = butter(4, CLAP_HIGH_PASS_HZ, btype="high", fs=TARGET_RATE, output="sos")
        self.starts: list[np.ndarray] = []  # the filter's state at the start of each block

    def energy(self, hop: int) -> np.ndarray:
        """Mean square of the high-passed audio in each whole window of ``hop`` samples."""
        from scipy.signal import sosfilt

        x, n = self.x, self.x.size // hop
        e = np.empty(n)
        zi = np.zeros((self.sos.shape[0], 2))
        for lo in range(0, x.size, self.BLOCK):
            self.starts.append(zi)
            hp, zi = sosfilt(self.sos, x[lo : lo + self.BLOCK].astype(np.float64), zi=zi)
            k, rows = lo // hop, min(hp.size // hop, n - lo // hop)
            e[k : k + rows] = np.square(hp[: rows * hop]).reshape(rows, hop).mean(axis=1)
        return e

    def samples(self, lo: int, hi: int) -> np.ndarray:
        """The high-passed samples ``lo:hi`` (after ``energy``), filtered again from their block's start."""
        from scipy.signal import sosfilt

        lo, hi = max(lo, 0), min(hi, self.x.size)
        first = lo // self.BLOCK * self.BLOCK
        hp, _ = sosfilt(self.sos, self.x[first:hi].astype(np.float64), zi=self.starts[lo // self.BLOCK])
        return hp[lo - first :]


def step_transients(t: np.ndarray, signal: np.ndarray, min_ratio: float = 2.5) -> list[Transient]:
    """Jumps between consecutive frames of a per-frame signal (times ``t``, s) at least ``min_ratio``
    times the take's 99.5th-percentile step, timed halfway between the two frames."""
    ok = np.isfinite(signal)
    t, s = t[ok], signal[ok]
    if s.size < 20:
        return []
    d = np.abs(np.diff(s))
    ref = float(np.percentile(d, 99.5)) or 1e-9
    idx = np.flatnonzero(d >= min_ratio * ref)
    return _first_of_bursts(
        [Transient(float(0.5 * (t[i] + t[i + 1])), float(d[i] / (min_ratio * ref))) for i in idx]
    )


def _first_of_bursts(items: list[Transient], gap_s: float = 0.25) -> list[Transient]:
    """One transient per burst: a snap's rise and fall (or a clap's shake) count once, at the first."""
    out: list[Transient] = []
    for x in items:
        if out and x.time_s - out[-1].time_s < gap_s:
            continue
        out.append(x)
    return out


def video_motion(path: str | Path, size: int = 64) -> np.ndarray:
    """Mean absolute change between consecutive frames of a video (0..255 units), one value per frame
    (the first is 0). Read with OpenCV; frames are shrunk to ``size`` pixels wide and made grey."""
    import cv2

    with opencv_name(path) as name:
        cap = cv2.VideoCapture(name)
    if not cap.isOpened():
        return np.zeros(0)
    prev = None
    out = []
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            h, w = frame.shape[:2]
            small = cv2.resize(frame, (size, max(1, round(h * size / w))), interpolation=cv2.INTER_AREA)
            grey = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY).astype(np.float32)
            out.append(0.0 if prev is None else float(np.mean(np.abs(grey - prev))))
            prev = grey
    finally:
        cap.release()
    return np.asarray(out)


def video_transients(motion: np.ndarray, frame_t: np.ndarray, min_ratio: float = 6.0) -> list[Transient]:
    """Bursts of frame-to-frame change (``video_motion``) at least ``min_ratio`` times the take's
    99th percentile, at the take time (s) of the frame where the change lands."""
    n = min(motion.size, frame_t.size)
    if n < 20:
        return []
    m = motion[:n]
    ref = float(np.percentile(m, 99)) or 1e-9
    idx = [i for i in np.flatnonzero(m >= min_ratio * ref) if i > 0]
    return _first_of_bursts(
        [Transient(float(0.5 * (frame_t[i - 1] + frame_t[i])), float(m[i] / (min_ratio * ref))) for i in idx]
    )
