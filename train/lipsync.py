"""Where lip sync fails, by phone: errors per articulatory class of the frame's phone, and whether a
model closes the lips on bilabials.

A dataset built with a PPG that knows phones (``s2a-dataset build --ppg pocketsphinx|bottleneck``)
stores each frame's phone (``phones.npy``: ids into the manifest's ``features.ppg.phones``, -1 unknown).
Each phone name is read as ``dataset.phones.phone_index`` reads aligners' labels (stress digits, case,
TIMIT and IPA spellings folded onto ARPAbet) and falls in one class of ``PHONE_CLASSES``; a name outside
ARPAbet, and an unknown phone, is counted as unclassified.

Lip aperture (``lip_aperture``), from ARKit's blendshape semantics: ``jawOpen`` lowers the jaw and the
lower lip with it; ``mouthClose`` brings the lips together against the open jaw (lips touch when it
equals jawOpen); ``mouthUpperUp`` and ``mouthLowerDown`` (left and right) raise the upper lip and lower
the lower lip apart with the jaw still. Aperture = max(0, jawOpen - mouthClose) + ½ (mean mouthUpperUp +
mean mouthLowerDown), the lip term when the rig has all four lip channels, each weight clipped to 0..1
first (as a rig shows a model's); 0 is closed lips. On the real Live Link Face take with its audio
(NeuroSync test set, phones by pocketsphinx phone recognition), 12 of its 13 bilabial segments reach an
aperture under 0.05 on the take's own frames (10 of 12 through a dataset's 60 fps frames and eval),
against 34 % of its other speech segments; the lip term matters there: jawOpen - mouthClose alone is
under 0.05 in 72 % of the other segments (that speaker barely opens the jaw).

Bilabial closure: a segment is a run of consecutive frames whose phone is bilabial, widened by
``MARGIN_S`` on each side (the PPG's 20 ms grid: closure and acoustic boundary need not meet on one
frame); its minimum aperture over the usable frames is compared. The recorded take closes the lips
there when its minimum is at most ``CLOSED``; the prediction closes them as the take does when its
minimum is at most the recorded one plus ``TOLERANCE``. The hit rate is over the recorded closures;
segments without a usable frame, and those where the recorded take does not close, are counted apart.
A face that never opens keeps every closure, so the counterpart is scored too:

Open-vowel opening: a segment is a run of open-vowel frames (AA AE AO AW AY), widened alike; the
recorded take opens there when its maximum aperture is at least ``OPENED``, and the prediction opens as
the take does when its own maximum reaches ``OPENED`` too. The hit rate is over the recorded openings.
On the real NeuroSync take 17 of its 20 open-vowel segments open that far, against 6 of its 12
bilabial segments. No face that never moves scores on both: a constant aperture keeps a closure only
at or under ``CLOSED + TOLERANCE`` (0.10), below ``OPENED`` (0.15): the lips shut throughout keep every
closure and no opening, and the train-mean floor scores on one figure at most.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from capture.runs import runs
from dataset.phones import ARPABET, phone_index

# (class, ARPAbet phones, why it matters for the face); every ARPAbet phone is in exactly one class
PHONE_CLASSES: tuple[tuple[str, tuple[str, ...], str], ...] = (
    ("bilabial", ("P", "B", "M"), "the lips close: a missed closure is the most noticed lip-sync error"),
    ("labiodental", ("F", "V"), "the lower lip touches the upper teeth"),
    ("rounded", ("UW", "OW", "W"), "the lips round and protrude"),
    ("open_vowel", ("AA", "AE", "AO", "AW", "AY"), "the jaw opens widest (AW and AY start open)"),
    (
        "other_vowel",
        ("AH", "EH", "ER", "EY", "IH", "IY", "OY", "UH"),
        "a mid or close jaw (AH is also the reduced schwa)",
    ),
    (
        "other_consonant",
        ("CH", "D", "DH", "G", "HH", "JH", "K", "L", "N", "NG", "R", "S", "SH", "T", "TH", "Y", "Z", "ZH"),
        "made with the tongue or throat: the lips follow their neighbours",
    ),
    ("silence", ("SIL",), "the mouth at rest or in a pause"),
)
CLASS_NAMES = tuple(name for name, _, _ in PHONE_CLASSES)
BILABIAL = CLASS_NAMES.index("bilabial")
OPEN_VOWEL = CLASS_NAMES.index("open_vowel")

CLOSED = 0.05  # aperture at or under which the lips are closed (blendshape units)
TOLERANCE = 0.05  # how far above the recorded minimum a predicted minimum may be and still close
OPENED = 0.15  # aperture at or over which the lips are open (above CLOSED + TOLERANCE: see module doc)
MARGIN_S = 0.02  # a bilabial or open-vowel segment widened by this much on each side

JAW = ("jawopen", "mouthclose")  # also the crucial channels of evaluate
LIPS = ("mouthupperupleft", "mouthupperupright", "mouthlowerdownleft", "mouthlowerdownright")
APERTURE = (
    "max(0, jawOpen - mouthClose) + 0.5 * (mean mouthUpperUp L/R + mean mouthLowerDown L/R), the lip "
    "term when the rig has all four"
)


def phone_classes(phones: list[str]) -> np.ndarray:
    """Class index (in ``PHONE_CLASSES``) of each phone name, -1 for a name outside ARPAbet."""
    class_of = {p: k for k, (_, members, _) in enumerate(PHONE_CLASSES) for p in members}
    out = []
    for name in phones:
        index = phone_index(str(name))
        out.append(-1 if index is None else class_of[ARPABET[index]])
    return np.asarray(out, np.int64)


def aperture_columns(channels: list[str]) -> tuple[list[int], list[int]] | None:
    """Columns of (jawOpen, mouthClose) and of the four lip channels (empty when the rig lacks any), or
    None when the rig lacks jawOpen or mouthClose."""
    lowered = [c.lower() for c in channels]
    if not all(c in lowered for c in JAW):
        return None
    lips = [lowered.index(c) for c in LIPS] if all(c in lowered for c in LIPS) else []
    return [lowered.index(c) for c in JAW], lips


def lip_aperture(x: np.ndarray, columns: tuple[list[int], list[int]]) -> np.ndarray:
    """Per-frame lip aperture (module doc) of blendshape values ``x`` (frames, channels)."""
    jaw, lips = columns
    # only the columns read, clipped: a weight outside 0..1 (a model's) is as a rig shows it
    x = np.clip(np.asarray(x, np.float64)[:, [*jaw, *lips]], 0.0, 1.0)
    aperture = np.maximum(x[:, 0] - x[:, 1], 0.0)
    if lips:
        aperture = aperture + 0.5 * (x[:, 2:4].mean(1) + x[:, 4:6].mean(1))
    return aperture


class SegmentHits:
    """One segment figure (bilabial closure or open-vowel opening): segments seen, those without a
    usable frame, those where the recorded take reaches the figure's aperture, and how many of these the
    model and the floor reach too."""

    def __init__(self):
        self.segments = self.unscored = self.recorded = 0
        self.hits = {"model": 0, "floor": 0}

    def summary(self, recorded: str) -> dict[str, Any]:
        """Counts and hit rates, the recorded segments under the name ``recorded``."""

        def rate(hits: int) -> dict[str, Any]:
            return {"hits": hits, "hit_rate": hits / self.recorded if self.recorded else None}

        return {
            "segments": self.segments,
            "unscored_segments": self.unscored,  # no usable frame
            recorded: self.recorded,
            "model": rate(self.hits["model"]),
            "floor": rate(self.hits["floor"]),
        }


class LipSyncTally:
    """Squared errors per phone class, bilabial closures and open-vowel openings of a model's predictions
    and of the floor's, utterance by utterance (paper scale for the errors: values × 100)."""

    def __init__(self, channels: list[str], phones: list[str], fps: float):
        self.class_of = phone_classes(phones)
        self.columns = aperture_columns(channels)
        self.margin = int(round(MARGIN_S * fps))
        self.channels = len(channels)
        self.se = {"model": np.zeros(len(PHONE_CLASSES)), "floor": np.zeros(len(PHONE_CLASSES))}
        self.frames = np.zeros(len(PHONE_CLASSES), np.int64)
        self.unclassified = 0
        self.closure, self.opening = SegmentHits(), SegmentHits()

    def add(self, phone_ids: np.ndarray, pred: np.ndarray, floor: np.ndarray, true: np.ndarray, mask):
        """One utterance: ``phone_ids`` (frames,), de-normalised ``pred``, ``floor``, ``true`` (frames,
        channels) and ``mask`` (frames,) usable frames, as ``ErrorTally.add`` scores them."""
        ids = np.asarray(phone_ids, np.int64)
        known = (ids >= 0) & (ids < self.class_of.size)
        cls = np.full(ids.shape, -1, np.int64)
        cls[known] = self.class_of[ids[known]]
        true = np.asarray(true, np.float64)
        classified = mask & (cls >= 0)  # the usable frames of a phone in some class
        for who, x in (("model", pred), ("floor", floor)):
            se = (((np.asarray(x, np.float64) - true) * 100.0) ** 2).sum(1)
            self.se[who] += np.bincount(cls[classified], se[classified], len(PHONE_CLASSES))
        self.frames += np.bincount(cls[classified], minlength=len(PHONE_CLASSES))
        self.unclassified += int((mask & (cls < 0)).sum())
        if self.columns is not None:
            self._segments(cls, pred, floor, true, mask)

    def _segments(self, cls: np.ndarray, pred, floor, true, mask) -> None:
        """Bilabial closures and open-vowel openings (module doc) of one utterance."""
        recorded = lip_aperture(true, self.columns)
        apertures = {who: lip_aperture(x, self.columns) for who, x in (("model", pred), ("floor", floor))}
        for usable in self._usable_frames(cls == BILABIAL, mask, self.closure):
            lowest = recorded[usable].min()
            if lowest <= CLOSED:
                self.closure.recorded += 1
                for who, aperture in apertures.items():
                    self.closure.hits[who] += bool(aperture[usable].min() <= lowest + TOLERANCE)
        for usable in self._usable_frames(cls == OPEN_VOWEL, mask, self.opening):
            if recorded[usable].max() >= OPENED:
                self.opening.recorded += 1
                for who, aperture in apertures.items():
                    self.opening.hits[who] += bool(aperture[usable].max() >= OPENED)

    def _usable_frames(self, flags: np.ndarray, mask: np.ndarray, figure: SegmentHits):
        """The usable frames (indices) of each run of ``flags`` widened by the margin, counted in
        ``figure``; a run without a usable frame is counted unscored and not given."""
        for start, end in runs(flags):
            figure.segments += 1
            first = max(start - self.margin, 0)
            usable = first + np.flatnonzero(mask[first : end + self.margin])
            if usable.size:
                yield usable
            else:
                figure.unscored += 1

    def per_phone_class(self) -> dict[str, Any]:
        """RMSE × 100 over every scored channel per class of the frame's phone, pooled over the usable
        frames of the class; the floor's alike."""

        def rmse(se: float, n: int) -> float | None:
            return float(np.sqrt(se / (n * self.channels))) if n else None

        return {
            "classes": {
                name: {
                    "frames": int(self.frames[k]),
                    "rmse": rmse(self.se["model"][k], self.frames[k]),
                    "floor": rmse(self.se["floor"][k], self.frames[k]),
                    "phones": list(members),
                }
                for k, (name, members, _) in enumerate(PHONE_CLASSES)
            },
            "unclassified_frames": self.unclassified,
        }

    def _aperture_formula(self) -> str:
        """``APERTURE`` as this rig reads it: without the lip term when it lacks a lip channel."""
        return APERTURE if self.columns[1] else APERTURE.split(" + ")[0]

    def bilabial_closure(self) -> dict[str, Any] | None:
        """Hit rates of bilabial closures (module doc), None when the rig lacks jawOpen or mouthClose."""
        if self.columns is None:
            return None
        return {
            **self.closure.summary("recorded_closures"),
            "aperture": self._aperture_formula(),
            "closed_at_most": CLOSED,
            "tolerance": TOLERANCE,
            "margin_frames": self.margin,
        }

    def open_vowel_opening(self) -> dict[str, Any] | None:
        """Hit rates of openings on open vowels (module doc), None when the rig lacks jawOpen or
        mouthClose."""
        if self.columns is None:
            return None
        return {
            **self.opening.summary("recorded_openings"),
            "aperture": self._aperture_formula(),
            "opened_at_least": OPENED,
            "margin_frames": self.margin,
        }
