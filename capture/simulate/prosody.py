"""What the simulated speaker says and how: pseudo-words in phrases, phone durations, accents, F0 and
loudness.

An utterance is a table of segments (one per phone, two per diphthong) with sample-exact boundaries.
Prosody is drawn per phrase (loudness, F0 declination) and per word (accent). The same accent raises
F0, raises loudness and, through the speaker's couplings, opens the jaw wider: pitch and energy carry
information about the face that the phone identities alone do not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .phones import SILENCE, Inventory
from .speaker import Speaker

MIN_SEGMENT_S = 0.022  # shortest segment; keeps the voice's cross-fades (10 ms each side) valid


@dataclass
class Utterance:
    """Segments of one take's speech, on the audio clock (seconds from the first audio sample).

    Per segment: ``phone`` (inventory index), ``part`` (0, or 1 for a diphthong's second half),
    ``start``/``end`` (samples), ``word`` (index into ``words``, -1 in silence), ``phrase`` (-1 in
    silence), ``accent`` (0..1, the word's), ``loud_db`` (level relative to the speaker's, dB) and
    ``jaw_gain`` (multiplier on jaw opening from prosody).
    """

    inventory: Inventory
    sample_rate: int
    phone: np.ndarray
    part: np.ndarray
    start: np.ndarray
    end: np.ndarray
    word: np.ndarray
    phrase: np.ndarray
    accent: np.ndarray
    loud_db: np.ndarray
    jaw_gain: np.ndarray
    words: list[str]
    f0_knots_s: np.ndarray  # F0 contour knots (s) and values (semitones re the speaker's F0)
    f0_knots_st: np.ndarray

    @property
    def samples(self) -> int:
        return int(self.end[-1])

    @property
    def duration_s(self) -> float:
        return self.samples / self.sample_rate

    def f0_st(self, t: np.ndarray) -> np.ndarray:
        """F0 contour in semitones relative to the speaker's base F0 at times ``t`` (s)."""
        return np.interp(t, self.f0_knots_s, self.f0_knots_st)

    def phone_intervals(self) -> list[tuple[float, float, str]]:
        """(start s, end s, symbol) per phone, diphthong halves merged; silence is ``""``."""
        out: list[tuple[float, float, str]] = []
        sr = self.sample_rate
        for i in range(self.phone.size):
            sym = self.inventory.phones[self.phone[i]].symbol
            if self.part[i] == 1 and out:
                out[-1] = (out[-1][0], self.end[i] / sr, out[-1][2])
                continue
            label = "" if sym == SILENCE else sym
            if not label and out and not out[-1][2]:
                out[-1] = (out[-1][0], self.end[i] / sr, "")
                continue
            out.append((self.start[i] / sr, self.end[i] / sr, label))
        return out

    def word_intervals(self) -> list[tuple[float, float, str]]:
        """(start s, end s, word) per word, with ``""`` intervals for the silences between."""
        out: list[tuple[float, float, str]] = []
        sr = self.sample_rate
        for i in range(self.phone.size):
            w = int(self.word[i])
            label = self.words[w] if w >= 0 else ""
            key = (w, label)
            if out and out[-1][3] == key:
                out[-1] = (out[-1][0], self.end[i] / sr, label, key)
            else:
                out.append((self.start[i] / sr, self.end[i] / sr, label, key))
        return [(a, b, s) for a, b, s, _ in out]


def _syllable(rng: np.random.Generator, inv: Inventory) -> list[str]:
    onset = inv.onsets[rng.integers(len(inv.onsets))]
    vowels = inv.vowels
    nucleus = vowels[rng.integers(len(vowels))]
    coda: tuple[str, ...] = ()
    if rng.random() < inv.coda_probability:
        coda = inv.codas[rng.integers(len(inv.codas))]
    return [*onset, nucleus, *coda]


def plan_utterance(
    rng: np.random.Generator,
    inv: Inventory,
    speaker: Speaker,
    seconds: float,
    sample_rate: int,
    lead_silence_s: float,
    trail_silence_s: float,
) -> Utterance:
    """Phrases of pseudo-words filling about ``seconds`` of audio, with leading and trailing silence."""
    sil = inv.index(SILENCE)
    rows: list[
        tuple[int, int, float, int, int, float, float]
    ] = []  # phone, part, dur, word, phrase, acc, ldb
    words: list[str] = []
    rows.append((sil, 0, lead_silence_s, -1, -1, 0.0, 0.0))
    t = lead_silence_s
    target_end = max(seconds - trail_silence_s, t + 0.5)
    phrase = 0
    knots_t: list[float] = [0.0]
    knots_st: list[float] = [0.0]
    while t < target_end - 0.3:
        n_words = int(rng.integers(3, 10))
        phrase_db = float(rng.normal(0.0, 3.0))
        phrase_st = float(rng.normal(0.0, 1.0))
        phrase_start = t
        vowel_marks: list[tuple[float, float, float]] = []  # (centre s, accent, duration)
        for w in range(n_words):
            if w > 0 and t >= target_end:
                break  # the take is long enough: end the phrase here
            n_syll = int(rng.choice((1, 1, 2, 2, 3)))
            syllables = [_syllable(rng, inv) for _ in range(n_syll)]
            stressed = int(rng.integers(n_syll))
            accent = 0.0 if rng.random() < 0.55 else float(rng.uniform(0.35, 1.0))
            word_index = len(words)
            words.append("".join(s for syl in syllables for s in syl))
            last_word = w == n_words - 1 or t >= target_end - 0.4
            for si, syl in enumerate(syllables):
                for sym in syl:
                    ph = inv.phone(sym)
                    # Lognormal spread per token; phrase-final syllables lengthen; stress lengthens vowels.
                    dur = ph.duration_s / speaker.rate * float(np.exp(rng.normal(0.0, 0.18)))
                    acc = accent if (si == stressed and ph.is_vowel) else 0.0
                    if ph.is_vowel:
                        dur *= 1.0 + 0.35 * acc + (0.15 if si == stressed else -0.1)
                    if last_word and si == n_syll - 1:
                        dur *= 1.4
                    ldb = phrase_db + 6.0 * acc + float(rng.normal(0.0, 1.0))
                    ldb -= 3.0 * (t - phrase_start) / 3.0  # loudness declines over a phrase
                    if ph.kind == "diphthong":
                        half = max(dur / 2, MIN_SEGMENT_S)
                        rows.append((inv.index(sym), 0, half, word_index, phrase, acc, ldb))
                        rows.append((inv.index(sym), 1, half, word_index, phrase, acc, ldb))
                        dur = 2 * half
                    else:
                        dur = max(dur, MIN_SEGMENT_S)
                        rows.append((inv.index(sym), 0, dur, word_index, phrase, acc, ldb))
                    if ph.is_vowel:
                        vowel_marks.append((t + dur / 2, acc, dur))
                    t += dur
        # F0: declination over the phrase, an accent peak on every accented vowel, a final fall.
        span = max(t - phrase_start, 0.2)
        knots_t.append(phrase_start)
        knots_st.append(phrase_st + 1.0)
        for centre, acc, dur in vowel_marks:
            decl = phrase_st + 1.0 - 3.5 * (centre - phrase_start) / span
            knots_t.extend([centre - dur / 2, centre, centre + dur / 2])
            bump = acc * speaker.f0_range_st
            knots_st.extend([decl + 0.3 * bump, decl + bump, decl + 0.4 * bump])
        knots_t.append(t)
        knots_st.append(phrase_st - 3.5)
        phrase += 1
        pause = float(rng.uniform(0.15, 0.6))
        if t + pause >= target_end:
            break
        rows.append((sil, 0, pause, -1, -1, 0.0, 0.0))
        t += pause
    rows.append((sil, 0, trail_silence_s, -1, -1, 0.0, 0.0))
    knots_t.append(t + trail_silence_s + 1.0)
    knots_st.append(knots_st[-1])

    dur = np.array([r[2] for r in rows])
    edges = np.concatenate([[0], np.cumsum(np.rint(dur * sample_rate).astype(np.int64))])
    kt = np.asarray(knots_t)
    order = np.argsort(kt, kind="stable")
    utt = Utterance(
        inventory=inv,
        sample_rate=sample_rate,
        phone=np.array([r[0] for r in rows], dtype=np.int64),
        part=np.array([r[1] for r in rows], dtype=np.int64),
        start=edges[:-1],
        end=edges[1:],
        word=np.array([r[3] for r in rows], dtype=np.int64),
        phrase=np.array([r[4] for r in rows], dtype=np.int64),
        accent=np.array([r[5] for r in rows]),
        loud_db=np.array([r[6] for r in rows]),
        jaw_gain=np.ones(len(rows)),
        words=words,
        f0_knots_s=kt[order],
        f0_knots_st=np.asarray(knots_st)[order],
    )
    utt.jaw_gain = jaw_gain(utt, speaker)
    return utt


def jaw_gain(utt: Utterance, speaker: Speaker) -> np.ndarray:
    """Multiplier on each vowel's jaw opening: wider when louder (per dB) and higher (per semitone)."""
    centre_s = (utt.start + utt.end) / 2 / utt.sample_rate
    pitch = utt.f0_st(centre_s)
    gain = np.exp(speaker.jaw_energy_coupling * utt.loud_db + speaker.jaw_pitch_coupling * pitch)
    is_vowel = np.array([utt.inventory.phones[p].is_vowel for p in utt.phone])
    return np.where(is_vowel, np.clip(gain, 0.5, 2.2), 1.0)
