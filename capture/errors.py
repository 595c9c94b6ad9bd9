"""Errors a user can cause. The command-line tools print them as one line and exit with code 1."""

from __future__ import annotations

import base64
import json
import os
import re
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
# shown: ``"hours_per_speaker_keys_b64": {"caf\\xe9": "Y2Fm6Q=="}``.
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
        keys = [k or None for _, _, k in items]
        shown = [v for v, _, _ in items]
        return shown, raw if any(r is not None for r in raw) else None, keys if any(keys) else None
    if not isinstance(value, dict):
        return value, None, None
    out: dict[Any, Any] = {}
    shown_keys = _shown_keys(value)
    for key, v in value.items():
        name = shown_keys.get(key, key)
        out[name], raw, keys = _strict(v)
        if raw is not None:
            out[f"{name}{RAW_BYTES}"] = raw
        if keys:
            out[f"{name}{KEYS_RAW_BYTES}"] = keys
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
    return names_restored(value) if (RAW_BYTES if isinstance(text, str) else b"_b64") in text else value


def names_restored(value: Any) -> Any:
    """What ``strict_names`` made of ``value``, read back from JSON: each name not UTF-8 as Python holds it
    (surrogate escapes, from its bytes beside it), the keys holding those bytes gone. JSON written before
    (a lone surrogate, ``"\\udcff"``, which Python reads back as the name) is returned as it is."""
    if isinstance(value, list):
        return [names_restored(v) for v in value]
    if not isinstance(value, dict):
        return value
    if not any(isinstance(key, str) and key.endswith(RAW_BYTES) for key in value):
        return {key: names_restored(v) for key, v in value.items()}
    out: dict[Any, Any] = {}
    for key, v in value.items():
        if isinstance(key, str) and _beside_a_key(key, value):
            continue
        v = _bytes_named(names_restored(v), value.get(f"{key}{RAW_BYTES}"))
        out[key] = _keys_named(v, value.get(f"{key}{KEYS_RAW_BYTES}"))
    return out


def _beside_a_key(key: str, value: dict) -> bool:
    """Whether ``key`` of ``value`` holds the bytes of another key's names (``KEY_b64``, ``KEY_keys_b64``)."""
    return any(key.endswith(end) and key[: -len(end)] in value for end in (KEYS_RAW_BYTES, RAW_BYTES))


def _bytes_named(value: Any, raw: Any) -> Any:
    """A name (or list of names) from its text and its bytes as ``_strict`` kept them."""
    if isinstance(value, list) and isinstance(raw, list) and len(raw) == len(value):
        return [_bytes_named(v, r) for v, r in zip(value, raw)]
    return name_of(value, raw) if isinstance(value, str) and isinstance(raw, str) else value


def _keys_named(value: Any, raw: Any) -> Any:
    """A dict (or list of dicts) keyed by names from its keys' text and their bytes as ``_strict`` kept
    them."""
    if isinstance(value, list) and isinstance(raw, list) and len(raw) == len(value):
        return [_keys_named(v, r) for v, r in zip(value, raw)]
    if not isinstance(value, dict) or not isinstance(raw, dict):
        return value
    return {name_of(k, raw.get(k)) if isinstance(k, str) else k: v for k, v in value.items()}


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
