"""Generic paired data from other rigs: an audio file, a frames x channels matrix, channel names, a rate.

Frame ``i`` covers ``[i/F, (i+1)/F)`` seconds from the start of the audio, so its time is ``i/F``.
Channel names are kept as given (a rig's own controls, e.g. FACEGOOD's 116); names of Live Link
channels in any spelling are mapped to the toolkit's canonical ARKit names, also when every name carries
one prefix or suffix around them (``A2F_jawOpen``, ``jawOpen_bs``: repair ``channel_affix``).

The matrix is a ``.npy`` array, a CSV (optional header row of names; comma, semicolon or tab separated),
the blendshape JSON that NVIDIA Audio2Face exports (``exportFps``, ``numFrames``, ``numPoses``,
``facsNames``, ``weightMat``; its joint tracks are not face weights and are left out), which carries its
own names and rate, a BEAT face JSON (``names``, ``frames`` of ``time`` and ``weights``), which carries
its names and frame times, or Face Cap's text export (``bs`` line of names, ``k`` lines of a time in
milliseconds, the head and eye pose, which is left out, and the weights). Columns beside ARKit channels
that are no face channel (MediaPipe's ``_neutral``, a generator's emotion weights) are left out.
"""

from __future__ import annotations

import codecs
import csv
import json
import math
import os
import re
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from . import channels as ch
from .audio_io import read_audio
from .csv_take import (
    COUNT_NAMES,
    MAX_GAP_S,
    NTSC_FPS,
    NTSC_TOLERANCE,
    STANDARD_TOLERANCE,
    fill_dropped,
    nearest_standard,
    note_channel_typos,
    plain_number,
    repair,
)
from .errors import InputError
from .npz import NPZ_ERRORS, npz_array, npz_headers, open_npz
from .take import MAX_FPS, FrameStatus, Take, TakeMeta, safe_id, source_file


class NoFrameRate(InputError):
    """Paired data whose rate the file does not give (nor a usable time column): ``--fps`` is needed."""


def load_npy(path: Path) -> np.ndarray:
    """A ``.npy`` array, never unpickled (object arrays are refused)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Python 2 era .npy headers are harmless
            return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"not a numeric or string .npy array ({exc})", path) from None


# Byte-order marks of the "Unicode" text Windows tools save, and the codec that reads each.
_BOMS = (
    (codecs.BOM_UTF32_LE, "utf-32"),  # before UTF-16 LE, whose mark begins it
    (codecs.BOM_UTF32_BE, "utf-32"),
    (codecs.BOM_UTF16_LE, "utf-16"),
    (codecs.BOM_UTF16_BE, "utf-16"),
)


def bom_codec(raw: bytes) -> str | None:
    """The codec of text starting with a UTF-16 or UTF-32 byte-order mark (``raw``: its first bytes)."""
    return next((codec for bom, codec in _BOMS if raw.startswith(bom)), None)


def read_text(path: Path) -> str:
    """A text file's contents: UTF-8 (a byte-order mark is skipped), or UTF-16/UTF-32 with a byte-order
    mark (Windows' "Unicode" text). Other text is a one-line error naming the file and line."""
    raw = path.read_bytes()
    codec = bom_codec(raw)
    if codec is not None:
        try:
            return raw.decode(codec)
        except UnicodeDecodeError:
            raise InputError(f"not {codec.upper()} text, although it starts like it", path) from None
    if b"\x00" in raw:
        raise InputError("holds NUL bytes: UTF-16 text without a byte-order mark? (save it as UTF-8)", path)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError("not UTF-8 text (save it as UTF-8)", path, line) from None


# A names file line that numbers its name ("0 jawOpen", "1<TAB>jawLeft"), as printed lists often do.
_NUMBERED_NAME = re.compile(r"(\d+)[ \t]+(\S.*)")


def read_names(path: str | Path) -> list[str]:
    """Channel names: a text file (one per line, or comma-separated; quotes as in a CSV; blank lines and
    a comma ending a line are skipped), a ``.json`` list of names (or an object holding one list of them,
    or Audio2Face's ``facsNames``) or a ``.npy`` array of strings (text, or UTF-8 bytes). An empty name is
    refused, as is a name twice, and a text file whose names carry a JSON list's brackets or quotes."""
    path = Path(path)
    if not path.is_file():
        raise InputError("channel-name file not found", path)
    if path.suffix.lower() == ".npy":
        names = string_names(load_npy(path), path)
    elif path.suffix.lower() == ".json":
        names = _json_names(path)
    else:
        names = []
        for number, line in enumerate(read_text(path).splitlines(), start=1):
            if not line.strip():
                continue
            cells = [c.strip() for c in next(csv.reader([line], skipinitialspace=True), [])]
            if len(cells) > 1 and not cells[-1]:
                cells.pop()  # a comma ending the line
            if not all(cells):
                raise InputError("an empty channel name (two commas in a row?)", path, number)
            debris = next((c for c in cells if _json_debris(c)), None)
            if debris is not None:
                raise InputError(
                    f"channel name {_show(debris)} carries brackets or quotes: a JSON list of names? "
                    "save it as a .json file, or write one name a line",
                    path,
                    number,
                )
            names.extend(cells)
        numbered = [_NUMBERED_NAME.fullmatch(n) for n in names]
        if names and all(numbered):
            index = [int(m[1]) for m in numbered]
            if index in (list(range(len(names))), list(range(1, len(names) + 1))):
                names = [m[2].strip() for m in numbered]
    if not names:
        raise InputError("no channel names", path)
    twice = repeated_name(names)
    if twice is not None:
        raise InputError(f"channel name {twice[1]!r} appears twice", path)
    return names


def _json_debris(name: str) -> bool:
    """Whether a name read from a text file is what a JSON list (or object) of names leaves when read as
    text: it opens with the list's ``[`` (``{``), closes it without opening a bracket of its own (not
    ``brow_up[L]``), or is wrapped in matching quotes (``'a'``; the csv module unwraps ``"a"``)."""
    return (
        name[0] in "[{"
        or (name[-1] in "]}" and not any(b in name for b in "[{"))
        or (len(name) > 1 and name[0] == name[-1] and name[0] in "\"'")
    )


def string_names(arr: np.ndarray, path: Path) -> list[str]:
    """Channel names from an array of strings (text, or bytes in UTF-8), as ``.npy``/``.npz`` hold them."""
    if arr.dtype.kind not in "US":
        raise InputError(f"names array holds {arr.dtype}, not strings", path)
    names = []
    for i, x in enumerate(arr.ravel()):
        if isinstance(x, bytes):
            try:
                x = x.decode("utf-8")
            except UnicodeDecodeError:
                raise InputError(
                    f"name {i} ({_show(bytes(x))}) is not UTF-8 text: save the names as a str array "
                    "(dtype U), or as UTF-8 bytes",
                    path,
                ) from None
        names.append(str(x).strip())
    if "" in names:
        raise InputError(f"name {names.index('')} of the array is empty", path)
    return names


def _json_of(text: Callable[[], str], path: Path) -> Any:
    """The JSON value of the text ``text()`` reads from ``path``; one-line errors for text that is not
    JSON, nested too deeply, or not decodable."""
    try:
        return json.loads(text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not a JSON file ({exc})", path) from None
    except RecursionError:
        raise InputError("not a JSON file (nested too deeply)", path) from None


def _json_names(path: Path) -> list[str]:
    """Channel names from a ``.json`` file: a list of names, or an object holding one list (``{"names":
    [...]}``) or Audio2Face's ``facsNames``."""
    data = _json_of(lambda: read_text(path), path)
    if isinstance(data, dict):
        lists = [v for v in data.values() if isinstance(v, list)]
        data = data["facsNames"] if "facsNames" in data else lists[0] if len(lists) == 1 else data
    if not isinstance(data, list) or not all(isinstance(n, str) for n in data):
        raise InputError(
            'a .json names file must hold a list of names (["jawOpen", ...]), or an object holding one '
            '({"names": [...]})',
            path,
        )
    names = [n.strip() for n in data]
    if "" in names:
        raise InputError(f"name {names.index('')} of the list is empty", path)
    return names


# First lines of a names file that are a header, not a channel (compared as in ``_column_key``).
NAMES_HEADERS = (
    "name", "names", "channel", "channels", "channelname", "channelnames", "blendshape", "blendshapes",
    "blendshapename", "blendshapenames", "bsname", "bsnames", "shape", "shapes", "pose", "poses",
    "posename", "facsnames", "label", "labels", "control", "controls",
)  # fmt: skip


def _names_mismatch(names: list[str], columns: int, matrix_path) -> str:
    """What is wrong when a names file gives another number of names than the matrix has columns."""
    text = f"{len(names)} channel names for a matrix of {columns} columns ({Path(matrix_path).name})"
    if len(names) == columns + 1 and _column_key(names[0]) in NAMES_HEADERS:
        text += f": is the first line, {names[0]!r}, a header? remove it"
    return text


def repeated_name(names: list[str]) -> tuple[str, str] | None:
    """The first two names that are one name in any case and spacing (first, second), or None."""
    seen: dict[str, str] = {}
    for n in names:
        key = n.strip().lower()
        if key in seen:
            return seen[key], n
        seen[key] = n
    return None


def exact_rate(fps: float | None) -> float | None:
    """A frame rate within ``NTSC_TOLERANCE`` of an NTSC rate (29.97, 59.94, 23.976: what tools write for
    30000/1001, ...) as that rate exactly, so that takes of two writers are at one rate; others as given."""
    if fps is None:
        return None
    for ntsc in NTSC_FPS.values():
        if abs(fps / ntsc - 1) < NTSC_TOLERANCE:
            return ntsc
    return fps


def read_json_matrix(path: Path) -> tuple[np.ndarray, list[str], float | None]:
    """Weights, names and frame rate (None: the file gives none) of a JSON matrix: an Audio2Face
    blendshape export, or a BEAT face JSON (its frame times come first, as a ``time`` column)."""
    data = _json_of(lambda: read_text(path), path)  # Windows tools save "Unicode" (UTF-16) text too
    if (
        isinstance(data, dict)
        and not {"weightMat", "facsNames"} & data.keys()
        and {"names", "frames"} <= data.keys()
    ):
        return _beat_face(data, path)
    if not isinstance(data, dict) or "weightMat" not in data or "facsNames" not in data:
        if isinstance(data, dict):
            keys = ", ".join(_show(key, 80) for key in list(data)[:4]) + (", ..." if len(data) > 4 else "")
            held = f"an object of {keys}" if data else "an empty object"
        else:
            held = f"a list of {len(data)} items" if isinstance(data, list) else _json_kind(data)
        raise InputError(
            f"holds {held}: not an Audio2Face blendshape export (no weightMat and facsNames), nor a BEAT "
            "face JSON (no names and frames)",
            path,
        )
    return _a2f_export(data, path)


def _a2f_export(data: dict, path: Path) -> tuple[np.ndarray, list[str], float | None]:
    """Weights, pose names and frame rate of an Audio2Face blendshape export."""
    names, rows, fps = data["facsNames"], data["weightMat"], data.get("exportFps")
    _check_json_names(names, "facsNames", path)
    if not isinstance(rows, list) or not rows:
        raise InputError("weightMat must be a non-empty list of frames", path)
    matrix = _json_rows(rows, lambda i: f"weightMat[{i}]", f"facsNames {len(names)} names", len(names), path)
    for key, want in (("numFrames", len(rows)), ("numPoses", len(names))):
        got = data.get(key)
        if got is not None and (isinstance(got, bool) or got != want):
            raise InputError(f"{key} is {_show(got)} but the file holds {want}", path)
    if fps is not None:
        if not _json_number(fps):
            raise InputError(f"exportFps must be a number, not {_show(fps)}", path)
        try:
            fps = exact_rate(float(fps))
        except OverflowError:
            raise InputError(f"exportFps must be a frame rate, not {_show(fps)}", path) from None
    return matrix, [n.strip() for n in names], fps


# The key of a BEAT face JSON's frame time (seconds), and the name its column gets.
BEAT_TIME = "time"


class _FrameTimes(str):
    """The name of the column of frame times ``_beat_face`` puts before a BEAT face JSON's weights: no
    channel of the file, so names given for its channels (``--names``) leave it in place."""


def _beat_face(data: dict, path: Path) -> tuple[np.ndarray, list[str], None]:
    """Times and weights of a BEAT face JSON, the layout of the BEAT dataset's ARKit weights and of
    generators trained on it (``{"names": [...], "frames": [{"time": s, "weights": [...]}, ...]}``):
    a ``time`` column (when every frame has a time) and one per name. A frame's ``rotation`` (the
    head's) is not a face weight and is left out."""
    names, frames = data["names"], data["frames"]
    _check_json_names(names, "names", path)
    if not isinstance(frames, list) or not frames or not all(isinstance(f, dict) for f in frames):
        raise InputError('frames must be a non-empty list of frames ({"time": ..., "weights": [...]})', path)
    unweighted = next((i for i, f in enumerate(frames) if "weights" not in f), None)
    if unweighted is not None:
        raise InputError(f"frames[{unweighted}] has no weights", path)
    rows = [f["weights"] for f in frames]
    matrix = _json_rows(rows, lambda i: f"frames[{i}].weights", f"names {len(names)} names", len(names), path)
    names = [n.strip() for n in names]
    timed = [BEAT_TIME in f for f in frames]
    if not any(timed):
        return matrix, names, None
    if not all(timed):
        raise InputError(f"frames[{timed.index(False)}] has no time, frames[{timed.index(True)}] has", path)
    times = _json_rows([[f[BEAT_TIME]] for f in frames], lambda i: f"frames[{i}].time", "a time", 1, path)
    return np.column_stack([times, matrix]), [_FrameTimes(BEAT_TIME), *names], None


def _check_json_names(names: object, key: str, path: Path) -> None:
    """Refuse a JSON matrix's ``key`` that is not a non-empty list of names."""
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n.strip() for n in names):
        raise InputError(f"{key} must be a non-empty list of names", path)


def _json_number(value: object) -> bool:
    """Whether a JSON value is a number (not true or false, which Python counts as 1 and 0)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _json_kind(value: object) -> str:
    """What a JSON value is, in JSON's words (for a message): null, true, false, a string, an object, a
    number."""
    if value is None or isinstance(value, bool):
        return json.dumps(value)
    return "a string" if isinstance(value, str) else "an object" if isinstance(value, dict) else "a number"


def _json_rows(rows: list, where: Callable[[int], str], want: str, width: int, path: Path) -> np.ndarray:
    """The frames x ``width`` matrix of a JSON file's rows of numbers; ``where(i)`` names row ``i`` in a
    one-line error, ``want`` what gives the width (``facsNames 52 names``)."""
    matrix = np.empty((len(rows), width), dtype=np.float64)
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != width:
            got = f"{len(row)} values" if isinstance(row, list) else _json_kind(row)
            raise InputError(f"{where(i)} holds {got}, {want}", path)
        if not all(map(_json_number, row)):
            raise InputError(f"{where(i)} holds a value that is not a number", path)
        try:
            matrix[i] = row
        except OverflowError:
            raise InputError(f"{where(i)} holds a number too large for a float", path) from None
    return matrix


def _rate(fps: float) -> str:
    """A frame rate for a message: an NTSC rate as written (29.97, 59.94, 23.976)."""
    return f"{round(fps, 3):g}"


def _show(value: object, limit: int = 40) -> str:
    """A value for an error message, cut short (a 400-digit number stays readable)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# A cell holding an SMPTE timecode (HH:MM:SS:FF, drop-frame HH:MM:SS;FF), and one holding a number written
# with a decimal comma (0,5).
_SMPTE = re.compile(r"\d{1,2}:\d{2}:\d{2}[:;.]\d{2}(\.\d+)?")
_DECIMAL_COMMA = re.compile(r"[+-]?\d*,\d+([eE][+-]?\d+)?")
# A cell of digits grouped with '_' (``1_000``, ``0.000_5``), which Python's float() alone would read;
# each '_' between two digits, so that no two parts of the pattern match the same text (a long cell of
# digits is matched in one pass, not tried at every split).
_DIGITS = r"[0-9]+(_[0-9]+)*"
_GROUPED_DIGITS = re.compile(rf"[+-]?({_DIGITS}(\.({_DIGITS})?)?|\.{_DIGITS})([eE][+-]?{_DIGITS})?")
# iFacialMocap's stream text, a frame a line: ``mouthSmile_R-0|eyeLookOut_L-12|...|=head#...|`` (its
# blendshapes on 0..100, then head and eye angles), as a script saving what the app sends writes it;
# ``mouthSmile_R&0|...`` (values perhaps negative) when the app sends version 2 (``sendDataVersion=v2``).
_IFACIALMOCAP = re.compile(r"\s*[A-Za-z_]+(-|&-?)\d+(\.\d+)?\|")


def _delimiter(first: list[str]) -> str:
    """A CSV's separator, from its first lines: the one of comma, semicolon (spreadsheets in locales with a
    decimal comma write ``;``) and tab that splits them, outside quotes, into the same number of cells,
    the most; a comma when none does."""

    def cells(line: str, sep: str) -> int:
        try:
            row = next(csv.reader([line], delimiter=sep), [])
        except csv.Error:  # a cell past the csv module's limit: refused when the rows are read
            return 0
        return len([c for c in row if c.strip()] if sep == "\t" else row)  # a stray tab ending a line

    counts = {sep: {cells(line, sep) for line in first} for sep in (",", ";", "\t")}
    agreeing = [sep for sep, n in counts.items() if len(n) == 1 and min(n) > 1]
    return max(agreeing, key=lambda sep: min(counts[sep]), default=",")


def header_names(line: str) -> list[str]:
    """The cells of a CSV's first line (its header, when it has one), split as ``read_matrix`` splits it."""
    try:
        return [
            c.strip() for c in next(csv.reader([line], delimiter=_delimiter([line]), skipinitialspace=True))
        ]
    except (csv.Error, StopIteration):
        return []


def _numbers(cells: list[str], decimal_comma: bool) -> list[float]:
    """A row's values; an empty cell (how pandas writes NaN) is NaN. ValueError for any other cell that
    is not a number, also ``1_0`` and other scripts' digits, which Python's float() alone would read."""
    if not all(map(plain_number, cells)):
        raise ValueError
    if decimal_comma:
        cells = [c.replace(",", ".") for c in cells]
    return [float(c) if c else math.nan for c in cells]


def _is_number(cell: str, decimal_comma: bool) -> bool:
    try:
        _numbers([cell], decimal_comma)
    except ValueError:
        return False
    return True


def _column_numbers(cells: list[str]) -> int:
    """How many columns a first row numbers 0, 1, ..., N-1 (pandas' default header, perhaps after the
    index column's empty cell), or 0 when it is not such a row (it takes 3 to tell it from data)."""
    numbers = cells[1:] if cells and cells[0] == "" else cells
    return len(numbers) if len(numbers) >= 3 and numbers == _counting(0, len(numbers)) else 0


def _counting(start: int, count: int) -> list[str]:
    """Cells counting ``start``, ``start + 1``, ... (``count`` of them), as an index column writes them."""
    return [str(i) for i in range(start, start + count)]


def _non_numeric(cells: list[str], column: int, header: list[str] | None, sep: str) -> str:
    """The one-line error for a row whose cell ``column`` is not a number: the cell, its column and what
    it looks like."""
    cell = cells[column]
    where = f"column {header[column]!r}" if header else f"column {column + 1}"
    hint = ""
    if _SMPTE.fullmatch(cell):
        hint = (
            ": an SMPTE timecode, not seconds (give the times in seconds, or frame numbers in a "
            "`frame` column)"
        )
    elif sep == "," and _DECIMAL_COMMA.fullmatch(cell):
        hint = " (a decimal comma? write numbers with a point, or separate the cells with ';')"
    elif sep == "," and (";" in cell or "\t" in cell):
        hint = f" (separated by {'semicolons' if ';' in cell else 'tabs'} below a comma-separated header?)"
    elif cells == header:
        hint = " (the header row again: files joined one after another? import each file alone)"
    elif len(cells) > 1 and (ch.is_known(cell) or cell == ch.NEUTRAL_SCORE):  # not a names file as a matrix
        hint = (
            ": a blendshape's name, in a column of names (one row per blendshape and frame, as MediaPipe "
            "scripts write its categories): write one row per frame with a column per blendshape (pandas: "
            "df.pivot(index=<time column>, columns=<name column>, values=<score column>))"
        )
    elif _GROUPED_DIGITS.fullmatch(cell):
        hint = " (digits grouped with '_' are not read)"
    return f"non-numeric value in the matrix: {_show(cell)} in {where}{hint}"


def _other_text(line: str) -> str | None:
    """What a text file whose first non-blank line is ``line`` holds when it is another program's text,
    not a table of weights (iFacialMocap's stream text, a Unity YAML clip), or None."""
    if _IFACIALMOCAP.match(line):
        return (
            "iFacialMocap's stream text (blendshape-value|... or blendshape&value|... on a 0..100 scale, "
            "then =head#...)"
        )
    if line.startswith("%YAML"):
        return "a YAML file (a Unity animation clip, as Unity's Face Capture records a take)"
    return None


def _read_csv(path: Path, notes: list[dict]) -> tuple[np.ndarray, list[str] | None, int]:
    """Values, header names (None without a header row) and, for a header of column numbers
    (0..N-1, pandas' default), N (else 0) of a CSV matrix, or of a Face Cap text export. See
    ``read_matrix``; what is left out is said in ``notes``."""
    text = read_text(path)
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if not lines:
        raise InputError("matrix has no frames", path)
    if (other := _other_text(lines[0][1])) is not None:
        raise InputError(
            f"{other}, not a table of weights, which is not read: save the weights as a CSV of a row per "
            "frame under a header of names (and a time column)",
            path,
            lines[0][0],
        )
    if is_face_cap("\n".join(line for _, line in lines[:5])):  # as far as is_face_cap looks
        return _face_cap(lines, path, notes)
    sep = _delimiter([line for _, line in lines[:2]])
    decimal_comma = sep != ","
    rows = []  # (line number, cells): quotes as a CSV has them (R quotes every name)
    reader = csv.reader((line for _, line in lines), delimiter=sep, skipinitialspace=True)
    try:
        for cells in reader:
            rows.append((lines[reader.line_num - 1][0], [c.strip() for c in cells]))
    except csv.Error as exc:
        raise InputError(f"not a CSV row ({exc})", path, lines[reader.line_num - 1][0]) from None
    header, numbered = None, _column_numbers(rows[0][1])
    if numbered or not all(_is_number(c, decimal_comma) for c in rows[0][1]):
        header = rows.pop(0)[1]
    if not rows:
        raise InputError("matrix has no frames", path)
    width = len(rows[0][1])
    for number, cells in rows:
        if len(cells) != width:
            raise InputError(f"row has {len(cells)} values, the first row {width}", path, number)
    if header is not None and len(header) == width + 1 and header[-1] == "":
        header.pop()  # a comma ending the header line only
    if all(cells[-1] == "" for _, cells in rows) and width > 1 and (header is None or len(header) == width):
        if header is None or header[-1] == "":  # a comma ending every line: no column
            rows = [(n, cells[:-1]) for n, cells in rows]
            header = header[:-1] if header is not None else None
            width -= 1
    if header is not None and header[0] in ("", PANDAS_INDEX) and len(header) == width > 1:
        index = [cells[0] for _, cells in rows]
        if index in (_counting(0, len(rows)), _counting(1, len(rows))):  # pandas' index, R's row names
            rows = [(n, cells[1:]) for n, cells in rows]
            header = header[1:]
            width -= 1
        elif header[0] == PANDAS_INDEX:
            raise InputError(
                f"the first column, {PANDAS_INDEX!r} (pandas' name for a column without a name), does not "
                "count the rows 0, 1, ... as an index does: name it, or delete it",
                path,
                lines[0][0],
            )
    if header is not None and len(header) != width:
        raise InputError(f"the header names {len(header)} columns, the rows hold {width}", path, lines[0][0])
    if header is not None and not all(header):
        column = header.index("") + 1
        raise InputError(f"the header leaves a column without a name (column {column})", path, lines[0][0])
    values = np.empty((len(rows), width), dtype=np.float64)
    for r, (number, cells) in enumerate(rows):
        try:
            values[r] = _numbers(cells, decimal_comma)
        except ValueError:
            j = next(j for j, c in enumerate(cells) if not _is_number(c, decimal_comma))
            raise InputError(
                _non_numeric(cells, j, None if numbered else header, sep), path, number
            ) from None
    return values, None if numbered else header, numbered


# The lines of Face Cap's text export (Bannaflak's iOS app): ``info,...``; ``bs,`` and its blendshapes'
# names (ARKit's, sides as ``_L``/``_R``); a ``k,`` line per frame: the time in milliseconds from the
# recording's start, the head's position (3) and rotation (3, degrees), the left and right eye's rotation
# (2 each, degrees), and the blendshapes' weights (0..1) in the ``bs`` line's order.
FACE_CAP_NAMES, FACE_CAP_FRAME = "bs,", "k,"
FACE_CAP_POSE = 10


def is_face_cap(start: str) -> bool:
    """Whether a text file starting with ``start`` (its first lines) is a Face Cap text export: a ``bs``
    line among its first three, after an ``info`` line or followed by a ``k`` line (a note or a list of
    names that merely starts with ``bs,`` is none)."""
    lines = [line for line in start.splitlines() if line.strip()]
    names = next((i for i, line in enumerate(lines[:3]) if line.startswith(FACE_CAP_NAMES)), None)
    if names is None:
        return False
    after = lines[names + 1 : names + 3]
    return lines[0].startswith("info,") or any(line.startswith(FACE_CAP_FRAME) for line in after)


def _face_cap(
    lines: list[tuple[int, str]], path: Path, notes: list[dict]
) -> tuple[np.ndarray, list[str], int]:
    """Times (a ``time_ms`` column) and weights of a Face Cap text export; the head and eye pose of each
    frame is left out (noted), as are ``info`` lines."""
    names: list[str] | None = None
    rows = []
    for number, line in lines:
        cells = [c.strip() for c in line.split(",")]
        if cells[0] == "info":
            continue
        if cells[0] == FACE_CAP_NAMES.rstrip(","):
            if names is not None:
                raise InputError("a second bs line (blendshape names)", path, number)
            names = cells[1:]
            if not all(names):
                raise InputError("the bs line leaves a blendshape without a name", path, number)
            continue
        if cells[0] != FACE_CAP_FRAME.rstrip(","):
            raise InputError(f"not a Face Cap line (info, bs or k): {_show(line)}", path, number)
        if names is None:
            raise InputError("a k line (frame) before the bs line naming the blendshapes", path, number)
        weights = len(cells) - 2 - FACE_CAP_POSE
        if weights != len(names):
            held = f"{weights} weights after the time and {FACE_CAP_POSE} head and eye values"
            if weights < 0:  # a line cut short
                held = f"{len(cells) - 1} values, fewer than the time and {FACE_CAP_POSE} head and eye values"
            raise InputError(
                f"k line holds {held}, the bs line names {len(names)} blendshapes",
                path,
                number,
            )
        values = [cells[1], *cells[2 + FACE_CAP_POSE :]]
        try:
            if not all(values):  # the app writes every value: an empty cell is no NaN
                raise ValueError
            rows.append(_numbers(values, False))
        except ValueError:
            bad = next(c for c in values if not c or not _is_number(c, False))
            raise InputError(f"non-numeric value in a k line: {_show(bad)}", path, number) from None
    if names is None or not rows:
        raise InputError(
            "a Face Cap export without " + ("a bs line" if names is None else "k lines (frames)"), path
        )
    repair(
        notes,
        None,
        "pose_left_out",
        f"Face Cap's head position and rotation and eye rotations ({FACE_CAP_POSE} values a frame) left out: "
        "not blendshape weights",
    )
    return np.array(rows, dtype=np.float64), [_FrameTimes("time_ms"), *names], 0


def _read_matrix(
    path: Path, notes: list[dict] | None = None
) -> tuple[np.ndarray, list[str] | None, float | None, int]:
    """``read_matrix``, and for a CSV whose header row numbers its columns the number of them (else 0);
    what a reader leaves out of the file is said in ``notes``."""
    path = Path(path)
    if not path.is_file():
        raise InputError("matrix file not found", path)
    header = fps = None
    numbered = 0
    if path.suffix.lower() == ".npy":
        m = load_npy(path)
    elif path.suffix.lower() == ".npz":
        m, header, fps = _read_npz(path)
    elif path.suffix.lower() == ".json":
        m, header, fps = read_json_matrix(path)
    else:
        m, header, numbered = _read_csv(path, [] if notes is None else notes)
    if m.dtype.kind not in "fiu" or m.ndim != 2:
        raise InputError(f"expected a 2-D numeric frames x channels matrix, got {m.dtype} {m.shape}", path)
    if m.shape[0] == 0:
        raise InputError("matrix has no frames", path)
    return m, header, fps, numbered


# Names of the arrays of a .npz that hold the weights (when it holds more than one array), their channel
# names and the frame rate, compared in lower case.
NPZ_WEIGHTS = ("weights", "values", "blendshapes")
NPZ_NAMES = ("names", "channels", "facsnames", "channel_names")
NPZ_FPS = ("fps", "frame_rate", "framerate")


def _read_npz(path: Path) -> tuple[np.ndarray, list[str] | None, float | None]:
    """The weights of a ``.npz`` (never unpickled): its only 2-D numeric array, or the one named in
    ``NPZ_WEIGHTS``; with the names (an array of strings named in ``NPZ_NAMES``) and rate (a number named
    in ``NPZ_FPS``) when it stores them. Members that are not ``.npy`` arrays (a README) are ignored, and
    only the arrays used are read."""
    try:
        with open_npz(path) as npz:
            if not isinstance(npz, np.lib.npyio.NpzFile):
                raise InputError("a .npy array, not a .npz archive: name it .npy", path)
            arrays = npz_headers(npz)
            named = [k for k in NPZ_WEIGHTS if k in arrays]
            planes = [k for k, (_, shape, dtype) in arrays.items() if len(shape) == 2 and dtype.kind in "fiu"]
            found = named if len(named) == 1 else planes if len(planes) == 1 else None
            if found is None:
                held = (
                    ", ".join(f"{k} {dtype} {shape}" for k, (_, shape, dtype) in arrays.items()) or "nothing"
                )
                raise InputError(
                    f"a .npz needs one 2-D frames x channels array, or one named {', '.join(NPZ_WEIGHTS)} "
                    f"(it holds {held})",
                    path,
                )
            names = next(
                (string_names(npz_array(npz, arrays[k], path), path) for k in NPZ_NAMES if k in arrays), None
            )
            fps = next((arrays[k] for k in NPZ_FPS if k in arrays), None)
            if fps is not None:
                _, shape, dtype = fps
                if math.prod(shape) != 1 or dtype.kind not in "fiu":
                    raise InputError(
                        f"the frame rate it stores must be one number, not {dtype} {shape}", path
                    )
                fps = exact_rate(float(npz_array(npz, fps, path).ravel()[0]))
            return npz_array(npz, arrays[found[0]], path), names, fps
    except NPZ_ERRORS as exc:
        raise InputError(f"not a .npz of numeric or string arrays, or a damaged one ({exc})", path) from None


def read_matrix(path: str | Path) -> tuple[np.ndarray, list[str] | None, float | None]:
    """Frames x channels weights from ``.npy`` or ``.npz`` (never unpickled), ``.csv`` (optional header
    row; comma, semicolon or tab separated, a decimal comma with the last two; empty cells are NaN) or an
    Audio2Face or BEAT ``.json``; with the names and frame rate the file gives (else None)."""
    m, header, fps, _ = _read_matrix(Path(path))
    return m, header, fps


# Paired data below this rate is a misread time column (milliseconds taken for seconds), not a capture.
MIN_FPS = 1.0
# No face capture runs slower: a time column giving a lower rate holds something other than seconds.
MIN_CAPTURE_FPS = 10.0
# Audio longer or shorter than the frames by more than this (s) is noted as repair ``length_mismatch``.
LENGTH_MISMATCH_S = 1.0
# A time column's late start is named as the cause of a length mismatch when the frames, counted from
# their first time, fit the audio within this (s).
LATE_START_S = 0.25
# Header names of a column that holds each frame's time rather than a channel, compared by
# ``_column_key`` (lower case, letters and digits only: `Time (s)` is `times`, `time_ms` is `timems`).
SECONDS_COLUMNS = (
    "time", "times", "timesec", "timeseconds", "seconds", "secs", "sec", "timestamp", "timestamps",
    "timestampsec", "timestampseconds", "timecode", "t", "ts",
)  # fmt: skip
MILLISECONDS_COLUMNS = (
    "timems", "timemsec", "timemillis", "timemilliseconds", "timestampms", "timestampmillis", "milliseconds",
    "millis", "msec", "ms", "tms",
)  # fmt: skip
FRAME_COLUMNS = (
    "frame", "frames", "frameindex", "framenumber", "frameno", "framenum", "frameidx", "framecount",
)  # fmt: skip
# A name of SECONDS_COLUMNS is in seconds (divisor 1), of MILLISECONDS_COLUMNS in milliseconds (1000).
_CLOCK_KINDS = {
    **dict.fromkeys(SECONDS_COLUMNS, ("seconds", 1)),
    **dict.fromkeys(FRAME_COLUMNS, ("frames", 1)),
    **dict.fromkeys(MILLISECONDS_COLUMNS, ("seconds", 1000)),
}
# Other header names holding one of these words hold times too (`frame_timestamp_ms`, `pts_time`,
# `elapsed_s`), in the unit a word of ``_UNIT_WORDS`` gives (units per second), else in the unit the
# column's step fits (``_unit_by_step``).
TIME_WORDS = ("time", "times", "timestamp", "timestamps", "timecode", "elapsed", "pts")
_UNIT_WORDS = {
    **dict.fromkeys(("s", "sec", "secs", "second", "seconds"), 1),
    **dict.fromkeys(("ms", "msec", "msecs", "millis", "millisecond", "milliseconds"), 1000),
    **dict.fromkeys(("us", "usec", "usecs", "micros", "microsecond", "microseconds"), 1_000_000),
}
_UNITS = {1: "seconds", 1000: "milliseconds", 1_000_000: "microseconds"}
# A column is taken for a clock by its values alone (``_clock_like``) from this many rows, when it runs
# past CLOCK_END (beyond any blendshape weight) under a name that is not a face channel's.
CLOCK_ROWS = 10
CLOCK_END = 2.0


_column_key = ch.column_key  # lower case, letters and digits only


def _clock_kind(name: str) -> tuple[str, int | None] | None:
    """What a header name says its column holds: ("seconds", units per second, None when the name gives
    no unit), ("frames", 1), or None: a channel."""
    kind = _CLOCK_KINDS.get(_column_key(name))
    if kind is not None:
        return kind
    words = re.findall(r"[a-z]+", re.sub(r"([a-z])([A-Z])", r"\1_\2", name).lower())
    if not any(w in TIME_WORDS for w in words):
        return None
    units = [_UNIT_WORDS[w] for w in words if w in _UNIT_WORDS]
    return "seconds", units[-1] if units else None


def _unit_by_step(clock: np.ndarray, fps: float | None) -> int | None:
    """The unit (units per second: 1, 1000 or 1e6) in which a column of increasing times steps by one
    frame at ``fps`` (None: at a standard rate), else None."""
    per_unit = column_rate(clock)[0]
    for divisor in _UNITS:
        rate = per_unit * divisor
        if nearest_standard(rate) is not None if fps is None else abs(rate / fps - 1) <= STANDARD_TOLERANCE:
            return divisor
    return None


def _clock_like(name: str, values: np.ndarray, fps: float | None) -> str | None:
    """What a column named ``name`` holds when its values increase from row to row as a clock's do
    (frame numbers, or times in a unit that steps one frame at ``fps`` or a standard rate), else None:
    at least ``CLOCK_ROWS`` of them, running past ``CLOCK_END``, under a name no face channel has."""
    if values.size < CLOCK_ROWS or not np.isfinite(values).all() or not (np.diff(values) > 0).all():
        return None
    if values[-1] <= CLOCK_END or ch.is_known(name):
        return None
    if counts_frames(values):
        return "frame numbers"
    divisor = _unit_by_step(values, fps)
    if divisor is None:
        return None
    return f"{_UNITS[divisor]} at {_rate(column_rate(values)[0] * divisor)} frames per second"


# Characters that end a prefix (or begin a suffix) that a rig or exporter puts on every channel name.
AFFIX_SEPARATORS = "_- "


def live_link_under_affix(names: list[str]) -> tuple[list[str], str] | None:
    """Channel names that are all Live Link names once a prefix or suffix every one of them carries is cut
    off (``A2F_jawOpen``, ``CTRL_expressions_jawOpen``, ``jawOpen_bs``: exporters and rigs name their
    curves so), as ``channel_name`` spells them, and the affix for a message (``'A2F_'``); None when some
    name is no Live Link name that way (a rig's own controls, MetaHuman's ``..._mouthCornerPullL``) or
    every name is one already. A prefix ends (a suffix begins) at an ``AFFIX_SEPARATORS`` character; the
    longest that leaves Live Link names is cut."""
    if all(ch.is_known(n) for n in names):
        return None
    heads = _affix_lengths(names)
    backs = _affix_lengths([n[::-1] for n in names])
    for head, back in [(h, 0) for h in heads] + [(0, b) for b in backs]:
        core = [n[head : len(n) - back] for n in names]
        if all(core) and all(ch.is_known(c) for c in core):
            return [channel_name(c) for c in core], repr(names[0][:head] or names[0][len(names[0]) - back :])
    return None


def _affix_lengths(names: list[str]) -> list[int]:
    """The lengths of the prefixes all ``names`` share that end at an ``AFFIX_SEPARATORS`` character,
    longest first."""
    first = names[0]
    shared = len(os.path.commonprefix(names))
    return [i + 1 for i in range(shared - 1, -1, -1) if first[i] in AFFIX_SEPARATORS]


def channel_name(name: str) -> str:
    """A channel's name as the take keeps it: Live Link/ARKit names in canonical spelling (any spelling
    ``capture.channels`` accepts, also under a prefix: ``blendShapes.JawOpen``); a rig's own as given."""
    return ch.canonical(name) if ch.is_known(name) else name


# The header pandas gives a first column without a name when it reads a CSV written with its index.
PANDAS_INDEX = "Unnamed: 0"


def emotion_weights(names: list[str]) -> str | None:
    """Why a header whose channels (time and index columns aside) are all emotion names
    (``channels.EMOTION_NAMES``: Audio2Face-3D's a2e_emotion_output.csv, NeuroSync's 7 emotions) is not a
    face take, or None when it has another channel."""
    rest = [n for n in names if n.strip() and n != PANDAS_INDEX and _clock_kind(n) is None]
    if not rest or not all(ch.side_score(n) for n in rest):
        return None
    shown = ", ".join(rest[:3]) + (", ..." if len(rest) > 3 else "")
    return f"holds emotion weights ({shown}), not face channels: not a face take"


def _frame_clock(
    names: list[str], matrix: np.ndarray, fps: float | None, path
) -> tuple[str | None, np.ndarray | None, list[int], str | None, list[dict]]:
    """The column that places the frames, if the header has one: (kind "seconds"/"frames", its values in
    seconds or frame numbers (other units converted), the columns that are no channels, its name, repair
    notes). A frame-number column beside a time column is left out (note ``frame_column``); a first
    column increasing like a clock under a name that does not say so is an error, not a channel."""
    found = [(i, n, _clock_kind(n)) for i, n in enumerate(names)]
    found = [(i, n, k) for i, n, k in found if k is not None]
    if not found:
        what = _clock_like(names[0], matrix[:, 0].astype(np.float64), fps) if len(names) > 1 else None
        if what is not None:
            raise InputError(
                f"column {names[0]!r} increases from row to row like a clock ({what}), but its name does not "
                "say so: name it `time` (seconds), `time_ms` (milliseconds) or `frame` (frame numbers) to "
                "place the frames by it, or delete it",
                path,
            )
        return None, None, [], None, []
    times = [f for f in found if f[2][0] == "seconds"]
    frames = [f for f in found if f[2][0] == "frames"]
    if len(times) > 1 or len(frames) > 1:
        raise InputError(
            f"several time columns: {', '.join(n for _, n, _ in found)}: keep one and delete the others", path
        )
    notes = []
    if times and frames:
        repair(
            notes,
            None,
            "frame_column",
            f"frame-number column {frames[0][1]!r} left out: the frames are placed by the "
            f"time column {times[0][1]!r}",
        )
    i, name, (kind, divisor) = (times or frames)[0]
    clock = matrix[:, i].astype(np.float64)
    if not np.isfinite(clock).all() or (clock.size > 1 and not (np.diff(clock) > 0).all()):
        raise InputError(f"time column {name!r} must be finite and increase from row to row", path)
    if kind == "frames" and not np.array_equal(clock, np.round(clock)):
        raise InputError(f"frame column {name!r} holds values that are not whole numbers", path)
    if divisor is None and clock.size > 1 and not counts_frames(clock):
        divisor = _unit_by_step(clock, fps)
        if divisor is None:
            at = f" at {_rate(fps)} fps" if fps is not None else " at a standard frame rate"
            raise InputError(
                f"time column {name!r} does not name its unit, and its step is one frame{at} in none of "
                f"seconds, milliseconds and microseconds: add the unit to its name ({name}_s, {name}_ms)",
                path,
            )
        if divisor != 1:
            repair(
                notes,
                None,
                "time_unit",
                f"time column {name!r} names no unit: read in {_UNITS[divisor]}, in which its "
                "step is one frame",
            )
    return kind, clock / (divisor or 1), [i for i, _, _ in found], name, notes


def counts_frames(clock: np.ndarray) -> bool:
    """Whether a time column holds frame numbers rather than seconds: whole numbers stepping by 1."""
    return clock.size > 1 and np.array_equal(clock, np.round(clock)) and float(np.median(np.diff(clock))) == 1


def column_rate(times: np.ndarray) -> tuple[float, float]:
    """Frames per second a time column keeps over the whole take, and its relative standard error: the
    slope of a least-squares line through the times against their frame numbers (a gap counts its missing
    frames). Unlike the median step it survives rounding: 30 fps written to 2 decimals steps by 0.03 and
    0.04 s (a median of 0.03: 33.3 fps), 60 fps by 0.01 and 0.02 s."""
    steps = np.diff(times)
    period = float(np.median(steps))
    frames = None
    for _ in range(5):  # frame numbers from the period, the period from the frame numbers, until they agree
        counted = np.concatenate([[0.0], np.cumsum(np.maximum(np.rint(steps / period), 1))])
        if frames is not None and np.array_equal(counted, frames):
            break
        frames = counted
        f, t = frames - frames.mean(), times - times.mean()
        period = float(f @ t / (f @ f))
    residual = t - period * f
    spread = math.sqrt(float(residual @ residual) / (f.size - 2) / float(f @ f)) if f.size > 2 else 0.0
    return 1 / period, spread / period


def nominal_rate(rate: float, spread: float = 0.0) -> float:
    """The frame rate a time column keeping ``rate`` (relative standard error ``spread``) was written at:
    the nearest standard rate when within 3 % (as ``detect_fps``), its NTSC rate when the column keeps
    that within ``NTSC_TOLERANCE`` (or 3 standard errors of a short or coarsely rounded column, at most
    half way to the nominal rate), else ``rate`` to 3 decimals."""
    std = nearest_standard(rate)
    if std is None:
        return round(rate, 3)
    ntsc = NTSC_FPS.get(std)
    near = min(max(NTSC_TOLERANCE, 3 * spread), 5e-4)
    return ntsc if ntsc is not None and abs(rate / ntsc - 1) < near else std


def _frame_times(kind: str | None, clock: np.ndarray | None, frames: int, fps: float, path) -> np.ndarray:
    """Frame times (s from the audio's start): ``i / fps``, or from the time column, which may not jump
    by more than ``MAX_GAP_S``."""
    if kind is None:
        return np.arange(frames, dtype=np.float64) / fps
    time = clock if kind == "seconds" else clock / fps
    step = np.diff(time)
    if step.size and step.max() > MAX_GAP_S:
        at = int(np.argmax(step))
        raise InputError(
            f"the time column jumps by {step[at]:.6g} s after frame {at + 1} (more than "
            f"{MAX_GAP_S:g} s: two recordings joined, or a corrupt clock)",
            path,
        )
    return time


def read_paired(
    audio_path: str | Path,
    matrix_path: str | Path,
    fps: float | None,
    names_path: str | Path | None = None,
    take_id: str | None = None,
    names_option: bool = True,
    first_frame: int | None = None,
    value_scale: float | None = None,
    first_frame_strict: bool = True,
) -> Take:
    """A take from audio + weight matrix + names at ``fps`` frames per second (None: the rate the
    matrix file gives, as an Audio2Face export does, or its time column's), named ``take_id``
    (default: the matrix file's stem). ``names_option``: whether the caller can give ``names_path``
    (``--names``), which the error for a matrix without names then suggests.

    A header column named like a time (``time``, ``timestamp``, ``Time (s)``, ... in seconds from the
    audio's start; ``time_ms``, ``milliseconds``, ... in milliseconds) or a frame index (``frame``,
    ``frame_index``, ...) places the frames instead of the row index and is not a channel; gaps in it
    become DROPPED frames. A take placed by seconds gets its audio with start source
    ``paired_time_column`` (align keeps the times), others ``paired_frame_convention``.

    ``first_frame``: the number in a frame-number column of the frame at the audio's start (None: 1 when
    the column starts at 1, with note ``frame_numbers_from_1``, else 0); for a file without such a column
    an error, or with ``first_frame_strict`` False (a batch, whose other files may have one) ignored with
    note ``first_frame_ignored``. ``value_scale``: a factor the weights are multiplied by
    (``--value-scale 0.01`` for weights on a 0..100 scale)."""
    if fps is not None and not 0 < fps < math.inf:  # also NaN
        raise InputError(f"--fps must be a positive frame rate, not {fps}")
    if value_scale is not None and not 0 < value_scale < math.inf:
        raise InputError(f"--value-scale must be a positive number, not {value_scale}")
    read_notes: list[dict] = []
    matrix, header, file_fps, numbered = _read_matrix(Path(matrix_path), read_notes)
    if file_fps is not None:  # checked before a time column's unit is found from it
        _check_rate(file_fps, matrix_path, " (the rate the file gives)")
    fps, file_fps = exact_rate(fps), exact_rate(file_fps)
    if file_fps is not None and fps is not None and not math.isclose(file_fps, fps, rel_tol=1e-6):
        raise InputError(
            f"--fps {_rate(fps)} but the file says {_rate(file_fps)} frames per second", matrix_path
        )
    if names_path is not None:
        names = read_names(names_path)
        times = header[:1] if header and isinstance(header[0], _FrameTimes) else []
        columns = matrix.shape[1] - len(times)
        if len(names) != columns:
            raise InputError(_names_mismatch(names, columns, matrix_path), names_path)
        names = [*times, *names]
    elif header is not None:
        names = header
    else:
        alone = "import the file alone with --matrix, --names and --audio (--names applies only there)"
        if numbered:
            remedy = (
                "give --names, or write the names in it"
                if names_option
                else f"write the names in it, or {alone}"
            )
            raise InputError(
                f"the header row numbers the columns 0..{numbered - 1} (pandas' default) instead of naming "
                f"them: {remedy}",
                matrix_path,
            )
        remedy = (
            "give --names or a header row in the matrix CSV"
            if names_option
            else f"write a header row of channel names in the CSV, or {alone}"
        )
        raise InputError(f"no channel names: {remedy}", matrix_path)
    if len(names) != matrix.shape[1]:
        raise InputError(f"{len(names)} channel names for a matrix of {matrix.shape[1]} columns", matrix_path)
    emotions = emotion_weights(names)
    if emotions is not None:
        raise InputError(emotions, matrix_path)
    kind, clock, columns, clock_name, notes = _frame_clock(
        names, matrix, fps if fps is not None else file_fps, matrix_path
    )
    notes[:0] = read_notes
    kept = [j for j in range(len(names)) if j not in columns]
    side, said = ch.side_scores([names[j] for j in kept])
    if side:  # MediaPipe's _neutral, a generator's emotions: no face channels
        columns = sorted({*columns, *(kept[j] for j in side)})
        repair(notes, None, "side_scores", said)
    counts = [j for j, n in enumerate(names) if n.strip().lower() == COUNT_NAMES[0].lower()]
    if counts:  # a Live Link Face CSV's layout read as paired data: its count column is no channel
        columns = sorted({*columns, *counts})
        repair(
            notes,
            None,
            "count_column",
            f"column {names[counts[0]]!r} left out: the Live Link Face app's count of the values on a row, "
            "not a channel",
        )
    if columns:
        names = [n for j, n in enumerate(names) if j not in columns]
        matrix = np.delete(matrix, columns, axis=1)
        if not names:
            raise InputError("no channel columns besides the time column", matrix_path)
    if kind == "seconds" and counts_frames(clock) and fps != 1:
        if fps is None:
            raise NoFrameRate(
                f"time column {clock_name!r} steps by exactly 1 (frame numbers, not seconds?): name the "
                "column `frame`, or give --fps",
                matrix_path,
            )
        kind = "frames"
        repair(
            notes,
            None,
            "frame_numbers",
            f"time column {clock_name!r} holds whole frame numbers (steps of 1), not seconds: "
            f"read as frame numbers at {_rate(fps)} fps",
        )
    renumber = None  # a frame column numbered from N > 1 read as from 0: what --first-frame N would do
    if kind == "frames":
        if first_frame is None and clock[0] > 1:
            renumber = (
                f"frame column {clock_name!r} starts at frame {clock[0]:.0f}: if that frame is at the "
                f"audio's start, import again with --first-frame {clock[0]:.0f}"
            )
        clock = clock - _first_frame(clock, first_frame, clock_name, notes)
    elif first_frame is not None:
        without = "--first-frame applies to a frame-number column (`frame`), and it has none"
        if first_frame_strict:
            raise InputError(without, matrix_path)
        repair(notes, None, "first_frame_ignored", f"{without}: ignored")
    if value_scale is not None:
        matrix = matrix * value_scale
        repair(notes, None, "value_scale", f"values multiplied by {value_scale:g} (--value-scale)")
    detected = fps is None and file_fps is None
    rate = spread = None
    if kind == "seconds" and clock.size > 1:
        rate, spread = column_rate(clock)
    fps = fps if fps is not None else file_fps
    if fps is None and rate is not None:
        fps = nominal_rate(rate, spread)
    if fps is None:
        raise NoFrameRate("no frame rate: give --fps", matrix_path)
    _check_rate(fps, matrix_path, " (is the time column in milliseconds?)" if kind == "seconds" else "")
    if detected and rate is not None and fps < MIN_CAPTURE_FPS:
        raise NoFrameRate(
            f"time column {clock_name!r} gives {fps:g} frames per second, slower than any face capture "
            f"(below {MIN_CAPTURE_FPS:g}): is it in milliseconds (name it time_ms), or frame numbers (name "
            "it frame)? else give --fps",
            matrix_path,
        )
    if rate is not None and abs(rate / fps - 1) > STANDARD_TOLERANCE + 3 * spread:
        raise InputError(
            f"the time column's step ({1 / rate:.5g} s) does not match {_rate(fps)} frames per second (its "
            f"times keep {rate:.4g} frames per second)",
            matrix_path,
        )
    given, names = names, [channel_name(n) for n in names]
    under_affix = live_link_under_affix(given)
    if under_affix is not None:
        names, affix = under_affix
        repair(
            notes,
            None,
            "channel_affix",
            f"every channel name carries {affix} around a Live Link name ({given[0]!r}): read as "
            f"{', '.join(names[:3])}{', ...' if len(names) > 3 else ''}",
        )
    twice = repeated_name(names)
    if twice is not None:  # named as the file names them: jaw_open and blendShapes.JawOpen
        key = twice[0].strip().lower()
        first, second = [g for g, n in zip(given, names) if n.strip().lower() == key][:2]
        raise InputError(f"channels {first!r} and {second!r} are the same channel", matrix_path)
    _note_misnamed_channels(names, notes)
    with np.errstate(over="ignore"):  # beyond float32: inf, a BAD_VALUE frame
        values = matrix.astype(np.float32)
    status = np.where(np.isfinite(values).all(axis=1), FrameStatus.TRACKED, FrameStatus.BAD_VALUE).astype(
        np.uint8
    )
    time = _frame_times(kind, clock, matrix.shape[0], fps, matrix_path)
    meta = TakeMeta(
        id=safe_id(take_id or Path(matrix_path).stem),
        source_kind="paired_matrix",
        fps=float(fps),
        channels=names,
        sources=[source_file(matrix_path, "matrix")],
    )
    if names_path is not None:
        meta.sources.append(source_file(names_path, "channel_names"))
    meta.repairs.extend(notes)
    percent = _percent_scale(values)
    if percent is not None:
        repair(meta.repairs, None, "percent_scale", percent)
    bad = int((status != FrameStatus.TRACKED).sum())
    if bad:
        repair(meta.repairs, None, "bad_value", f"{bad} frames hold NaN/inf: marked invalid")
    if kind is not None:
        time, values, status, inserted = fill_dropped(time, values, status, 1 / fps)
        if inserted:
            repair(meta.repairs, None, "dropped_frames", f"{inserted} frames missing from the time column")
    take = Take(meta, time, values, status)
    audio = read_audio(audio_path, meta.repairs)
    if time[-1] < 0 or time[0] >= audio.duration_s:
        raise InputError(
            f"the frames ({time[0]:.6g}..{time[-1]:.6g} s) lie outside the audio "
            f"(0..{audio.duration_s:.3f} s)" + (f": {renumber}" if renumber else ""),
            matrix_path,
        )
    take.attach_audio(audio, 0.0, "paired_time_column" if kind == "seconds" else "paired_frame_convention")
    meta.sources.append(source_file(audio_path, "audio"))
    hint = "check --fps"
    if file_fps is not None:  # an Audio2Face export's exportFps, a .npz's fps: no --fps to check
        hint = f"check the frame rate the file gives ({_rate(fps)} fps), and that the audio is this file's"
    if renumber and time[0] > LENGTH_MISMATCH_S:
        hint = renumber
    elif kind == "seconds" and abs(paired_excess_s(take) + time[0]) <= LATE_START_S:
        hint = (
            f"the time column starts at {time[0]:.3f} s, which is where the mismatch comes from: its clock "
            "does not start with the audio (give the times from the audio's start)"
        )
    note_length_mismatch(take, hint)
    return take


def _note_misnamed_channels(names: list[str], notes: list[dict]) -> None:
    """In an ARKit layout (Live Link channels outnumber the other names), say which name that is no
    channel is close to one the file lacks (``jawOpen_L``, ``JawOpne`` without ``jawOpen``: repair
    ``channel_typo``, a warning of import), as for the app's CSV; the column keeps its name. A rig's own
    controls (FACEGOOD's ``mouth_press_l``, ``tongue_u``) are not ARKit names misspelt: not looked at."""
    known = [n for n in names if ch.is_known(n)]
    unknown = [n for n in names if not ch.is_known(n)]
    if unknown and len(known) > len(unknown):
        note_channel_typos(known, unknown, notes)


def _check_rate(fps: float, path, hint: str) -> None:
    """Refuse a frame rate outside [MIN_FPS, MAX_FPS] (also NaN), ``hint`` added to the message."""
    if not MIN_FPS <= fps <= MAX_FPS:
        raise InputError(f"the frame rate must be in [{MIN_FPS:g}, {MAX_FPS:g}], not {fps:g}{hint}", path)


def _first_frame(clock: np.ndarray, given: int | None, name: str, notes: list[dict]) -> int:
    """The frame number of a frame-number column at the audio's start: ``given`` (--first-frame), else 1
    when the column starts at 1 (timelines of Maya, Blender, iClone, Faceware: note
    ``frame_numbers_from_1``), else 0."""
    if given is not None or clock[0] != 1:
        return given or 0
    repair(
        notes,
        None,
        "frame_numbers_from_1",
        f"frame column {name!r} starts at 1: read as counting from 1 (frame 1 at the audio's "
        "start); the file cannot tell that from counting from 0 with frame 0 missing: if so, import "
        "again with --first-frame 0",
    )
    return 1


# Weights on a 0..100 scale (sliders in percent) rather than 0..1: the largest value reaches PERCENT_PEAK
# (the scale is used: not intensities on 0..5, as OpenFace's action units), none lies outside
# PERCENT_RANGE, and at least half the channels that move reach past PERCENT_CHANNEL (a 0..1 rig
# overshoots 1 by a few hundredths; head and eye angles in degrees are a handful of channels).
PERCENT_PEAK = 20.0
PERCENT_RANGE = (-5.0, 105.0)
PERCENT_CHANNEL = 1.5


# Weights stored as bytes, 0..255 (8-bit quantised exports): the largest value from BYTE_RANGE's bottom
# (past the middle of the bytes' range: not a 0..100 scale overshooting) to its top, and the same share
# of the channels that move reaching past PERCENT_CHANNEL.
BYTE_RANGE = (128.0, 255.0)


def _percent_scale(values: np.ndarray) -> str | None:
    """Why ``values`` (frames x channels) look like weights on a 0..100 scale (or 0..255), or None."""
    finite = np.isfinite(values)
    if not finite.any():
        return None
    top = np.where(finite, values, -np.inf).max(axis=0)
    low = np.where(finite, values, np.inf).min(axis=0)
    moving, large = top > 0.01, top > PERCENT_CHANNEL
    peak = top.max()
    if peak < PERCENT_PEAK or low.min() < PERCENT_RANGE[0] or peak > BYTE_RANGE[1]:
        return None
    if PERCENT_RANGE[1] < peak < BYTE_RANGE[0]:
        return None
    if 2 * large.sum() < moving.sum():
        return None
    scale, factor = ("0..100", "0.01") if peak <= PERCENT_RANGE[1] else ("0..255", "0.00392157 (1/255)")
    return (
        f"the weights look like a {scale} scale, not 0..1 (largest {peak:.4g}; {large.sum()} of the "
        f"{moving.sum()} channels that move reach past {PERCENT_CHANNEL:g}): if so, import again with "
        f"--value-scale {factor}"
    )


def paired_excess_s(take: Take) -> float:
    """How much longer (s; negative: shorter) a take's audio is than the frames it was paired with. The
    frames end one frame period after the last, on the clock align places them by (frame i at i / fps
    under the frame-index convention, a Live Link CSV's timecodes running 0.16 % slow against it); both
    are measured from the audio's start. A take read without its audio (align reads it from its file
    a block at a time) is measured by its record in meta.json."""
    info = take.meta.audio
    if info.start_source == "paired_frame_convention":
        frames_end = float(take.time[0]) + take.time.size / take.meta.fps - info.start_s
    else:
        frames_end = float(take.time[-1]) + 1 / take.meta.fps - info.start_s
    duration_s = take.audio.duration_s if take.audio is not None else info.samples / info.sample_rate
    return duration_s - frames_end


def note_length_mismatch(take: Take, hint: str) -> None:
    """Note audio more than ``LENGTH_MISMATCH_S`` longer or shorter than the frames it was paired with
    (repair ``length_mismatch``; ``hint`` says what to check)."""
    mismatch = paired_excess_s(take)
    if abs(mismatch) > LENGTH_MISMATCH_S:
        repair(
            take.meta.repairs,
            None,
            "length_mismatch",
            f"audio is {abs(mismatch):.3f} s {'longer' if mismatch > 0 else 'shorter'} than "
            f"the frames: {hint}",
        )
