"""Errors a user can cause. The command-line tools print them as one line and exit with code 1."""

from __future__ import annotations

from pathlib import Path


def printable(text: str) -> str:
    """``text`` as a message shows it: the bytes of a file name that are not UTF-8 (held by Python as
    surrogate escapes, printed as ``\\udcff``) as ``\\xff``, as Python shows bytes (``caf\\xe9.mp3``)."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:  # a surrogate no file name's bytes give
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


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
