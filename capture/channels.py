"""The Live Link Face / ARKit channel schema.

Channels are addressed by name, never by position: the Live Link UDP stream (engine order,
``EARFaceBlendShape``) and the app's CSV export order JawLeft/JawRight and MouthLeft/MouthRight
differently. Canonical names inside the toolkit are ARKit's camelCase (``jawOpen``); the CSV and Unreal
use PascalCase (``JawOpen``). Lookup is case-insensitive, so both spellings resolve to one channel.
"""

from __future__ import annotations

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

_INDEX = {n.lower(): i for i, n in enumerate(LIVELINK_ORDER)}


def is_known(name: str) -> bool:
    """Whether ``name`` (any case) is one of the 61 Live Link channels."""
    return name.strip().lower() in _INDEX


def udp_index(name: str) -> int:
    """Index of a channel in the UDP packet / engine enum, from any spelling of its name."""
    try:
        return _INDEX[name.strip().lower()]
    except KeyError:
        raise InputError(f"unknown Live Link channel {name!r}") from None


def canonical(name: str) -> str:
    """Canonical (ARKit camelCase) name of a Live Link channel, from any spelling."""
    return ARKIT61[udp_index(name)]


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
