"""The Live Link Face / ARKit channel schema.

Channels are addressed by name, never by position: the Live Link UDP stream (engine order,
``EARFaceBlendShape``) and the app's CSV export order JawLeft/JawRight and MouthLeft/MouthRight
differently. Canonical names inside the toolkit are ARKit's camelCase (``jawOpen``); the CSV and Unreal
use PascalCase (``JawOpen``). Lookup is case-insensitive, so both spellings resolve to one channel, and
it accepts the spellings other tools write (listed at ``_spellings``): snake_case (``jaw_open``,
``mouth_smile_left``), a side written ``_L``/``_R`` or ``_Left``/``_Right`` (``eyeBlink_L``, ARKit's own
raw names; ``MouthSmile_L``, ``Eye_Blink_L``), and a namespace or path before the name (``Maya:jawOpen``,
``/World/Face/jawOpen``, ``blendShapes.jawOpen``).
"""

from __future__ import annotations

import difflib
import re

from .errors import InputError

# The 61 channels in Live Link UDP / Unreal engine order (EARFaceBlendShape), PascalCase as in the CSV.
LIVELINK_ORDER: tuple[str, ...] = (
    "EyeBlinkLeft",
    "EyeLookDownLeft",
    "EyeLookInLeft",
    "EyeLookOutLeft",
    "EyeLookUpLeft",
    "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight",
    "EyeLookDownRight",
    "EyeLookInRight",
    "EyeLookOutRight",
    "EyeLookUpRight",
    "EyeSquintRight",
    "EyeWideRight",
    "JawForward",
    "JawLeft",
    "JawRight",
    "JawOpen",
    "MouthClose",
    "MouthFunnel",
    "MouthPucker",
    "MouthLeft",
    "MouthRight",
    "MouthSmileLeft",
    "MouthSmileRight",
    "MouthFrownLeft",
    "MouthFrownRight",
    "MouthDimpleLeft",
    "MouthDimpleRight",
    "MouthStretchLeft",
    "MouthStretchRight",
    "MouthRollLower",
    "MouthRollUpper",
    "MouthShrugLower",
    "MouthShrugUpper",
    "MouthPressLeft",
    "MouthPressRight",
    "MouthLowerDownLeft",
    "MouthLowerDownRight",
    "MouthUpperUpLeft",
    "MouthUpperUpRight",
    "BrowDownLeft",
    "BrowDownRight",
    "BrowInnerUp",
    "BrowOuterUpLeft",
    "BrowOuterUpRight",
    "CheekPuff",
    "CheekSquintLeft",
    "CheekSquintRight",
    "NoseSneerLeft",
    "NoseSneerRight",
    "TongueOut",
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
)


def _csv_order() -> tuple[str, ...]:
    # The app's CSV swaps the two Left/Right pairs relative to the engine enum (formats doc §1).
    order = list(LIVELINK_ORDER)
    for a, b in (("JawLeft", "JawRight"), ("MouthLeft", "MouthRight")):
        i, j = order.index(a), order.index(b)
        order[i], order[j] = order[j], order[i]
    return tuple(order)


CSV_ORDER: tuple[str, ...] = _csv_order()


def arkit_name(pascal: str) -> str:
    """ARKit camelCase name of a Live Link PascalCase name (``JawOpen`` → ``jawOpen``)."""
    return pascal[0].lower() + pascal[1:]


def livelink_name(name: str) -> str:
    """Live Link PascalCase name of a channel given in any known spelling."""
    return LIVELINK_ORDER[udp_index(name)]


# Canonical toolkit names, in engine order.
ARKIT61: tuple[str, ...] = tuple(arkit_name(n) for n in LIVELINK_ORDER)
ARKIT52: tuple[str, ...] = ARKIT61[:52]
ROTATIONS: tuple[str, ...] = ARKIT61[52:]

_EYE = tuple(n for n in ARKIT52 if n.startswith("eye"))
_BROW = tuple(n for n in ARKIT52 if n.startswith("brow"))
PRONUNCIATION32: tuple[str, ...] = tuple(
    n for n in ARKIT52 if n not in _EYE and n not in _BROW and n != "tongueOut"
)

CHANNEL_SETS: dict[str, tuple[str, ...]] = {
    "arkit52": ARKIT52,
    "arkit61": ARKIT61,
    "pronunciation32": PRONUNCIATION32,
}

# Spellings of the Live Link channels other tools write, besides ARKit's and Live Link's own, compared
# ignoring case except where said:
# - snake_case, one ARKit word between underscores: ``jaw_open``, ``mouth_smile_left``, ``left_eye_yaw``;
# - the side of a left/right channel as ``_Left``/``_Right`` after the rest in camelCase or snake_case
#   (``mouthSmile_Left``, ``Eye_Blink_Right``), or as ``_L``/``_R`` (``eyeBlink_L``, ARKit's own raw names;
#   ``MouthSmile_L``, ``Eye_Blink_L``, ``jaw_L``) when the name is not all lower case: all lower case, a
#   one-letter side (``mouth_press_l``) is how rigs name their own controls, and FACEGOOD's
#   ``mouth_dimple_l`` and ``mouth_press_l`` would have become ``mouthDimpleLeft`` and ``mouthPressLeft``;
# - a namespace, path or dotted prefix before any of these: ``Maya:jawOpen``, ``/World/Face/jawOpen``,
#   ``Face|jawOpen``, ``blendShapes.jawOpen``.
# No spelling names two channels (checked when the tables are built).
_PREFIX = re.compile(r"^.*[.:/|\\]")


def _spellings() -> tuple[dict[str, int], dict[str, int]]:
    """Lower-case spellings -> engine index: those accepted in any case, and those with a one-letter
    side (``eyeBlink_L``), accepted when the name is not all lower case."""
    any_case: dict[str, int] = {}
    not_lower: dict[str, int] = {}

    def add(table: dict[str, int], key: str, index: int) -> None:
        if table.setdefault(key, index) != index or any_case.get(key, index) != index:
            raise RuntimeError(f"channel spelling {key!r} would name two channels")

    for i, pascal in enumerate(LIVELINK_ORDER):
        words = [w.lower() for w in re.findall(r"[A-Z][a-z]*", pascal)]
        add(any_case, "".join(words), i)
        add(any_case, "_".join(words), i)
        if len(words) > 1 and words[-1] in ("left", "right"):
            side = words[-1]
            for base in ("".join(words[:-1]), "_".join(words[:-1])):
                add(any_case, f"{base}_{side}", i)
                add(not_lower, f"{base}_{side[0]}", i)
    if set(not_lower) & set(any_case):
        raise RuntimeError("a one-letter side spelling is also another spelling")
    return any_case, not_lower


_INDEX, _ONE_LETTER_SIDE = _spellings()


def _lookup(name: str) -> int | None:
    """Engine index of ``name`` in any spelling the module accepts, or None."""
    bare = _PREFIX.sub("", name.strip()).strip()
    key = bare.lower()
    index = _INDEX.get(key)
    if index is None and key != bare:  # not all lower case
        index = _ONE_LETTER_SIDE.get(key)
    return index


def is_known(name: str) -> bool:
    """Whether ``name`` is one of the 61 Live Link channels, in any case and in the spellings other tools
    write (``jaw_open``, ``eyeBlink_L``, ``Maya:jawOpen``; see ``_spellings``)."""
    return _lookup(name) is not None


def udp_index(name: str) -> int:
    """Index of a channel in the UDP packet / engine enum, from any spelling of its name."""
    index = _lookup(name)
    if index is None:
        raise InputError(f"unknown Live Link channel {name!r}")
    return index


def canonical(name: str) -> str:
    """Canonical (ARKit camelCase) name of a Live Link channel, from any spelling."""
    return ARKIT61[udp_index(name)]


def _folded(name: str) -> str:
    return _PREFIX.sub("", name.strip()).replace("_", "").lower()


def meant_channel(name: str, missing: list[str] | tuple[str, ...]) -> str | None:
    """Of the channels ``missing`` (Live Link names), the one a name that is no channel was perhaps meant to
    be (a typo in a header: ``JawOpne``, ``MouthSmileLetf``), or None. Only a suggestion: a rig's own
    control keeps its name, so a close name is never taken for the channel."""
    folded = {_folded(m): m for m in missing}
    close = difflib.get_close_matches(_folded(name), list(folded), n=1, cutoff=0.8)
    return folded[close[0]] if close else None


# Columns other tools write beside the ARKit channels that are no face channel: MediaPipe FaceLandmarker's
# score of a neutral face (its category 0, ``_neutral``), and the emotion weights of emotion-driven
# generators, each writing its whole set of emotions (Audio2Face-3D's 10 in a2e_emotion_output.csv,
# NeuroSync's 7 after its 61 channels), compared in lower case, letters and digits only, of a name's last
# dotted part (``emotion_values.joy``).
NEUTRAL_SCORE = "_neutral"
AUDIO2FACE_EMOTIONS = (
    "amazement", "anger", "cheekiness", "disgust", "fear", "grief", "joy", "outofbreath", "pain", "sadness",
)  # fmt: skip
NEUROSYNC_EMOTIONS = ("angry", "disgusted", "fearful", "happy", "neutral", "sad", "surprised")
EMOTION_NAMES = AUDIO2FACE_EMOTIONS + NEUROSYNC_EMOTIONS
NEUTRAL_FACE, EMOTION_WEIGHTS = "MediaPipe's neutral-face score", "emotion weights"


def column_key(name: str) -> str:
    """A header name as time, frame and emotion columns are looked up: lower case, letters and digits only."""
    return re.sub(r"[^0-9a-z]", "", name.lower())


def _emotion(name: str) -> str:
    """A column name as emotion names are compared: ``column_key`` of its last dotted part."""
    return column_key(re.split(r"[.:/]", name)[-1])


def side_score(name: str) -> str | None:
    """What a column beside the face channels holds when it is no face channel (``_neutral``: "MediaPipe's
    neutral-face score"; ``Happy``: "emotion weights"), or None."""
    if name.strip() == NEUTRAL_SCORE:
        return NEUTRAL_FACE
    if _emotion(name) in EMOTION_NAMES:
        return EMOTION_WEIGHTS
    return None


def side_scores(names: list[str] | tuple[str, ...]) -> tuple[list[int], str | None]:
    """The columns of ``names`` that ``side_score`` says are no face channel, when the layout is ARKit's
    (Live Link channels outnumber the other names beside them: a rig's own control named ``happy`` is
    kept), and the note saying they were left out (None when none is). Emotion names are left out only
    when they hold a generator's whole set: a few of them beside ARKit's are an avatar's own expressions
    (VRM's ``Joy``, ``Angry``, ``Sorrow``, ``Fun``), kept."""
    found = [(j, n, side_score(n)) for j, n in enumerate(names)]
    found = [f for f in found if f[2] is not None]
    emotions = {_emotion(n) for _, n, what in found if what == EMOTION_WEIGHTS}
    if not any(emotions.issuperset(whole) for whole in (AUDIO2FACE_EMOTIONS, NEUROSYNC_EMOTIONS)):
        found = [f for f in found if f[2] != EMOTION_WEIGHTS]
    known = sum(map(is_known, names))
    if not found or known <= len(names) - len(found) - known:
        return [], None
    kinds: dict[str, list[str]] = {}
    for _, n, what in found:
        kinds.setdefault(what, []).append(repr(n))
    said = "; ".join(f"{', '.join(shown)} ({what})" for what, shown in kinds.items())
    return [j for j, _, _ in found], f"columns left out, no face channels: {said}"


def channel_set(spec: str) -> tuple[str, ...]:
    """Channels named by a set name (``arkit52``, ``arkit61``, ``pronunciation32``) or a comma list."""
    key = spec.strip().lower()
    if key in CHANNEL_SETS:
        return CHANNEL_SETS[key]
    names = [s for s in (p.strip() for p in spec.split(",")) if s]
    if not names:
        raise InputError(f"empty channel selection {spec!r}")
    known = ", ".join(CHANNEL_SETS)
    for n in names:
        if not is_known(n):
            raise InputError(f"unknown channel or channel set {n!r} (sets: {known})")
    return tuple(canonical(n) for n in names)


def swap_left_right(names: tuple[str, ...] | list[str]) -> list[str]:
    """Names with the JawLeft/JawRight and MouthLeft/MouthRight labels exchanged.

    Some app builds are reported to export these pairs inverted (formats doc §1); this is the opt-in
    repair, applied to labels so that values stay where they were recorded.
    """
    swap = {
        "jawleft": "jawRight",
        "jawright": "jawLeft",
        "mouthleft": "mouthRight",
        "mouthright": "mouthLeft",
    }
    return [swap.get(n.lower(), n) for n in names]
