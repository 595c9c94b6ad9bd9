"""Phone inventories of the simulated speaker: acoustics, durations and viseme targets per phone.

Two inventories: ``en`` (40 English-like phones, ARPAbet symbols) and ``es`` (23 Spanish-like phones,
a five-vowel system with a tap/trill contrast). Each phone carries what the voice needs (formants in Hz
for an adult male vocal tract, frication band, stop burst) and what the face needs: a viseme target and
a dominance (how strongly the phone imposes its target on each channel against its neighbours) over
the ``pronunciation32`` channels. Visemes follow articulatory phonetics: bilabials close and press the
lips, labiodentals roll the lower lip in, rounded vowels pucker and funnel, open vowels open the jaw,
spread vowels stretch and smile.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..channels import PRONUNCIATION32
from ..errors import InputError

SILENCE = "sil"

# Viseme targets are written with symmetric names; each expands to the Left/Right pair.
_PAIRS = {
    "smile": ("mouthSmileLeft", "mouthSmileRight"),
    "stretch": ("mouthStretchLeft", "mouthStretchRight"),
    "press": ("mouthPressLeft", "mouthPressRight"),
    "lowerDown": ("mouthLowerDownLeft", "mouthLowerDownRight"),
    "upperUp": ("mouthUpperUpLeft", "mouthUpperUpRight"),
    "frown": ("mouthFrownLeft", "mouthFrownRight"),
    "dimple": ("mouthDimpleLeft", "mouthDimpleRight"),
    "cheekSquint": ("cheekSquintLeft", "cheekSquintRight"),
    "noseSneer": ("noseSneerLeft", "noseSneerRight"),
}
# Channels the lips control: bilabials and labiodentals impose them strongly on their neighbours.
LIP_CHANNELS = (
    "mouthClose",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthFunnel",
    "mouthPucker",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
)
JAW_CHANNELS = ("jawOpen", "mouthLowerDownLeft", "mouthLowerDownRight")
ROUNDING_CHANNELS = ("mouthFunnel", "mouthPucker")

# Rest pose: lips together but not pressed, jaw almost closed (real takes idle near 0.02 jawOpen).
_REST = {"jawOpen": 0.02, "mouthClose": 0.01, "mouthShrugUpper": 0.02}


@dataclass(frozen=True)
class Phone:
    """One phone: its class, acoustics (Hz, seconds) and face target.

    ``kind`` is one of vowel, diphthong, stop, affricate, fricative, nasal, approximant, tap, silence.
    ``formants`` are (F1, F2, F3) of an adult male; a diphthong glides to ``formants2``/``viseme2``.
    ``frication`` is the (low, high) band of its noise in Hz, ``burst`` the centre of a stop's release.
    """

    symbol: str
    kind: str
    voiced: bool
    duration_s: float
    formants: tuple[float, float, float] = (500.0, 1500.0, 2500.0)
    viseme: dict[str, float] = field(default_factory=dict)
    dominance: dict[str, float] = field(default_factory=dict)
    formants2: tuple[float, float, float] | None = None
    viseme2: dict[str, float] | None = None
    frication: tuple[float, float] | None = None
    frication_level: float = 0.0
    burst: float | None = None
    intrinsic_db: float = 0.0  # vowel intrinsic intensity relative to a mid vowel
    place: str = ""

    @property
    def is_vowel(self) -> bool:
        return self.kind in ("vowel", "diphthong")


@dataclass(frozen=True)
class Inventory:
    """A language-like phone set plus the syllable shapes its pseudo-words are built from."""

    name: str
    description: str
    phones: tuple[Phone, ...]
    onsets: tuple[tuple[str, ...], ...]
    codas: tuple[tuple[str, ...], ...]
    coda_probability: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "_index", {p.symbol: i for i, p in enumerate(self.phones)})

    def index(self, symbol: str) -> int:
        return self._index[symbol]  # type: ignore[attr-defined]

    def phone(self, symbol: str) -> Phone:
        return self.phones[self.index(symbol)]

    @property
    def vowels(self) -> tuple[str, ...]:
        return tuple(p.symbol for p in self.phones if p.is_vowel)


def viseme_vector(target: dict[str, float]) -> np.ndarray:
    """A viseme written with symmetric names as a vector over ``PRONUNCIATION32`` (0..1 units)."""
    out = np.zeros(len(PRONUNCIATION32), dtype=np.float64)
    for name, value in {**_REST, **target}.items():
        for ch in _PAIRS.get(name, (name,)):
            out[PRONUNCIATION32.index(ch)] = value
    return out


def dominance_vector(phone: Phone) -> np.ndarray:
    """Per-channel dominance of a phone over ``PRONUNCIATION32`` (dimensionless, 1 = a vowel's)."""
    out = np.ones(len(PRONUNCIATION32), dtype=np.float64)
    for name, value in phone.dominance.items():
        if name == "*":
            out[:] = value
    for name, value in phone.dominance.items():
        if name == "*":
            continue
        group = {"lips": LIP_CHANNELS, "jaw": JAW_CHANNELS, "round": ROUNDING_CHANNELS}.get(name)
        for ch in group or _PAIRS.get(name, (name,)):
            out[PRONUNCIATION32.index(ch)] = value
    return out


def viseme_matrix(inv: Inventory) -> tuple[np.ndarray, np.ndarray]:
    """Targets and dominances of every phone: two arrays (phones x 32) in inventory order."""
    targets = np.stack([viseme_vector(p.viseme) for p in inv.phones])
    dominance = np.stack([dominance_vector(p) for p in inv.phones])
    return targets, dominance


# --- building blocks shared by both inventories -------------------------------------------------

_CONS_DOM = {"*": 0.25}  # consonants mostly inherit the face of their vowels


def _vowel(sym, f, vis, dur=0.09, db=0.0, f2=None, vis2=None, dom=None) -> Phone:
    dominance = {"round": 2.0} if vis.get("mouthPucker", 0) > 0.2 else {}
    dominance |= dom or {}
    kind = "diphthong" if f2 else "vowel"
    return Phone(sym, kind, True, dur, f, vis, dominance, f2, vis2, intrinsic_db=db)


def _bilabial(sym, kind, voiced, dur) -> Phone:
    vis = {"mouthClose": 0.22, "press": 0.06, "jawOpen": 0.04, "mouthRollLower": 0.03, "mouthRollUpper": 0.02}
    dom = {"*": 0.3, "lips": 8.0, "jaw": 2.0, "mouthClose": 10.0}
    if kind == "nasal":
        return Phone(sym, kind, voiced, dur, (250.0, 1100.0, 2300.0), vis, dom, place="bilabial")
    return Phone(sym, kind, voiced, dur, (300.0, 900.0, 2300.0), vis, dom, burst=900.0, place="bilabial")


def _stop(sym, voiced, place, dur) -> Phone:
    burst = {"alveolar": 4000.0, "velar": 2000.0, "dental": 3500.0}[place]
    jaw = {"alveolar": 0.07, "velar": 0.1, "dental": 0.08}[place]
    f = {
        "alveolar": (300.0, 1700.0, 2600.0),
        "velar": (300.0, 2000.0, 2400.0),
        "dental": (300.0, 1600.0, 2600.0),
    }
    return Phone(sym, "stop", voiced, dur, f[place], {"jawOpen": jaw}, _CONS_DOM, burst=burst, place=place)


def _fricative(sym, voiced, place, dur) -> Phone:
    band, level, vis, dom = {
        "labiodental": (
            (1500.0, 7000.0),
            0.10,
            {"mouthRollLower": 0.28, "upperUp": 0.12, "jawOpen": 0.05, "mouthClose": 0.04},
            {"*": 0.3, "lips": 6.0, "jaw": 1.5},
        ),
        "dental": ((1400.0, 7500.0), 0.08, {"jawOpen": 0.1, "lowerDown": 0.08}, {"*": 0.3, "jaw": 1.5}),
        "alveolar": ((4500.0, 8000.0), 0.45, {"jawOpen": 0.04, "stretch": 0.06}, {"*": 0.3, "jaw": 2.0}),
        "postalveolar": (
            (2300.0, 5500.0),
            0.4,
            {"jawOpen": 0.06, "mouthFunnel": 0.24, "mouthPucker": 0.2, "upperUp": 0.08},
            {"*": 0.3, "round": 3.0, "jaw": 1.5},
        ),
        "velar": ((1200.0, 3500.0), 0.18, {"jawOpen": 0.1}, _CONS_DOM),
        "glottal": ((400.0, 6000.0), 0.0, {}, {"*": 0.05}),
    }[place]
    return Phone(
        sym,
        "fricative",
        voiced,
        dur,
        (500.0, 1500.0, 2500.0),
        vis,
        dom,
        frication=band,
        frication_level=level,
        place=place,
    )


def _affricate(sym, voiced, dur) -> Phone:
    vis = {"jawOpen": 0.06, "mouthFunnel": 0.24, "mouthPucker": 0.2, "upperUp": 0.08}
    return Phone(
        sym,
        "affricate",
        voiced,
        dur,
        (300.0, 1800.0, 2500.0),
        vis,
        {"*": 0.3, "round": 3.0},
        frication=(2300.0, 5500.0),
        frication_level=0.4,
        burst=3000.0,
        place="postalveolar",
    )


def _nasal(sym, place, f2, dur) -> Phone:
    jaw = 0.05 if place == "alveolar" else 0.09
    return Phone(sym, "nasal", True, dur, (250.0, f2, 2500.0), {"jawOpen": jaw}, _CONS_DOM, place=place)


def _approximant(sym, f, vis, dom, dur, kind="approximant") -> Phone:
    return Phone(sym, kind, True, dur, f, vis, dom)


_SIL = Phone(SILENCE, "silence", False, 0.3, viseme={}, dominance={"*": 0.6})

# Vowel visemes (adult values, 0..1): jaw height from F1, lip rounding from the vowel's roundedness.
_OPEN = {"jawOpen": 0.36, "lowerDown": 0.26, "upperUp": 0.08, "mouthShrugUpper": 0.0}
_SPREAD_HI = {"jawOpen": 0.07, "smile": 0.26, "stretch": 0.14, "lowerDown": 0.05, "cheekSquint": 0.04}


def _english() -> Inventory:
    v = _vowel
    phones = (
        _SIL,
        v("iy", (270.0, 2290.0, 3010.0), _SPREAD_HI, 0.09, -1.5),
        v(
            "ih",
            (390.0, 1990.0, 2550.0),
            {"jawOpen": 0.12, "smile": 0.14, "stretch": 0.08, "lowerDown": 0.08},
            0.07,
            -1.0,
        ),
        v(
            "eh",
            (530.0, 1840.0, 2480.0),
            {"jawOpen": 0.2, "smile": 0.1, "stretch": 0.06, "lowerDown": 0.14},
            0.08,
        ),
        v(
            "ae",
            (660.0, 1720.0, 2410.0),
            {"jawOpen": 0.3, "smile": 0.1, "stretch": 0.1, "lowerDown": 0.22},
            0.1,
            1.0,
        ),
        v("aa", (730.0, 1090.0, 2440.0), _OPEN, 0.1, 1.5),
        v("ah", (640.0, 1190.0, 2390.0), {"jawOpen": 0.26, "lowerDown": 0.17, "upperUp": 0.05}, 0.07, 0.8),
        v(
            "ao",
            (570.0, 840.0, 2410.0),
            {"jawOpen": 0.28, "mouthFunnel": 0.22, "mouthPucker": 0.12, "lowerDown": 0.12},
            0.1,
            1.0,
        ),
        v(
            "uh",
            (440.0, 1020.0, 2240.0),
            {"jawOpen": 0.12, "mouthFunnel": 0.16, "mouthPucker": 0.16},
            0.07,
            -0.5,
        ),
        v(
            "uw",
            (300.0, 870.0, 2240.0),
            {"jawOpen": 0.06, "mouthPucker": 0.36, "mouthFunnel": 0.3},
            0.09,
            -1.5,
        ),
        v("er", (490.0, 1350.0, 1690.0), {"jawOpen": 0.14, "mouthFunnel": 0.16, "mouthPucker": 0.12}, 0.09),
        v("ax", (500.0, 1500.0, 2500.0), {"jawOpen": 0.14, "lowerDown": 0.06}, 0.05, -1.0, dom={"*": 0.4}),
        v(
            "ey",
            (480.0, 2090.0, 2690.0),
            {"jawOpen": 0.18, "smile": 0.12, "lowerDown": 0.12},
            0.12,
            0.0,
            (330.0, 2300.0, 2900.0),
            {"jawOpen": 0.09, "smile": 0.22, "stretch": 0.1},
        ),
        v(
            "ay",
            (730.0, 1090.0, 2440.0),
            _OPEN,
            0.14,
            1.2,
            (400.0, 2000.0, 2550.0),
            {"jawOpen": 0.12, "smile": 0.16, "stretch": 0.08},
        ),
        v(
            "ow",
            (500.0, 900.0, 2400.0),
            {"jawOpen": 0.2, "mouthFunnel": 0.26, "mouthPucker": 0.18},
            0.12,
            0.5,
            (350.0, 800.0, 2300.0),
            {"jawOpen": 0.08, "mouthPucker": 0.34, "mouthFunnel": 0.26},
        ),
        v(
            "aw",
            (730.0, 1090.0, 2440.0),
            _OPEN,
            0.15,
            1.2,
            (400.0, 900.0, 2300.0),
            {"jawOpen": 0.1, "mouthPucker": 0.3, "mouthFunnel": 0.24},
        ),
        v(
            "oy",
            (570.0, 840.0, 2410.0),
            {"jawOpen": 0.26, "mouthFunnel": 0.24, "mouthPucker": 0.2},
            0.15,
            0.8,
            (400.0, 1900.0, 2500.0),
            {"jawOpen": 0.1, "smile": 0.14},
        ),
        _bilabial("p", "stop", False, 0.085),
        _bilabial("b", "stop", True, 0.07),
        _stop("t", False, "alveolar", 0.075),
        _stop("d", True, "alveolar", 0.06),
        _stop("k", False, "velar", 0.08),
        _stop("g", True, "velar", 0.065),
        _fricative("f", False, "labiodental", 0.1),
        _fricative("v", True, "labiodental", 0.065),
        _fricative("th", False, "dental", 0.1),
        _fricative("dh", True, "dental", 0.045),
        _fricative("s", False, "alveolar", 0.11),
        _fricative("z", True, "alveolar", 0.08),
        _fricative("sh", False, "postalveolar", 0.11),
        _fricative("zh", True, "postalveolar", 0.08),
        _fricative("hh", False, "glottal", 0.065),
        _affricate("ch", False, 0.12),
        _affricate("jh", True, 0.1),
        _bilabial("m", "nasal", True, 0.075),
        _nasal("n", "alveolar", 1500.0, 0.06),
        _nasal("ng", "velar", 2000.0, 0.08),
        _approximant("l", (360.0, 1300.0, 2700.0), {"jawOpen": 0.1, "lowerDown": 0.05}, _CONS_DOM, 0.06),
        _approximant(
            "r",
            (420.0, 1300.0, 1600.0),
            {"jawOpen": 0.08, "mouthFunnel": 0.16, "mouthPucker": 0.14},
            {"*": 0.3, "round": 1.5},
            0.06,
        ),
        _approximant(
            "w",
            (300.0, 700.0, 2200.0),
            {"jawOpen": 0.05, "mouthPucker": 0.4, "mouthFunnel": 0.22},
            {"*": 0.3, "round": 4.0},
            0.06,
        ),
        _approximant(
            "y", (280.0, 2200.0, 2900.0), {"jawOpen": 0.06, "smile": 0.16, "stretch": 0.1}, {"*": 0.4}, 0.05
        ),
    )
    onsets = (
        ("p",),
        ("b",),
        ("t",),
        ("d",),
        ("k",),
        ("g",),
        ("f",),
        ("v",),
        ("th",),
        ("dh",),
        ("s",),
        ("z",),
        ("sh",),
        ("hh",),
        ("ch",),
        ("jh",),
        ("m",),
        ("n",),
        ("l",),
        ("r",),
        ("w",),
        ("y",),
        ("p", "l"),
        ("b", "r"),
        ("t", "r"),
        ("k", "l"),
        ("s", "t"),
        ("s", "p"),
        ("f", "r"),
        ("g", "r"),
        (),
    )
    codas = (
        ("t",),
        ("d",),
        ("k",),
        ("p",),
        ("s",),
        ("z",),
        ("n",),
        ("m",),
        ("ng",),
        ("l",),
        ("r",),
        ("th",),
        ("v",),
        ("sh",),
        ("zh",),
        ("n", "t"),
        ("s", "t"),
        ("n", "d"),
        ("l", "d"),
        ("m", "p"),
    )
    return Inventory("en", "English-like: 40 phones, ARPAbet symbols", phones, onsets, codas, 0.55)


def _spanish() -> Inventory:
    v = _vowel
    phones = (
        _SIL,
        v("a", (700.0, 1300.0, 2500.0), _OPEN, 0.085, 1.5),
        v(
            "e",
            (450.0, 1900.0, 2550.0),
            {"jawOpen": 0.17, "smile": 0.14, "stretch": 0.07, "lowerDown": 0.12},
            0.08,
        ),
        v("i", (290.0, 2250.0, 2950.0), _SPREAD_HI, 0.075, -1.5),
        v("o", (480.0, 900.0, 2450.0), {"jawOpen": 0.2, "mouthFunnel": 0.26, "mouthPucker": 0.2}, 0.08, 0.5),
        v(
            "u",
            (310.0, 800.0, 2300.0),
            {"jawOpen": 0.06, "mouthPucker": 0.36, "mouthFunnel": 0.3},
            0.075,
            -1.5,
        ),
        _bilabial("p", "stop", False, 0.075),
        _bilabial("b", "stop", True, 0.06),
        _stop("t", False, "dental", 0.07),
        _stop("d", True, "dental", 0.055),
        _stop("k", False, "velar", 0.075),
        _stop("g", True, "velar", 0.06),
        _fricative("f", False, "labiodental", 0.09),
        _fricative("s", False, "alveolar", 0.1),
        _fricative("x", False, "velar", 0.09),
        _affricate("ch", False, 0.11),
        _bilabial("m", "nasal", True, 0.07),
        _nasal("n", "alveolar", 1500.0, 0.06),
        _nasal("ny", "palatal", 2100.0, 0.08),
        _approximant("l", (360.0, 1400.0, 2700.0), {"jawOpen": 0.1}, _CONS_DOM, 0.06),
        _approximant("rr", (450.0, 1400.0, 2300.0), {"jawOpen": 0.12}, _CONS_DOM, 0.09, kind="tap"),
        _approximant("r", (450.0, 1400.0, 2300.0), {"jawOpen": 0.12}, _CONS_DOM, 0.03, kind="tap"),
        _approximant("y", (280.0, 2200.0, 2900.0), {"jawOpen": 0.06, "smile": 0.14}, {"*": 0.4}, 0.05),
        _approximant(
            "w",
            (300.0, 700.0, 2200.0),
            {"jawOpen": 0.05, "mouthPucker": 0.38, "mouthFunnel": 0.2},
            {"*": 0.3, "round": 4.0},
            0.05,
        ),
    )
    onsets = (
        ("p",),
        ("b",),
        ("t",),
        ("d",),
        ("k",),
        ("g",),
        ("f",),
        ("s",),
        ("x",),
        ("ch",),
        ("m",),
        ("n",),
        ("ny",),
        ("l",),
        ("rr",),
        ("r",),
        ("y",),
        ("p", "r"),
        ("t", "r"),
        ("b", "l"),
        ("k", "w"),
        (),
    )
    codas = (("n",), ("s",), ("r",), ("l",), ("d",))
    return Inventory("es", "Spanish-like: 23 phones, five vowels, tap and trill", phones, onsets, codas, 0.3)


INVENTORIES: dict[str, Inventory] = {"en": _english(), "es": _spanish()}


def inventory(language: str) -> Inventory:
    """The phone inventory of a language code (``en``, ``es``); raises ``InputError`` otherwise."""
    try:
        return INVENTORIES[language.strip().lower()]
    except KeyError:
        known = ", ".join(sorted(INVENTORIES))
        raise InputError(f"unknown language {language!r} (simulated languages: {known})") from None
