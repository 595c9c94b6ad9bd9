"""Coarticulation: from a phone sequence to smooth ``pronunciation32`` trajectories.

Each segment holds its viseme target with a per-channel dominance. The trajectory is the
dominance-weighted average of the targets under a symmetric smoothing kernel (normalised convolution):
``y = K*(w x) / K*(w)`` with ``K`` a critically damped second-order low-pass run forwards and
backwards. This is the dominance model of Cohen and Massaro in a form that vectorises: a bilabial's
high lip dominance closes the lips even inside a vowel context, while a /t/ with low dominance lets
the jaw and lips of its neighbouring vowels through, and rounding spreads ahead of a rounded vowel.

The face leads the sound: the face shown at audio time ``t`` is the articulation of time
``t + face_lead_s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import filtfilt

from ..channels import PRONUNCIATION32
from .phones import JAW_CHANNELS, LIP_CHANNELS, viseme_matrix, viseme_vector
from .prosody import Utterance
from .speaker import Speaker

CONTROL_RATE = 200.0  # Hz: articulation is computed on a 5 ms grid, then sampled at the frame times
MARGIN_S = 1.0  # grid extends this far past the audio so capture offsets never leave it

_REST = viseme_vector({})
_TAU = {"lips": 0.016, "jaw": 0.024, "other": 0.03}  # s, time constant of each articulator group
_GROUP = {c: "lips" for c in LIP_CHANNELS} | {c: "jaw" for c in JAW_CHANNELS}


@dataclass
class Articulation:
    """The speaker's articulation on a uniform grid of the audio clock (s), ``pronunciation32`` channels."""

    t0: float
    rate: float
    values: np.ndarray  # (grid points, 32) float64, 0..1 units
    face_lead_s: float

    def face_at(self, t: np.ndarray) -> np.ndarray:
        """The face (frames x 32) seen at audio times ``t`` (s), the natural lead included."""
        x = (np.asarray(t, dtype=np.float64) + self.face_lead_s - self.t0) * self.rate
        x = np.clip(x, 0.0, self.values.shape[0] - 1.000001)
        i = np.floor(x).astype(np.int64)
        f = (x - i)[:, None]
        return self.values[i] * (1.0 - f) + self.values[i + 1] * f


def _lowpass(tau_s: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    a = np.exp(-1.0 / (tau_s * rate))
    return np.array([(1.0 - a) ** 2]), np.array([1.0, -2.0 * a, a * a])


def articulate(utt: Utterance, speaker: Speaker) -> Articulation:
    """Smooth ``pronunciation32`` trajectories of ``utt`` as spoken by ``speaker`` (0..1 units)."""
    inv = utt.inventory
    targets, dominance = viseme_matrix(inv)
    second = np.stack(
        [viseme_vector(p.viseme2) if p.viseme2 is not None else targets[i] for i, p in enumerate(inv.phones)]
    )
    seg_targets = np.where(utt.part[:, None] == 1, second[utt.phone], targets[utt.phone])
    seg_dom = dominance[utt.phone]
    # Prosody opens the jaw wider on loud, high vowels; the lower lip follows the jaw.
    for name in JAW_CHANNELS:
        j = PRONUNCIATION32.index(name)
        seg_targets[:, j] = seg_targets[:, j] * utt.jaw_gain
    gain = speaker.articulation_gain * np.asarray(speaker.channel_gain)
    seg_targets = _REST + (seg_targets - _REST) * gain

    sr = utt.sample_rate
    t0 = -MARGIN_S
    n = int(np.ceil((utt.duration_s + 2 * MARGIN_S) * CONTROL_RATE)) + 1
    grid = t0 + np.arange(n) / CONTROL_RATE
    seg = np.searchsorted(utt.end / sr, grid, side="right")
    inside = (grid >= 0) & (seg < utt.phone.size)
    seg = np.clip(seg, 0, utt.phone.size - 1)
    x = np.where(inside[:, None], seg_targets[seg], _REST)
    w = np.where(inside[:, None], seg_dom[seg], 0.6)
    out = np.empty_like(x)
    for group, tau in _TAU.items():
        cols = [j for j, c in enumerate(PRONUNCIATION32) if _GROUP.get(c, "other") == group]
        b, a = _lowpass(tau, CONTROL_RATE)
        num = filtfilt(b, a, (w * x)[:, cols], axis=0, padtype="constant")
        den = filtfilt(b, a, w[:, cols], axis=0, padtype="constant")
        out[:, cols] = num / np.maximum(den, 1e-9)
    # Left/right channels differ slightly per speaker, as real faces do.
    asym = speaker.left_right_asymmetry
    for j, c in enumerate(PRONUNCIATION32):
        if c.endswith("Left"):
            out[:, j] *= 1.0 + asym
        elif c.endswith("Right"):
            out[:, j] *= 1.0 - asym
    return Articulation(t0, CONTROL_RATE, np.maximum(out, 0.0), speaker.face_lead_s)
