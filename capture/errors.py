"""Errors a user can cause. The command-line tools print them as one line and exit with code 1."""

from __future__ import annotations

import base64
import json
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

# Such a byte as the ``repr`` of a name shows it (argparse's ``invalid float value: 'x\\udcff'``, a message's
# ``{name!r}``): ``\\udc80`` to ``\\udcff`` written out, its backslash not itself escaped (``\\\\udcff``
# in a repr is a backslash and ``udcff``) nor the second half of a pair (``\\ud83d\\udc80``, an emoji
# escaped as JSON escapes it).
_REPR_OF_BYTE = re.compile(r"(?<!\\)((?:\\\\)*)(?<!\\ud[89ab][0-9a-f]{2})\\udc([89a-f][0-9a-f])")


def printable(text: str) -> str:
    """``text`` as a message shows it: the bytes of a file name that are not UTF-8 (held by Python as
    surrogate escapes, printed as ``\\udcff``) as ``\\xff``, as Python shows bytes (``caf\\xe9.mp3``).
    The text of a name written out (a JSON value, a result line, a page) is left as it is otherwise."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a surrogate no file name's bytes give
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def printable_message(text: str) -> str:
    """``printable(text)`` for a message on stderr, which may hold a name's ``repr`` (a usage error's
    value refused): such a byte in it (``'x\\udcff'``) shown as ``\\xff`` too. Not for a name's own text
    (a JSON value, a result line, a page), which may hold a backslash and ``udcff`` as they are."""
    shown = printable(text)
    return _REPR_OF_BYTE.sub(r"\1\\x\2", shown) if "\\udc" in shown else shown  # a warning per row: cheap


# Names in JSON for strict readers (``strict_names``). Python holds the bytes of a file name that are not
# UTF-8 as surrogate escapes, which ``json.dumps`` writes as ``"\udcff"``: a lone surrogate, which jq and
# JavaScript turn into U+FFFD (the name lost) and an encoder to UTF-8 refuses. Every string is written as
# messages show it (``printable``); a dict's string value that was not UTF-8 also keeps its bytes, in
# base64, under the same key with ``_b64`` added (``"audio_b64"``), for a consumer needing the path itself:
# ``os.fsdecode(base64.b64decode(record["csv_b64"]))``. A list of names one of which is not UTF-8 keeps
# them as a list beside it, null for each name that is UTF-8 (``"outputs_b64": [null, "Y2Fm6f8="]``). A dict
# whose keys are names (a speaker's hours) keeps the bytes of each key not UTF-8 beside it, by the key as
# shown: ``"hours_per_speaker_keys_b64": {"caf\\xe9": "Y2Fm6Q=="}``. In a dict holding a key of its own
# of that name (another tool's ``audio_b64``), the bytes are kept under it with a count added
# (``"audio_b64 (2)"``), one more than any of its own there (``_places``).
RAW_BYTES = "_b64"  # added to the key of a name that is not UTF-8: its bytes, base64
KEYS_RAW_BYTES = "_keys" + RAW_BYTES  # added to the key of a dict keyed by names: their bytes, base64


def strict_names(value: Any) -> Any:
    """``value`` (dicts, lists and scalars nested) with every string ``printable`` and, beside each dict
    value that is a name not UTF-8 or a list holding one, its bytes (``RAW_BYTES``), and beside each dict
    value that is a dict keyed by such names (or a list of such dicts), their bytes (``KEYS_RAW_BYTES``);
    other values as they are. A key not UTF-8 shown as another key of its dict is (``a\\xff``, the
    byte, beside the text ``a\\xff``) is shown with `` (2)`` added, so that neither is lost."""
    return _strict(value)[0]


def _strict(value: Any) -> tuple[Any, Any, Any]:
    """(``value`` as ``strict_names`` shows it, the bytes kept beside it in a dict under ``RAW_BYTES``,
    those under ``KEYS_RAW_BYTES``; None for each of the two it needs none): one walk of ``value``.
    Bytes beside a list are a list, null for each item that needs none; a dict's are its keys'."""
    if isinstance(value, str):
        if value.isascii():  # most text: nothing to show otherwise, no bytes to keep
            return value, None, None
        raw = _raw_bytes(value)
        return printable(value), None if raw is None else base64.b64encode(raw).decode("ascii"), None
    if isinstance(value, (list, tuple)):
        items = [_strict(v) for v in value]
        raw = [r for _, r, _ in items]
        keys = [k for _, _, k in items]
        shown = [v for v, _, _ in items]
        return shown, raw if any(r is not None for r in raw) else None, keys if any(keys) else None
    if not isinstance(value, dict):
        return value, None, None
    out: dict[Any, Any] = {}
    shown_keys = _shown_keys(value)
    places = None  # the places beside a key taken: by the dict's own keys ending in _b64, by bytes kept
    for key, v in value.items():
        name = shown_keys.get(key, key)
        out[name], raw, keys = _strict(v)
        for end, kept in ((RAW_BYTES, raw), (KEYS_RAW_BYTES, keys or None)):
            if kept is not None:
                places = _places(shown_keys.get(k, k) for k in value) if places is None else places
                place = f"{name}{end}"
                n = max(places.get(place, [(0, "")]))[0] + 1
                out[place if n == 1 else f"{place} ({n})"] = kept
                places.setdefault(place, []).append((n, ""))
    keys_raw = {
        shown_keys[k]: base64.b64encode(raw).decode("ascii")
        for k in value
        if isinstance(k, str) and not k.isascii() and (raw := _raw_bytes(k)) is not None
    }
    return out, None, keys_raw or None


def _shown_keys(value: dict) -> dict[str, str]:
    """``{key: as strict_names shows it}`` for each text key of ``value``: ``printable``, a key not UTF-8
    whose display another key already has then `` (2)``, `` (3)``... added (a UTF-8 key keeps its text)."""
    shown = {k: k if k.isascii() else printable(k) for k in value if isinstance(k, str)}
    odd = {k: None for k in shown if not k.isascii() and _raw_bytes(k) is not None}  # in order
    if not odd:
        return shown
    taken = {text for k, text in shown.items() if k not in odd}
    for key in odd:
        base = text = shown[key]
        n = 1
        while text in taken:
            n += 1
            text = f"{base} ({n})"
        shown[key] = text
        taken.add(text)
    return shown


def loads_names(text: str | bytes) -> Any:
    """``json.loads(text)``, each name not UTF-8 as Python holds it (``names_restored``; walked only when
    the text holds ``RAW_BYTES``: most does not). Errors as ``json.loads``'s."""
    value = json.loads(text)
    marker = RAW_BYTES if isinstance(text, str) else RAW_BYTES.encode()
    return names_restored(value) if marker in text else value


def names_restored(value: Any) -> Any:
    """What ``strict_names`` made of ``value``, read back from JSON: each name not UTF-8 as Python holds it
    (surrogate escapes, from its bytes beside it), the keys holding those bytes gone. A key ending in
    ``_b64`` whose value is not the bytes of the name beside it as ``strict_names`` keeps them (a speaker
    named ``anna_b64`` beside ``anna``, another tool's field, a hand-edited one) is a key of its own, kept
    as it is (the bytes then kept at a count, ``audio_b64 (2)``: ``_places``). JSON written before (a
    lone surrogate, ``"\\udcff"``, which Python reads back as the name) is returned as it is."""
    if isinstance(value, list):
        return [names_restored(v) for v in value]
    if not isinstance(value, dict):
        return value
    out = {key: names_restored(v) for key, v in value.items()}
    if not any(isinstance(key, str) and RAW_BYTES in key for key in value):
        return out
    places = _places(value)
    spent = set()  # the keys that held a name's bytes
    for key in value:
        for end, restore in ((RAW_BYTES, _bytes_named), (KEYS_RAW_BYTES, _keys_named)):
            for _, beside in sorted(places.get(f"{key}{end}", ()), reverse=True):  # the last kept first
                if beside not in spent and (named := restore(out[key], value[beside])) is not None:
                    out[key] = named
                    spent.add(beside)
                    break
    return {key: v for key, v in out.items() if key not in spent}


def _places(keys: Iterable[Any]) -> dict[str, list[tuple[int, str]]]:
    """The keys of a dict that may hold bytes kept beside another (``_b64`` in them), by the place beside
    that key they take (``audio_b64``) and their count there: ``audio_b64`` is the first,
    ``audio_b64 (3)`` the third. ``strict_names`` keeps the bytes at the first place, or, when the dict
    has keys of its own there (another tool's ``audio_b64``), at a count one more than theirs, so that a
    reader tries them first."""
    places: dict[str, list[tuple[int, str]]] = {}
    for key in keys:
        if isinstance(key, str) and RAW_BYTES in key:
            count = _COUNT_ADDED.search(key)
            place, n = (key[: count.start()], int(count.group(1))) if count else (key, 1)
            places.setdefault(place, []).append((n, key))
    return places


def _bytes_named(value: Any, raw: Any) -> Any:
    """A name (or list of names) from its text and its bytes as ``_strict`` kept them; None when ``raw``
    is not such bytes of ``value``."""
    if isinstance(value, str):
        return _name_shown_as(value, raw)
    if isinstance(value, list) and isinstance(raw, list) and len(raw) == len(value):
        return _each_named(value, raw, _bytes_named)
    return None


def _keys_named(value: Any, raw: Any) -> Any:
    """A dict (or list of dicts) keyed by names from its keys' text and their bytes as ``_strict`` kept
    them (a key shown with `` (2)`` added too); None when ``raw`` is not such bytes of its keys."""
    if isinstance(value, list) and isinstance(raw, list) and len(raw) == len(value):
        return _each_named(value, raw, _keys_named)
    if not isinstance(value, dict) or not isinstance(raw, dict) or not raw:
        return None
    names = {}
    for shown, each in raw.items():
        name = _name_shown_as(shown, each, _COUNT_ADDED.sub("", shown)) if shown in value else None
        if name is None:
            return None
        names[shown] = name
    return {names.get(key, key): v for key, v in value.items()}


# `` (2)``: added to a key shown as another key is, and to bytes kept at a place taken (``_places``); only
# the counts written (2 on, no leading zero): a key of its own ``audio_b64 (1)`` or ``(02)`` is no count
_COUNT_ADDED = re.compile(r" \(([2-9]|[1-9][0-9]+)\)$")


def _each_named(values: list, raws: list, restore) -> list | None:
    """``values`` each restored by its item of ``raws`` (null: as it is); None when one is not restored,
    or none has bytes."""
    named = [v if r is None else restore(v, r) for v, r in zip(values, raws)]
    ok = any(r is not None for r in raws) and all(n is not None for n, r in zip(named, raws) if r is not None)
    return named if ok else None


def _name_shown_as(text: str, raw: Any, or_shown: str | None = None) -> str | None:
    """The name not UTF-8 whose bytes are ``raw`` in base64, if ``text`` (or ``or_shown``) is that name as
    ``printable`` shows it; else None."""
    name = name_of(text, raw)
    return name if name != text and printable(name) in (text, or_shown) else None


def name_of(text: str, raw: Any) -> str:
    """A name from its text in JSON and its bytes in base64 (None when the text is the name): as Python
    holds it, ``os.fsdecode``. Bytes that are no base64 (a hand-edited file) leave the text."""
    if not isinstance(raw, str):
        return text
    try:
        return os.fsdecode(base64.b64decode(raw, validate=True))
    except ValueError:  # binascii.Error
        return text


def _raw_bytes(text: str) -> bytes | None:
    """The bytes of a name that is not UTF-8 (held as surrogate escapes); None for UTF-8 text, and for a
    surrogate no file name's bytes give."""
    try:
        text.encode("utf-8")
        return None
    except UnicodeEncodeError:
        pass
    try:
        return text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:
        return None


def shown_against(value: float, bound: float, places: int = 2) -> str:
    """``value`` with ``places`` decimals, or as many more as it takes to read on its side of ``bound``: a
    confidence of 0.2951 under a bound of 0.3 as ``0.295``, not ``0.30``; audio 0.9996 s long under 1 s as
    ``0.9996``. For a message naming a figure beside the bound it missed."""
    for digits in range(places, 17):
        shown = f"{value:.{digits}f}"
        if value == bound or (float(shown) - bound) * (value - bound) > 0:  # strictly on its side
            return shown
    return repr(value)


def first_few(names, most: int = 5) -> str:
    """The first ``most`` of ``names``, comma-separated, and how many more there are (``a, b and 3 more``)."""
    return ", ".join(names[:most]) + (f" and {len(names) - most} more" if len(names) > most else "")


class S2AError(Exception):
    """Base of every error the toolkit raises for bad input or a failed check."""


class InputError(S2AError):
    """Input that cannot be used: names the file (and line or field) and says what is wrong."""

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None):
        self.path = str(path) if path is not None else None
        self.line = line
        self.reason = message  # what is wrong, without the file: alike for many files of one batch
        where = ""
        if self.path is not None:
            where = printable(self.path) + (f":{line}" if line is not None else "") + ": "
        super().__init__(where + message)
