"""BAS Partitur files (``.par``), as WebMAUS and the other BAS web services write them: a header of
``KEY: value`` lines ending at ``LBD:``, ``SAM:`` the sampling rate, then one line per segment of each tier.
The ``MAU`` tier is the phone segmentation: ``MAU: <begin> <duration> <word> <phone>``, begin and
duration in samples (a segment covers samples ``begin`` to ``begin + duration`` inclusive), word ``-1``
for a pause, phones in (X-)SAMPA with ``<p:>`` for a pause."""

from __future__ import annotations

import codecs
from pathlib import Path

from .errors import InputError


def read_maus_phones(path: str | Path) -> list[tuple[float, float, str]]:
    """The ``MAU`` tier's segments as (start s, end s, phone label); ``[]`` when the file has none (a
    Partitur written before MAUS ran). ``InputError`` naming the line of a malformed one."""
    path = Path(path)
    rate: float | None = None
    segments: list[tuple[int, int, str]] = []
    # only the SAM and MAU lines are decoded: the rest may be the Latin-1 of older BAS corpora (their ORT
    # words), and a file of another kind named .par (a Parchive volume) has neither
    for number, line in enumerate(path.read_bytes().removeprefix(codecs.BOM_UTF8).splitlines(), start=1):
        key, _, rest = line.partition(b":")
        if key not in (b"SAM", b"MAU"):
            continue
        try:
            fields = rest.decode("utf-8").split()
        except UnicodeDecodeError:
            raise InputError(f"a {key.decode()}: line that is not UTF-8 text", path, number) from None
        if key == b"SAM":
            if len(fields) != 1 or not fields[0].isdecimal() or int(fields[0]) == 0:
                raise InputError(
                    f"SAM: must be a sampling rate in Hz, found {' '.join(fields)!r}", path, number
                )
            rate = float(fields[0])
        else:
            if len(fields) < 4 or not (fields[0].isdecimal() and fields[1].isdecimal()):
                raise InputError(
                    "expected 'MAU: <begin sample> <duration in samples> <word> <phone>'", path, number
                )
            segments.append((int(fields[0]), int(fields[1]), " ".join(fields[3:])))
    if not segments:
        return []
    if rate is None:
        raise InputError("has MAU segments but no SAM: line (the sampling rate their samples count)", path)
    return [(begin / rate, (begin + length + 1) / rate, label) for begin, length, label in segments]
