"""Errors a user can cause. The command-line tools print them as one line and exit with code 1."""

from __future__ import annotations

import base64
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
    value that is a dict keyed by such names, their bytes (``KEYS_RAW_BYTES``); other values as they
    are."""
    if isinstance(value, str):
        return printable(value)
    if isinstance(value, (list, tuple)):
        return [strict_names(v) for v in value]
    if not isinstance(value, dict):
        return value
    out: dict[Any, Any] = {}
    for key, v in value.items():
        name = printable(key) if isinstance(key, str) else key
        out[name] = strict_names(v)
        raw = _names_bytes(v)
        if raw is not None:
            out[f"{name}{RAW_BYTES}"] = raw
        keys = _keys_bytes(v)
        if keys:
            out[f"{name}{KEYS_RAW_BYTES}"] = keys
    return out


def _keys_bytes(value: Any) -> dict[str, str] | None:
    """Of a dict, ``{key as shown: its bytes in base64}`` for each key that is a name not UTF-8 (empty when
    none is); None for any other value."""
    if not isinstance(value, dict):
        return None
    return {printable(k): raw for k in value if isinstance(k, str) and (raw := _names_bytes(k)) is not None}


def _names_bytes(value: Any) -> str | list[str | None] | None:
    """What ``strict_names`` keeps beside a dict value: a name's bytes in base64 when it is not UTF-8; for
    a list holding such a name, each name's (null for a name that is UTF-8); else None."""
    if isinstance(value, str):
        raw = _raw_bytes(value)
        return None if raw is None else base64.b64encode(raw).decode("ascii")
    if isinstance(value, (list, tuple)) and any(isinstance(v, str) for v in value):
        each = [_names_bytes(v) if isinstance(v, str) else None for v in value]
        return each if any(raw is not None for raw in each) else None
    return None


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
