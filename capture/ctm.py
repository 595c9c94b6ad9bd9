"""Kaldi CTM phone alignments (``ali-to-phones --ctm-output``, ``steps/get_train_ctm.sh``, MFA's Kaldi
stage): one line per phone, ``<utterance> <channel> <start s> <duration s> <phone> [<confidence>]``, many
utterances in one file, times from the start of each utterance. Phones are as the lang folder's
``phones.txt`` names them (often with word-position suffixes ``_B _I _E _S``), or that table's integer ids
when written before ``utils/int2sym.pl``: ``read_symbol_table`` reads the table that names them. NIST's
``;;`` comment lines and blank lines are skipped."""

from __future__ import annotations

import math
from pathlib import Path

from .errors import InputError
from .paired import read_text

Segment = tuple[float, float, str]


def _number(text: str, what: str, path: Path, line: int) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise InputError(f"the {what} must be a finite number of seconds, found {text!r}", path, line)
    return value


def read_ctm(path: str | Path) -> dict[str, list[Segment]]:
    """Utterance id -> its phones as (start s, end s, label), in file order; ``InputError`` naming the
    line of one that is not ``utterance channel start duration phone [confidence]``."""
    path = Path(path)
    utterances: dict[str, list[Segment]] = {}
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith(";;"):
            continue
        if len(fields) not in (5, 6):
            raise InputError(
                f"expected 'utterance channel start duration phone [confidence]', found {len(fields)} fields",
                path,
                number,
            )
        start = _number(fields[2], "start", path, number)
        duration = _number(fields[3], "duration", path, number)
        # to the microsecond: start + duration is off by float error at the phone boundaries (Kaldi's fall
        # on 10 ms, where every other 20 ms frame centre lies)
        utterances.setdefault(fields[0], []).append((start, round(start + duration, 6), fields[4]))
    return utterances


def has_integer_phones(utterances: dict[str, list[Segment]]) -> bool:
    """Whether the phones are Kaldi's integer ids (a CTM written before ``int2sym.pl``)."""
    labels = [label for segs in utterances.values() for *_, label in segs]
    return bool(labels) and all(label.isdigit() for label in labels)


def read_symbol_table(path: str | Path) -> dict[str, str]:
    """A Kaldi symbol table (``phones.txt``: ``<symbol> <id>`` a line) as id -> symbol."""
    path = Path(path)
    table: dict[str, str] = {}
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 2 or not fields[1].isdigit():
            raise InputError("expected '<phone> <integer id>' (a Kaldi phones.txt)", path, number)
        table[fields[1]] = fields[0]
    return table
