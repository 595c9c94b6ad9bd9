"""Source-filter speech synthesis for the simulated speaker.

Source: a Rosenberg glottal pulse train whose phase follows the F0 contour (declination, accents,
jitter), differentiated for lip radiation, plus aspiration noise. Filter: per segment a cascade of
formant resonators (F1..F4, scaled by the speaker's vocal-tract length, F1 raised by a wider jaw), and
a band-pass noise path for frication and stop bursts. Segments are filtered one at a time and
cross-faded over 10 ms on each side of every boundary, so formants glide from phone to phone.
Everything runs as whole-array numpy and ``scipy.signal.lfilter`` calls, a few per phone.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.signal import butter, lfilter, resample_poly

from .phones import Phone
from .prosody import Utterance
from .speaker import Speaker

XFADE_S = 0.010  # half-length of the cross-fade at each segment boundary
PREROLL_S = 0.008  # resonators ring in before a segment's output is used
_F4 = 3500.0
_BANDWIDTHS = (70.0, 100.0, 140.0, 200.0)  # Hz, F1..F4
_OPEN_Q, _CLOSE_Q = 0.42, 0.16  # Rosenberg pulse: opening and closing fractions of a period


def resonator_sos(freqs: tuple[float, ...], sample_rate: int) -> np.ndarray:
    """Cascade of two-pole resonators (one SOS row per formant), each with unit gain at 0 Hz."""
    rows = []
    nyq = 0.47 * sample_rate
    for f, bw in zip(freqs, _BANDWIDTHS):
        if f >= nyq:
            continue
        r = np.exp(-np.pi * bw / sample_rate)
        c = -2.0 * r * np.cos(2.0 * np.pi * f / sample_rate)
        g = 1.0 + c + r * r
        rows.append([g, 0.0, 0.0, 1.0, c, r * r])
    return np.asarray(rows, dtype=np.float64)


def _resonator_tf(freqs: tuple[float, ...], sample_rate: int) -> tuple[np.ndarray, np.ndarray]:
    # One direct-form filter for the whole cascade: four well-separated resonators stay accurate
    # (1e-8 of the SOS result at 44.1 kHz) and one lfilter call costs half of a sosfilt call.
    sos = resonator_sos(freqs, sample_rate)
    a = np.ones(1)
    for row in sos:
        a = np.convolve(a, row[3:])
    return np.array([np.prod(sos[:, 0])]), a


@lru_cache(maxsize=256)
def _band_tf(low: float, high: float, sample_rate: int) -> tuple[np.ndarray, np.ndarray]:
    high = min(high, 0.45 * sample_rate)
    low = min(low, 0.6 * high)
    return butter(2, [low, high], btype="band", fs=sample_rate)


def _glottal_table(size: int = 4096) -> np.ndarray:
    # Derivative of the Rosenberg flow per unit of phase, tabulated once.
    frac = np.arange(size) / size
    flow = np.where(
        frac < _OPEN_Q,
        0.5 - 0.5 * np.cos(np.pi * frac / _OPEN_Q),
        np.where(frac < _OPEN_Q + _CLOSE_Q, np.cos(0.5 * np.pi * (frac - _OPEN_Q) / _CLOSE_Q), 0.0),
    )
    return (np.roll(flow, -1) - flow) * size


_GLOTTAL = _glottal_table()


def glottal_source(f0_hz: np.ndarray, sample_rate: int) -> np.ndarray:
    """Differentiated Rosenberg pulses following ``f0_hz`` (one value per sample); peak ~1 at 100 Hz."""
    phase = np.cumsum(f0_hz / sample_rate)
    idx = ((phase - np.floor(phase)) * _GLOTTAL.size).astype(np.int64)
    # d(flow)/dt = d(flow)/d(phase) * f0; scaled so the closing peak is ~1 at 100 Hz.
    return _GLOTTAL[idx] * f0_hz * (2.0 * _CLOSE_Q / (np.pi * 100.0))


def _formants(ph: Phone, part: int, speaker: Speaker, jaw_gain: float) -> tuple[float, ...]:
    f = ph.formants2 if (part == 1 and ph.formants2 is not None) else ph.formants
    f1 = f[0] * jaw_gain**0.35  # a wider jaw raises F1
    return tuple(x * speaker.vtl_scale for x in (f1, f[1], f[2], _F4))


CHUNK_S = 20.0  # speech is synthesised in chunks of about this length, cut in silences (bounded memory)


def synthesize(utt: Utterance, speaker: Speaker, rng: np.random.Generator) -> np.ndarray:
    """Speech samples (float64, about ±0.5 full scale before the microphone) of ``utt``."""
    out = np.zeros(utt.samples)
    phones = utt.inventory.phones
    first = 0
    for i in range(1, utt.phone.size + 1):
        at_end = i == utt.phone.size
        long_enough = not at_end and (utt.start[i] - utt.start[first]) >= CHUNK_S * utt.sample_rate
        if at_end or (long_enough and phones[utt.phone[i]].kind == "silence"):
            _synthesize_chunk(utt, speaker, rng, first, i, out)
            first = i
    return out


def _synthesize_chunk(
    utt: Utterance, speaker: Speaker, rng: np.random.Generator, first: int, stop: int, out: np.ndarray
) -> None:
    """Add segments ``first`` .. ``stop - 1`` of ``utt`` to ``out``."""
    sr = utt.sample_rate
    n = utt.samples
    inv = utt.inventory
    xf = int(round(XFADE_S * sr))
    pre = int(round(PREROLL_S * sr))
    c_lo = max(int(utt.start[first]) - xf - pre, 0)
    c_hi = min(int(utt.end[stop - 1]) + xf, n)
    t = np.arange(c_lo, c_hi) / sr
    # F0 on a 5 ms grid with jitter, then per sample.
    grid_t = np.arange(t[0], t[-1] + 0.01, 0.005)
    st = utt.f0_st(grid_t) + rng.normal(0.0, speaker.jitter * 17.3, grid_t.size)  # 1 % jitter ~ 0.17 st
    f0 = np.interp(t, grid_t, speaker.f0_hz * 2.0 ** (st / 12.0))
    # Normalised to the speaker's base F0: high voices are not louder, but a pitch accent still is.
    source = glottal_source(f0, sr) * (100.0 / speaker.f0_hz)
    source *= np.interp(t, grid_t, np.exp(rng.normal(0.0, 0.05, grid_t.size)))  # shimmer
    noise = _uniform_noise(rng, c_hi - c_lo).astype(np.float64)
    breathy = source + speaker.breathiness * noise  # vowels' excitation: voicing plus a little breath

    ramp_up = (np.arange(2 * xf) + 0.5) / (2 * xf)
    ramp_down = ramp_up[::-1].copy()
    phones = inv.phones
    level = 10.0 ** ((speaker.loudness_db + utt.loud_db) / 20.0)
    burst_len = int(0.012 * sr)
    burst_shape = np.linspace(1.0, 0.2, burst_len)
    for i in range(first, stop):
        ph = phones[utt.phone[i]]
        kind = ph.kind
        if kind == "silence":
            continue
        a, b = int(utt.start[i]), int(utt.end[i])
        lo, hi = a - xf - pre, b + xf
        if lo < c_lo or hi > c_hi:
            continue  # speech always sits between leading and trailing silence; never reached
        lo, hi, a, b = lo - c_lo, hi - c_lo, a - c_lo, b - c_lo  # chunk-local sample indices
        amp = level[i] * (10.0 ** (ph.intrinsic_db / 20.0))
        fric = None
        if kind in ("stop", "affricate"):
            rel = a + int(0.65 * (b - a)) - lo  # release point: closure first, then the burst
            exc = np.empty(hi - lo)
            exc[:rel] = (0.12 * amp) * source[lo : lo + rel] if ph.voiced else 0.0
            if ph.voiced:
                exc[rel:] = (0.5 * amp) * breathy[lo + rel : hi]  # voicing resumes after the release
            else:
                exc[rel:] = (0.35 * amp) * noise[lo + rel : hi]  # aspiration
            fric = np.zeros(hi - lo)
            burst = min(burst_len, hi - lo - rel)
            fric[rel : rel + burst] = (1.2 * amp) * burst_shape[:burst]
            if kind == "affricate":
                fric[rel + burst :] = ph.frication_level * amp
            fric *= noise[lo:hi]
        elif kind == "fricative":
            if ph.place == "glottal":
                exc = (0.12 * amp) * noise[lo:hi]  # /h/: breath through the next vowel
            else:
                exc = (0.3 * amp) * source[lo:hi] if ph.voiced else None
                fric = (ph.frication_level * amp) * noise[lo:hi]
        elif kind == "nasal":
            exc = (0.3 * amp) * breathy[lo:hi]
        elif kind in ("approximant", "tap"):
            exc = (0.55 * amp) * breathy[lo:hi]
        else:
            exc = amp * breathy[lo:hi]
        seg = np.zeros(hi - lo) if exc is None else None
        if exc is not None:
            # Stops and fricatives take their vocal-tract shape from the next vowel (coarticulation).
            shape_ph, shape_part = ph, int(utt.part[i])
            if kind in ("stop", "fricative", "affricate") and i + 1 < utt.phone.size:
                nxt = phones[utt.phone[i + 1]]
                if nxt.is_vowel:
                    shape_ph, shape_part = nxt, 0
            bf, af = _resonator_tf(_formants(shape_ph, shape_part, speaker, float(utt.jaw_gain[i])), sr)
            seg = lfilter(bf, af, exc)
            if kind == "nasal":
                seg = lfilter(*_band_tf(80.0, 2000.0, sr), seg)
        if fric is not None:
            band = ph.frication if (ph.frication is not None and kind != "stop") else None
            if band is None:
                band = (0.6 * ph.burst, 1.6 * ph.burst)
            seg = seg + lfilter(*_band_tf(band[0], band[1], sr), fric)
        # Linear cross-fade ramps centred on both boundaries; neighbouring ramps sum to one.
        seg = seg[pre:]
        seg[: 2 * xf] *= ramp_up
        seg[-2 * xf :] *= ramp_down
        out[c_lo + a - xf : c_lo + hi] += seg * 0.07  # speech at about -26 dBFS RMS before the microphone


def synthesis_rate(sample_rate: int) -> int:
    """The rate (Hz) the voice is synthesised at: 44.1/48 kHz output is made at half rate and
    upsampled, as speech above 11 kHz carries nothing a model of the face needs."""
    return sample_rate // 2 if sample_rate > 24000 else sample_rate


def _uniform_noise(rng: np.random.Generator, n: int) -> np.ndarray:
    # Unit-variance uniform noise: a fifth of the cost of Gaussian draws, and once filtered the
    # difference is inaudible.
    return (rng.random(n, dtype=np.float32) - np.float32(0.5)) * np.float32(np.sqrt(12.0))


def microphone(
    speech: np.ndarray,
    rng: np.random.Generator,
    gain_db: float,
    noise_db: float,
    speech_rate: int,
    sample_rate: int,
) -> np.ndarray:
    """The recorded signal as 16-bit PCM at ``sample_rate`` (Hz): speech (at ``speech_rate``) at the
    microphone's gain plus room noise of ``noise_db`` dBFS RMS (rumble and hiss), clipped."""
    p = np.exp(-2.0 * np.pi * 300.0 / speech_rate)
    # Rumble: low-passed noise scaled analytically (a one-pole filter passes (1-p)/(1+p) of the power).
    level = 10.0 ** (noise_db / 20.0)
    y = lfilter([1.0 - p], [1.0, -p], _uniform_noise(rng, speech.size))
    y *= 0.95 * level / np.sqrt((1.0 - p) / (1.0 + p))
    y += speech * 10.0 ** (gain_db / 20.0)
    if sample_rate != speech_rate:
        y = resample_poly(y, sample_rate // speech_rate, 1)
    y += _uniform_noise(rng, y.size) * np.float32(0.3 * level)
    # In place: long takes at 48 kHz would otherwise hold several full-length copies.
    y *= 32768.0
    np.rint(y, out=y)
    np.clip(y, -32768, 32767, out=y)
    return y.astype(np.int16)
