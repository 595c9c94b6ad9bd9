"""Live Link Face CSV takes: a fast, forgiving reader and a writer in the app's exact format.

Format (formats doc §2): header ``Timecode,BlendShapeCount,<61 names>`` (newer builds spell the second
column ``BlendshapeCount``), rows ``HH:MM:SS:FF.fff,61,<61 values with 10 decimals>``, face-lost rows
``<timecode>,0`` (or, from other writers, a count of 0 over values that are all 0). Columns are matched
by name, case-insensitively; times come from the timecode, never from the row index. A spreadsheet's
re-save is read too: quoted fields lose their quotes, and a comma ending every line is no column.

Reading has two paths with one result. Clean files (the common case) are parsed by pyarrow's
multi-threaded CSV engine with fixed column types; anything unusual falls back to a line-by-line
parser that repairs what it can, records each repair with its line in the take's metadata, and raises
``InputError`` naming the file and line for what it cannot repair.

Repairs (each appears in ``TakeMeta.repairs`` as ``{"line", "kind", "message"}``):

============== ================================================================================
kind           what was done
============== ================================================================================
bom            a UTF-8 byte-order mark before the header was ignored
truncated_row  a last line cut short (no line end, too few fields) was dropped
wrong_fields   a row with the wrong number of fields was dropped; its slot becomes a dropped frame
bad_timecode   a row whose timecode does not parse was dropped; its slot becomes a dropped frame
bad_value      non-numeric, NaN, infinite or out-of-float32-range cells were set to NaN and the frame
               marked BAD_VALUE
bad_count      the BlendShapeCount cell was neither the row's number of values nor that of the channels
               among them (extra columns named in the header: ``blendshape_counts``); values kept
duplicate_row  a row repeating the previous row's timecode was dropped (the first one is kept)
timecode_rate  FF counts at a lower rate than the app's 60 (another writer of the format): times were
               read as FF/rate (``read_timecode_rate``); or FF fits no standard rate (read at 60)
============== ================================================================================

Notes, which ``strict=True`` lets pass (nothing was changed): ``trailing_comma`` (every line ends with a
comma), ``unknown_columns`` (header names that are not Live Link channels, kept under their own names),
``row_rate_change`` (the rows come at another rate for a while: ``note_row_rate_changes``).

Errors: missing, empty or binary file; a header that is not a Live Link Face header (one separated by
``;`` or tabs says to export it with commas), or that names a column twice or leaves one empty (saying
how to fix it); the header again further down (two files joined); no usable data rows (naming the first
rejected row); a timecode going backwards (other than across midnight) or jumping forward by more than
``MAX_GAP_S`` (a clock jump or two files joined: the app writes a row for every frame, so such a gap
would become thousands of dropped frames). ``strict=True`` turns every repair into an error as well.
"""

from __future__ import annotations

import csv
import math
import re
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import channels as ch
from .atomic import atomic_write
from .errors import InputError
from .numbers import is_finite_number
from .runs import run_bounds
from .take import FrameStatus, SourceFile, Take, TakeMeta, safe_id, source_file
from .timecode import (
    CSV_TIMECODE_RATE,
    Timecode,
    at_timecode_rate,
    parse_fixed_width,
    timecode_frames,
    timecode_rate_of,
    unwrap_midnight,
    whole_seconds,
)

COUNT_NAMES = ("BlendShapeCount", "BlendshapeCount")
VARIANTS = ("cal", "raw", "neutral")
_VARIANT_RE = re.compile(r"^(?P<prefix>.*?)(?:_(?P<variant>cal|raw|neutral))?$", re.IGNORECASE)
STANDARD_FPS = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 120.0)
# NTSC rates (N * 1000/1001), and how close a take's rate must come to one to be it rather than N.
NTSC_FPS = {std: std * 1000 / 1001 for std in (24.0, 30.0, 60.0)}
NTSC_TOLERANCE = 1e-4
_FLOAT32_MAX = float(np.finfo(np.float32).max)
MAX_GAP_S = 30.0  # a longer forward gap between rows is a clock jump (or joined files), not dropped frames


@dataclass
class CsvRows:
    """What a Live Link Face CSV holds, before it becomes a take."""

    path: Path
    count_name: str
    columns: list[str]  # value column names as written in the header
    seconds_of_day: np.ndarray  # float64, continuous across midnight
    values: np.ndarray  # float32 rows x columns, NaN where no value
    status: np.ndarray  # uint8 FrameStatus per row
    repairs: list[dict[str, Any]] = field(default_factory=list)
    line_ending: str = "\n"


def repair(repairs: list, line: int | None, kind: str, message: str) -> None:
    """Note a repair in ``repairs``: the record every importer writes to a take's ``meta.repairs``
    (``line`` is the file's line it concerns, or None for the file as a whole)."""
    repairs.append({"line": line, "kind": kind, "message": message})


_LINE_END = re.compile(r"\r\n|\r|\n")


def text_lines(text: str) -> list[str]:
    """The lines of a text file, split at ``\\n``, ``\\r\\n`` or a lone ``\\r`` only: ``str.splitlines``
    also splits at form feeds, ``\\x1c``-``\\x1e``, ``\\x85`` and ``\\u2028``, which would shift every
    later line number and cut a row holding one in two."""
    lines = _LINE_END.split(text)
    if lines[-1] == "":
        lines.pop()  # the line end closing the last line starts no line
    return lines


def _fields(line: str) -> list[str]:
    """A line's fields. A spreadsheet's re-save may quote them (``"Timecode","BlendshapeCount",...``):
    the quotes go, as the csv module reads them; the app itself never quotes."""
    if '"' not in line:
        return line.split(",")
    try:
        return next(csv.reader([line]))
    except csv.Error:  # a damaged line (a huge quoted field): the row checks say what is wrong with it
        return line.split(",")


def app_header_separator(line: str) -> str | None:
    """The separator of a line that starts like the app's header (``Timecode,BlendShapeCount``, any
    case and spacing, quoted or not, as a spreadsheet may re-save it): ``,``, or ``;`` or a tab from a
    spreadsheet's re-save; None for any other line."""
    for sep in (",", ";", "\t"):
        cells = [c.strip().strip('"').replace(" ", "").lower() for c in line.split(sep)[:2]]
        if cells == ["timecode", "blendshapecount"]:
            return sep
    return None


def _parse_header(text: str, path: Path) -> tuple[str, list[str], bool]:
    """Count column name, value column names, and whether every line ends with a comma (a spreadsheet's
    re-save: that empty last column is no column, when the rows leave it empty too)."""
    names = [c.strip() for c in _fields(text.rstrip("\r\n"))]
    if len(names) < 3 or names[0].lower() != "timecode" or names[1].lower() != "blendshapecount":
        sep = app_header_separator(text)
        if sep is not None:
            raise InputError(
                f"a Live Link Face CSV re-saved with {sep!r} between the fields (a spreadsheet in a "
                "decimal-comma locale?): export it with commas between the fields and '.' as the "
                "decimal point, as the app writes it",
                path,
                1,
            )
        shown = text[:60].encode("unicode_escape").decode("ascii")
        raise InputError(
            "not a Live Link Face CSV: the header must start with Timecode,BlendShapeCount "
            f"(found {shown!r})",
            path,
            1,
        )
    trailing_comma = len(names) > 3 and names[-1] == ""
    values = names[2:-1] if trailing_comma else names[2:]
    if "" in values:
        column = values.index("") + 3
        raise InputError(
            f"header leaves column {column} empty: name it, or delete that column from every row", path, 1
        )
    # one channel under two spellings (JawOpen and jaw_open) is a column named twice too
    keys = [ch.canonical(n) if ch.is_known(n) else n.lower() for n in values]
    dupes = sorted({n for n, key in zip(values, keys) if keys.count(key) > 1})
    if dupes:
        raise InputError(f"header names a column twice: {dupes}: rename or delete one of each", path, 1)
    return names[1], values, trailing_comma


def blendshape_counts(columns: list[str]) -> set[int]:
    """The ``BlendShapeCount`` a row of these value columns may carry: the number of values, or, with
    columns past the channels named in the header (``HeadX``...), the number of channels among them."""
    channels = sum(ch.is_known(c) for c in columns)
    return {len(columns), channels} if channels else {len(columns)}


def _read_head(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except IsADirectoryError:
        raise InputError("is a folder, not a CSV file", path) from None
    if not head.strip():
        raise InputError("file is empty", path)
    if b"\x00" in head:
        raise InputError("binary data, not a CSV text file", path, 1)
    return head


def read_csv_rows(path: str | Path, strict: bool = False) -> CsvRows:
    """Parse a Live Link Face CSV into rows (times of day in seconds, values, per-row status)."""
    path = Path(path)
    head = _read_head(path)
    first, _, rest = head.partition(b"\n")
    # pyarrow reading no rows can abort the process at exit (apache/arrow#38676): the careful parser
    # reports a file without data rows.
    if not head.startswith(b"\xef\xbb\xbf") and b"\r" not in head and rest.strip():
        try:
            count_name, columns, trailing_comma = _parse_header(first.decode("utf-8"), path)
        except UnicodeDecodeError:
            raise InputError("binary data, not a CSV text file", path, 1) from None
        rows = None if trailing_comma else _read_fast(path, count_name, columns)
        if rows is not None:
            return rows
    return _read_careful(path, strict)


def _read_fast(path: Path, count_name: str, columns: list[str]) -> CsvRows | None:
    """pyarrow path for well-formed files; ``None`` sends the file to the careful parser."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    face_lost: list[str] = []
    other_invalid = []

    def on_invalid(row: Any) -> str:
        text = row.text or ""
        parts = text.split(",")
        if len(parts) == 2 and parts[1].strip() == "0":
            face_lost.append(parts[0])
        else:
            other_invalid.append(text)
        return "skip"

    names = ["tc", "count"] + [f"v{i}" for i in range(len(columns))]
    # Parsed as float64 and narrowed on the copy below: pyarrow parses doubles faster than floats, and
    # the careful parser rounds the same way (decimal -> double -> float32).
    types = {n: pa.float64() for n in names[2:]}
    types["tc"] = pa.string()
    types["count"] = pa.int32()
    undecodable = []
    previous_hook = sys.unraisablehook
    # A row that is not UTF-8 makes pyarrow fail inside our handler; that failure only tells us to use
    # the careful parser, so keep it from being printed.
    sys.unraisablehook = undecodable.append
    try:
        # Memory-mapped, fixed types, no quoting, no UTF-8 re-validation: the least work pyarrow can do.
        # 2 MB blocks keep both cores busy to the end (16 MB blocks left one idle for the last ones: 0.76x
        # pyarrow's default read of a 176 MB hour, against 1.0-1.1x now).
        with pa.memory_map(str(path)) as source:
            table = pacsv.read_csv(
                source,
                read_options=pacsv.ReadOptions(column_names=names, skip_rows=1, block_size=1 << 21),
                parse_options=pacsv.ParseOptions(quote_char=False, invalid_row_handler=on_invalid),
                convert_options=pacsv.ConvertOptions(
                    column_types=types, strings_can_be_null=False, check_utf8=False
                ),
            )
    except (pa.ArrowException, UnicodeDecodeError, OSError):
        return None
    finally:
        sys.unraisablehook = previous_hook
    if undecodable:
        return None
    if other_invalid or table.num_rows == 0:
        return None
    if table.column("count").null_count or table.column("tc").null_count:
        return None
    counts = table.column("count").to_numpy()
    zero_filled = None  # rows of count 0: face lost, written with every value 0 (see _read_careful)
    off = counts != len(columns)
    if off.any():  # the common file has every count right: nothing more to look at
        zero_filled = counts == 0
        if not np.isin(counts[off & ~zero_filled], list(blendshape_counts(columns))).all():
            return None
    tc = table.column("tc").combine_chunks()
    offsets = np.frombuffer(tc.buffers()[1], dtype=np.int32)[tc.offset : tc.offset + len(tc) + 1]
    data = np.frombuffer(tc.buffers()[2], dtype=np.uint8)
    if not np.all(np.diff(offsets) == 15):
        return None
    tracked_t = parse_fixed_width(data[offsets[0] : offsets[-1]].reshape(-1, 15))
    if tracked_t is None:
        return None
    # Column-major, so that each parsed column lands in one contiguous copy.
    values = np.empty((table.num_rows, len(columns)), dtype=np.float32, order="F")
    for i in range(len(columns)):
        col = table.column(i + 2)
        if col.null_count:
            return None
        start = 0
        for chunk in col.chunks:  # copy chunk by chunk: no concatenated temporary per column
            with np.errstate(over="ignore"):  # beyond float32 becomes inf: the careful parser repairs it
                values[start : start + len(chunk), i] = chunk.to_numpy(zero_copy_only=False)
            start += len(chunk)
    if not np.isfinite(values).all():
        return None
    status = np.zeros(table.num_rows, dtype=np.uint8)
    if zero_filled is not None and zero_filled.any():
        if np.any(values[zero_filled] != 0):
            return None  # a count of 0 over values: the careful parser notes it
        values[zero_filled] = np.nan
        status[zero_filled] = FrameStatus.FACE_LOST
    if face_lost:
        lost_chars = np.frombuffer("".join(face_lost).encode("ascii", "replace"), dtype=np.uint8)
        if any(len(s) != 15 for s in face_lost):
            return None
        lost_t = parse_fixed_width(lost_chars.reshape(-1, 15))
        if lost_t is None:
            return None
        # Rows of either kind interleave in the file; the (unwrapped) timecode restores their order.
        all_t = np.concatenate([tracked_t, lost_t])
        is_lost = np.concatenate([np.zeros(tracked_t.size, bool), np.ones(lost_t.size, bool)])
        order = _file_order(tracked_t, lost_t)
        if order is None:
            return None
        tracked_t = all_t[order]
        is_lost = is_lost[order]
        full = np.full((order.size, len(columns)), np.nan, dtype=np.float32)
        full[~is_lost] = values
        values = full
        full_status = np.full(order.size, FrameStatus.FACE_LOST, dtype=np.uint8)
        full_status[~is_lost] = status
        status = full_status
    t = unwrap_midnight(tracked_t)
    if t.size > 1 and not (np.all(np.diff(t) > 0) and np.diff(t).max() <= MAX_GAP_S):
        return None
    return CsvRows(path, count_name, columns, t, values, status)


def _file_order(tracked: np.ndarray, lost: np.ndarray) -> np.ndarray | None:
    """Merge order of two row kinds by time; ``None`` when a midnight wrap makes it ambiguous."""
    both = np.concatenate([tracked, lost])
    if both.size and both.max() - both.min() > 43200:
        return None
    return np.argsort(both, kind="stable")


def _read_careful(path: Path, strict: bool) -> CsvRows:
    raw = path.read_bytes()
    repairs: list[dict[str, Any]] = []
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
        repair(repairs, 1, "bom", "UTF-8 byte-order mark before the header ignored")
    line_ending = "\r\n" if b"\r\n" in raw[:65536] else "\n"
    text = raw.decode("utf-8", errors="replace")
    ends_with_newline = text.endswith(("\n", "\r"))
    lines = text_lines(text)
    if not lines or "\ufffd" in lines[0]:
        raise InputError("binary data, not a CSV text file", path, 1)
    count_name, columns, trailing_comma = _parse_header(lines[0], path)
    ncols = len(columns) + 2
    counts = {str(n) for n in blendshape_counts(columns)}
    times: list[float] = []
    rows: list[list[float] | None] = []
    status: list[int] = []
    line_numbers: list[int] = []
    last = len(lines)
    comma_rows = 0  # rows whose comma ending the line was dropped (``trailing_comma``)
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue  # empty lines carry nothing (pyarrow's fast path skips them too)
        if line.strip() == lines[0].strip():
            raise InputError(
                "the header repeats here: two recordings joined into one file? Split it at this line",
                path,
                number,
            )
        fields = _fields(line)
        if trailing_comma and len(fields) == ncols + 1 and fields[-1].strip():
            raise InputError(
                "the header's last column is empty but this row has a value there: name it in the header, "
                "or delete that column from every row",
                path,
                number,
            )
        if trailing_comma and len(fields) in (3, ncols + 1) and not fields[-1].strip():
            fields.pop()  # the comma ending every line, a face-lost row's too
            comma_rows += 1
        lost = len(fields) == 2 and fields[1].strip() == "0"
        if not lost and len(fields) != ncols:
            if number == last and not ends_with_newline and len(fields) < ncols:
                repair(
                    repairs,
                    number,
                    "truncated_row",
                    f"last row cut short ({len(fields)} of {ncols} fields) dropped",
                )
            else:
                repair(
                    repairs,
                    number,
                    "wrong_fields",
                    f"row has {len(fields)} fields, expected {ncols}: dropped",
                )
            continue
        try:
            tod = Timecode.parse(fields[0]).seconds_of_day
        except ValueError as exc:
            repair(repairs, number, "bad_timecode", f"{exc}: row dropped")
            continue
        vals: list[float] = []
        if not lost:
            try:
                if not plain_number(line):
                    raise ValueError
                vals = [float(x) for x in fields[2:]]
            except ValueError:
                vals = [_cell_value(x) for x in fields[2:]]
        count = fields[1].strip()
        # Count 0 is the app's face-lost marker; a writer that fills the row with zeros means the same
        if lost or (count == "0" and all(v == 0 for v in vals)):
            times.append(tod)
            rows.append(None)
            status.append(FrameStatus.FACE_LOST)
            line_numbers.append(number)
            continue
        row_status = FrameStatus.TRACKED
        if count not in counts:
            expected = " or ".join(sorted(counts, key=int))
            message = f"{count_name} is {count!r} but the row has {len(columns)} values ({expected} expected)"
            repair(repairs, number, "bad_count", message)
        bad = [columns[i] for i, v in enumerate(vals) if not abs(v) <= _FLOAT32_MAX]
        if bad:
            vals = [v if abs(v) <= _FLOAT32_MAX else math.nan for v in vals]
            row_status = FrameStatus.BAD_VALUE
            repair(
                repairs,
                number,
                "bad_value",
                f"non-numeric, non-finite or out-of-range value in {', '.join(bad[:5])}"
                + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
                + ": set to NaN, frame marked invalid",
            )
        times.append(tod)
        rows.append(vals)
        status.append(row_status)
        line_numbers.append(number)
    if strict and repairs:
        first = repairs[0]
        raise InputError(f"{first['message']} (strict mode)", path, first["line"])
    if not times:
        rejected = [r for r in repairs if r["kind"] != "bom"]
        if rejected:
            first = rejected[0]
            raise InputError(f"no usable data rows; the first: {first['message']}", path, first["line"])
        raise InputError("no data rows after the header", path)
    t = unwrap_midnight(np.asarray(times))
    values = np.full((len(rows), len(columns)), np.nan, dtype=np.float32)
    for i, r in enumerate(rows):
        if r is not None:
            values[i] = r
    st = np.asarray(status, dtype=np.uint8)
    keep = np.ones(t.size, dtype=bool)
    for i in np.flatnonzero(np.diff(t) <= 0) + 1:
        prev = i - 1
        while not keep[prev]:
            prev -= 1
        if t[i] == t[prev]:
            same = np.array_equal(values[i], values[prev], equal_nan=True)
            keep[i] = False
            repair(
                repairs,
                line_numbers[i],
                "duplicate_row",
                "row repeats the previous timecode"
                + (" with the same values" if same else " with different values")
                + f" (line {line_numbers[prev]}): dropped",
            )
            if strict:
                raise InputError("duplicate timecode (strict mode)", path, line_numbers[i])
        elif t[i] < t[prev]:
            raise InputError(
                f"timecode {fields_tc(t[i])} goes back from {fields_tc(t[prev])} on line "
                f"{line_numbers[prev]} (a clock jump?); split the file there or fix the timecodes",
                path,
                line_numbers[i],
            )
    kept = np.flatnonzero(keep)
    gaps = np.diff(t[kept])
    if gaps.size and gaps.max() > MAX_GAP_S:
        a, b = kept[np.argmax(gaps)], kept[np.argmax(gaps) + 1]
        raise InputError(
            f"timecode {fields_tc(t[b])} jumps {gaps.max():,.0f} s forward from {fields_tc(t[a])} on line "
            f"{line_numbers[a]} (a clock jump, or files joined?); gaps over {MAX_GAP_S:g} s are refused: "
            "split the file there or fix the timecodes",
            path,
            line_numbers[b],
        )
    if trailing_comma:  # after the strict check: nothing was changed, so strict mode reads it too
        lines_with = "every line ends" if comma_rows else "the header ends"
        repair(repairs, 1, "trailing_comma", f"{lines_with} with a comma: no column, ignored")
    return CsvRows(path, count_name, columns, t[keep], values[keep], st[keep], repairs, line_ending)


def plain_number(text: str) -> bool:
    """Whether ``float()`` may read ``text`` (a cell, or a row of them): it reads ``1_0`` as 10.0 and
    U+0661 (an Arabic-Indic one) as 1.0, which no writer of numbers means; ASCII without ``_`` only."""
    return "_" not in text and text.isascii()


def _cell_value(text: str) -> float:
    """A value cell as a float; NaN when it is not a plain decimal number of ASCII digits."""
    try:
        return float(text) if plain_number(text) else math.nan
    except ValueError:
        return math.nan


def fields_tc(seconds_of_day: float) -> str:
    return Timecode.from_seconds(seconds_of_day).format()


# A measured rate this close (relative) to a standard rate is that rate: the app writes 59.90 rows/s for 60.
STANDARD_TOLERANCE = 0.03


def nearest_standard(rate: float) -> float | None:
    """The standard frame rate nearest ``rate`` when within ``STANDARD_TOLERANCE`` of it (24 and 25 are
    4 % apart: the nearest, not the first), else None."""
    std = min(STANDARD_FPS, key=lambda s: abs(rate / s - 1))
    return std if abs(rate - std) / std < STANDARD_TOLERANCE else None


def detect_fps(times: np.ndarray) -> tuple[float, float]:
    """Nominal frame rate and the measured median frame period (s) from row times.

    The nominal rate snaps to the nearest standard rate when within 3 % (the app writes 59.90 rows/s for
    "60"). The phone's own rates are 30 and 60 (formats doc §0.11): a Live Link Face take whose rows come
    at 59.94/s is a "60" take, as one at 59.90/s is. (Paired data from video tools, whose times may keep
    an NTSC rate, is measured by ``paired.column_rate``.)
    """
    if times.size < 2:
        return 60.0, 1 / 60.0
    period = float(np.median(np.diff(times)))
    rate = 1.0 / period
    return nearest_standard(rate) or round(rate, 3), period


def missing_frames(times: np.ndarray, period: float) -> np.ndarray:
    """The DROPPED frames each gap between consecutive ``times`` needs: gaps longer than 1.5 frame
    periods, rounded to whole periods (float, so that a corrupt clock's huge gap cannot overflow)."""
    steps = np.diff(times)
    return np.where(steps > 1.5 * period, np.rint(steps / period) - 1, 0.0)


# Row steps a change of the row rate must hold to be one (a second at the app's 60 rows/s): dropped rows
# here and there, or a burst of them, are no change of rate.
RATE_CHANGE_ROWS = 60


def row_rate_changes(times: np.ndarray, period: float) -> list[tuple[int, int, float]]:
    """Stretches of rows that come at another rate than one per ``period`` (an app that goes from 60 to 30
    rows/s mid-take): ``(first row, last row, rows per second)`` each. A stretch is where most of every
    ``RATE_CHANGE_ROWS`` consecutive row steps are not one period long."""
    steps = np.diff(times)
    if steps.size < RATE_CHANGE_ROWS:
        return []
    off_rate = np.abs(steps / period - 1) >= 0.5
    counted = np.concatenate([[0], np.cumsum(off_rate)])
    need = RATE_CHANGE_ROWS // 2 + 1  # off-rate steps that make a window of steps "off"
    off = counted[RATE_CHANGE_ROWS:] - counted[:-RATE_CHANGE_ROWS] >= need
    # So the first window off ends ``need`` steps into a stretch, the last starts ``need`` before its end.
    stretches = []
    for start, stop in zip(*run_bounds(off)):
        first = 0 if start == 0 else start + RATE_CHANGE_ROWS - need
        last = times.size - 1 if stop == off.size else stop - 1 + need
        rate = (last - first) / (times[last] - times[first])
        stretches.append((int(first), int(last), nearest_standard(rate) or round(rate, 1)))
    return stretches


def note_row_rate_changes(times: np.ndarray, fps: float, period: float, repairs: list) -> None:
    """Say where the rows come at another rate than the take's (repair ``row_rate_change``). The frames
    stay as they are: a slower stretch's rows with DROPPED frames between them."""
    stretches = row_rate_changes(times, period)
    for first, last, rate in stretches[:3]:
        until = "the end" if last == times.size - 1 else f"{times[last] - times[0]:.1f} s"
        gaps = int(missing_frames(times[first : last + 1], period).sum())
        repair(
            repairs,
            None,
            "row_rate_change",
            f"rows come at {rate:g}/s, not {fps:g}/s, from about {times[first] - times[0]:.1f} s "
            f"({fields_tc(times[first])}) to {until}"
            + (f": {gaps} DROPPED frames between them" if gaps else ""),
        )
    if len(stretches) > 3:
        repair(repairs, None, "row_rate_change", f"and {len(stretches) - 3} more changes of the row rate")


def fill_dropped(
    times: np.ndarray, values: np.ndarray, status: np.ndarray, period: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Insert DROPPED placeholder frames (NaN values) into gaps longer than 1.5 frame periods.

    Returns the new times, values, status and the number of frames inserted.
    """
    if times.size < 2:
        return times, values, status, 0
    steps = np.diff(times)
    missing = missing_frames(times, period).astype(np.int64)
    total = int(missing.sum())
    if total == 0:
        return times, values, status, 0
    reps = np.ones(times.size, dtype=np.int64)
    reps[:-1] += missing
    start = np.repeat(times, reps)
    offset = np.arange(start.size) - np.repeat(np.cumsum(reps) - reps, reps)
    step = np.repeat(np.append(steps / (missing + 1), 0.0), reps)
    new_t = start + offset * step
    is_orig = offset == 0
    new_v = np.full((new_t.size, values.shape[1]), np.nan, dtype=np.float32)
    new_v[is_orig] = values
    new_s = np.full(new_t.size, FrameStatus.DROPPED, dtype=np.uint8)
    new_s[is_orig] = status
    return new_t, new_v, new_s, total


def split_variant(stem: str) -> tuple[str, str | None]:
    """``MySlate_166_iPhone_cal`` → (``MySlate_166_iPhone``, ``cal``)."""
    m = _VARIANT_RE.match(stem)
    assert m is not None
    variant = m.group("variant")
    return m.group("prefix"), variant.lower() if variant else None


def read_timecode_rate(rows: CsvRows, rate: float | None = None) -> float:
    """The rate the CSV's FF field counts at: ``rate`` if given, else the one ``timecode_rate_of``
    finds. Rows counted at another rate than the app's 60 get their times re-read at it (repair
    ``timecode_rate``); a rate FF passes is an ``InputError``."""
    t = rows.seconds_of_day
    top = float(timecode_frames(t)[1].max())
    if rate is None:
        rate = timecode_rate_of(t)
        seen = f"FF never passes {top:.3f} over {whole_seconds(t)} whole seconds"
        if rate is None:
            repair(
                rows.repairs,
                None,
                "timecode_rate",
                f"{seen}, which fits no standard timecode rate: read at {CSV_TIMECODE_RATE:g} fps "
                "(give the writer's rate with --timecode-rate)",
            )
            return CSV_TIMECODE_RATE
    elif top >= rate:
        raise InputError(
            f"timecode frames (FF) reach {top:.3f}: they do not count at {rate:g} fps", rows.path
        )
    else:
        seen = "as asked"
    if rate != CSV_TIMECODE_RATE:
        rows.seconds_of_day = at_timecode_rate(t, rate)
        message = f"timecode frames (FF) count at {rate:g} fps, not the app's {CSV_TIMECODE_RATE:g} ({seen})"
        repair(rows.repairs, None, "timecode_rate", f"{message}: times read as FF/{rate:g}")
    return rate


def rows_to_take(
    rows: CsvRows,
    take_id: str | None = None,
    swap_lr: bool = False,
    source: SourceFile | None = None,
    timecode_rate: float | None = None,
) -> Take:
    """Turn parsed rows into a take: canonical channel names, take clock, dropped frames filled in.

    ``rows`` is consumed (its value array is reordered in place, its times re-read at the rate its FF
    counts at: ``timecode_rate``, None to detect it). ``source`` is the file's provenance record,
    computed here when not given.
    """
    tc_rate = read_timecode_rate(rows, timecode_rate)
    known = [c for c in rows.columns if ch.is_known(c)]
    unknown = [c for c in rows.columns if not ch.is_known(c)]
    names = [ch.canonical(c) for c in known]
    if swap_lr:
        names = ch.swap_left_right(names)
    order = sorted(range(len(known)), key=lambda i: ch.udp_index(names[i]))
    col_of = {c: i for i, c in enumerate(rows.columns)}
    channels = [names[i] for i in order] + unknown
    take_cols = [col_of[known[i]] for i in order] + [col_of[c] for c in unknown]
    # Reorder columns in place: only the few that move are copied (a whole copy of an hour-long take
    # would cost as much as parsing it).
    take_cols_arr = np.asarray(take_cols)
    moved = np.flatnonzero(take_cols_arr != np.arange(take_cols_arr.size))
    values = rows.values
    if moved.size:
        values[:, moved] = values[:, take_cols_arr[moved]]
    tracked = rows.status == FrameStatus.TRACKED
    fps, period = detect_fps(rows.seconds_of_day[tracked] if tracked.sum() > 1 else rows.seconds_of_day)
    t, v, st, dropped = fill_dropped(rows.seconds_of_day, values, rows.status, period)
    t0 = float(t[0])
    prefix, variant = split_variant(rows.path.stem)
    slate, take_number, subject = parse_take_prefix(prefix)
    repairs = list(rows.repairs)
    if unknown:
        repair(repairs, 1, "unknown_columns", f"columns kept under their own names: {unknown}")
    note_row_rate_changes(rows.seconds_of_day, fps, period, repairs)  # else seen only as dropped frames
    meta = TakeMeta(
        id=safe_id(take_id or rows.path.stem),
        source_kind="livelink_csv",
        fps=fps,
        channels=channels,
        slate=slate,
        take_number=take_number,
        subject=subject,
        start_timecode=Timecode.from_seconds(t0).format(),
        timecode_rate=CSV_TIMECODE_RATE,
        sources=[source or source_file(rows.path, "blendshapes_csv")],
        repairs=repairs,
        csv={
            "count_name": rows.count_name,
            "variant": variant,
            "columns": rows.columns,
            "swapped_left_right": swap_lr,
            "line_ending": "crlf" if rows.line_ending == "\r\n" else "lf",
            "rows": int(rows.seconds_of_day.size),
            "start_seconds_of_day": t0,
            "measured_fps": round(1.0 / period, 4),
            "timecode_rate": tc_rate,
        },
    )
    meta.extra["dropped_frames_inserted"] = dropped
    return Take(meta, t - t0, v, st)


def parse_take_prefix(prefix: str) -> tuple[str | None, int | None, str | None]:
    """Slate, take number and subject from the app's ``{slate}_{take}_{subject}`` file prefix."""
    m = re.match(r"^(?P<slate>.+)_(?P<take>\d+)_(?P<subject>[^_]+)$", prefix)
    if not m:
        return None, None, None
    return m.group("slate"), int(m.group("take")), m.group("subject")


def read_livelink_csv(
    path: str | Path,
    take_id: str | None = None,
    strict: bool = False,
    swap_lr: bool = False,
    timecode_rate: float | None = None,
) -> Take:
    """Read one Live Link Face CSV (plain, ``_cal``, ``_raw`` or ``_neutral``) as a take; its FF field
    counts at ``timecode_rate`` fps (None: detected, see ``read_timecode_rate``)."""
    with ThreadPoolExecutor(1) as pool:
        # hashlib releases the GIL, so the checksum runs beside the parse.
        digest = pool.submit(source_file, path, "blendshapes_csv")
        rows = read_csv_rows(path, strict)
        take = rows_to_take(rows, take_id, swap_lr, digest.result(), timecode_rate)
    detected = [r for r in take.meta.repairs if r["kind"] == "timecode_rate"]
    if strict and timecode_rate is None and detected:  # a guess, which strict mode does not make
        raise InputError(f"{detected[0]['message']} (strict mode: give --timecode-rate)", path)
    return take


def _malformed_meta(take: Take, field: str, value: Any, what: str) -> InputError:
    """The error for a meta.json field ``write_livelink_csv`` cannot use (the take folder was edited)."""
    return InputError(
        f"take {take.meta.id}: malformed metadata: meta.json {field} must be {what}, not {value!r:.60}"
    )


def start_seconds_of_day(take: Take) -> float:
    """Time of day (s) of the take's first frame: the source CSV's, else the start timecode's, else 0.
    ``InputError`` naming the meta.json field when the one used is not a number or a timecode."""
    t0 = (take.meta.csv or {}).get("start_seconds_of_day")
    if t0 is not None:
        if not is_finite_number(t0):
            raise _malformed_meta(take, "csv.start_seconds_of_day", t0, "a finite number of seconds or null")
        return float(t0)
    if not take.meta.start_timecode:
        return 0.0
    try:
        return Timecode.parse(take.meta.start_timecode).seconds_of_day
    except ValueError:
        raise _malformed_meta(
            take, "start_timecode", take.meta.start_timecode, "HH:MM:SS:FF.fff or null"
        ) from None


def _csv_columns(take: Take) -> tuple[list[str], list[int | None]]:
    """The CSV's value columns in the app's order, and for each the take's column (None: missing)."""
    csv_info = take.meta.csv or {}
    out_names = list(ch.CSV_ORDER)
    # Undo an import-time label swap so that the written file matches the source column for column.
    label_names = ch.swap_left_right(ch.ARKIT61) if csv_info.get("swapped_left_right") else list(ch.ARKIT61)
    canon_to_col = {}
    for j, name in enumerate(take.meta.channels):
        if ch.is_known(name):
            canon_to_col[ch.canonical(name)] = j
    return out_names, [canon_to_col.get(ch.canonical(label_names[ch.udp_index(n)])) for n in out_names]


_WITH_VALUES = (int(FrameStatus.TRACKED), int(FrameStatus.INTERPOLATED))


def nonfinite_frames(take: Take) -> np.ndarray:
    """Frames ``write_livelink_csv`` would write with values but which hold a NaN or infinite value in
    a written channel: it writes them as ``<timecode>,0`` rows instead (boolean mask)."""
    cols = [j for j in _csv_columns(take)[1] if j is not None]
    finite = np.isfinite(take.values[:, cols]).all(axis=1)
    return np.isin(take.frame_status, _WITH_VALUES) & ~finite


def write_livelink_csv(
    take: Take,
    path: str | Path,
    count_name: str | None = None,
    fill_missing: float | None = 0.0,
) -> Path:
    """Write ``take`` as a Live Link Face CSV in the app's exact format.

    61 value columns in the app's CSV order with 10 decimals, ``Timecode`` from the take's start
    timecode plus frame time, tracked frames and the frames ``s2a-align`` interpolated across short gaps
    with their values (they are usable, and Epic's importer stops at the first face-lost row), face-lost
    and other invalid frames as ``<timecode>,0`` rows, dropped frames left out (as the app does).
    A frame with a NaN or infinite value in a written channel is a ``<timecode>,0`` row too
    (``nonfinite_frames``): the app never writes a partial row, and a ``nan`` cell is not its format.
    Channels the take lacks are written as ``fill_missing`` (or raise if ``None``). ``count_name``
    defaults to the spelling of the source file, else ``BlendShapeCount``; a meta.json that gives
    another name is an ``InputError``.
    """
    path = Path(path)
    if not count_name:
        count_name = (take.meta.csv or {}).get("count_name") or COUNT_NAMES[0]
        # the source header's spelling, in any case (as _parse_header reads it)
        if not isinstance(count_name, str) or count_name.lower() != COUNT_NAMES[0].lower():
            raise _malformed_meta(
                take, "csv.count_name", count_name, f"{COUNT_NAMES[0]} in any case, or null"
            )
    out_names, cols = _csv_columns(take)
    missing = [name for name, j in zip(out_names, cols) if j is None]
    if missing and fill_missing is None:
        raise InputError(f"take lacks channels for a Live Link Face CSV: {missing}")
    block = np.full((take.time.size, len(out_names)), fill_missing or 0.0, dtype=np.float32)
    for k, j in enumerate(cols):
        if j is not None:
            block[:, k] = take.values[:, j]
    t0 = start_seconds_of_day(take)
    row_fmt = "%s," + str(len(out_names)) + "," + ",".join(["%.10f"] * len(out_names)) + "\n"
    dropped = int(FrameStatus.DROPPED)
    usable = (np.isin(take.frame_status, _WITH_VALUES) & ~nonfinite_frames(take)).tolist()
    status, times = take.frame_status.tolist(), (t0 + take.time).tolist()
    with atomic_write(path, "w", encoding="ascii", newline="") as f:
        f.write("Timecode," + count_name + "," + ",".join(out_names) + "\n")
        for start in range(0, len(times), 4096):  # in blocks: bounded memory for hour-long takes
            lines = []
            for i, row in enumerate(block[start : start + 4096].tolist(), start):
                if status[i] == dropped:
                    continue
                tc = Timecode.from_seconds(times[i]).format()
                lines.append(row_fmt % (tc, *row) if usable[i] else tc + ",0\n")
            f.writelines(lines)
    return path
