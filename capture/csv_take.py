"""Live Link Face CSV takes: a fast, forgiving reader and a writer in the app's exact format.

Format (formats doc §2): header ``Timecode,BlendShapeCount,<61 names>`` (newer builds spell the second
column ``BlendshapeCount``), rows ``HH:MM:SS:FF.fff,61,<61 values with 10 decimals>``, face-lost rows
``<timecode>,0`` (or, from other writers, a count of 0 over values that are all 0). Columns are matched
by name, case-insensitively; times come from the timecode, never from the row index. A spreadsheet's
re-save is read too: quoted fields lose their quotes, and a comma ending every line is no column; one with
``;`` between the fields (a locale with decimal commas: Excel's and LibreOffice's CSV), or tabs (their
"Text (Tab delimited)", a TSV export), is converted once into the app's layout, its numbers read with the
decimal mark they are written with (``_resaved_lines``), and read as the app's CSV is (``_read_resaved``);
its messages quote its own cells.

Face-lost rows as pandas and spreadsheets re-save them (``<timecode>,0.0``, ``<timecode>,0,,,...``) are
face-lost rows too, a count written ``61.0`` is 61, and rows of nothing but commas are blank lines.

Reading has two paths with one result. Clean files (the common case) are parsed by pyarrow's
multi-threaded CSV engine with fixed column types; the careful parser reads line by line, repairs what
it can, records each repair with its line in the take's metadata, and raises ``InputError`` naming the
file and line for what it cannot repair. A long file with a few damaged rows takes both: pyarrow reads
the rows it can, the careful parser's per-row logic only the lines pyarrow cannot take (``_read_mended``),
so that a cut-short last line costs what the intact file does; a cell of a number's bytes that is no
number (``-``, ``0.1.2``, ``1e``: pyarrow names it, a scan of the file finds its lines) and a channel no
row fills are read so too. Files a spreadsheet or script re-saved whole (a BOM, CRLF, a comma ending
every line, pandas' index column, quoted header names, every cell or the timecodes in quotes) are read so
too, and so are quotes first met further on (later rows re-saved, a quoted cell here and there); a line
ending at a lone CR, or more than half the lines to read line by line, sends a file to the careful parser
whole. pyarrow reads a long file a part at a time (``PART_BYTES``), with quoting on in the parts holding a
quote, writing each part's values into one array and giving back its mapped pages once read, so that the
parse of an hour holds little more than its result.

Repairs (each appears in ``TakeMeta.repairs`` as ``{"line", "kind", "message"}``):

============== ================================================================================
kind           what was done
============== ================================================================================
bom            a UTF-8 byte-order mark before the header was ignored
separator      ``;`` (a spreadsheet's re-save in a locale with decimal commas) or tabs between the fields:
               read so, numbers with ``,`` as the decimal point when they are written so (all of them),
               else ``.``; a timecode's sub-frame after a comma (``44,643``) as after a point
truncated_row  a last line cut short (no line end, too few fields) was dropped
wrong_fields   a row with the wrong number of fields was dropped; its slot becomes a dropped frame
bad_timecode   a row whose timecode does not parse was dropped; its slot becomes a dropped frame
bad_value      non-numeric, NaN, infinite or out-of-float32-range cells were set to NaN and the frame
               marked BAD_VALUE
bad_count      the BlendShapeCount cell was neither the row's number of values nor that of the channels
               among them (extra columns named in the header: ``blendshape_counts``); values kept
duplicate_row  a row repeating the previous row's timecode was dropped (the first one is kept)
number_format  cells written as a spreadsheet's locale writes numbers were read (one note for each way,
               a cell written two ways counts in both): a quoted decimal comma (``"0,1421"``), a U+2212
               minus sign, no-break or narrow spaces
timecode_format timecodes without zero padding (``12:28:1:03.060``) were read (one note); FF at 60.000
               (never the app's) was read as the next second's frame 0 (another note); clock times
               ``HH:MM:SS.fff`` (another writer's) were read as seconds (another note); ``FF.mmm`` with
               the milliseconds of the second after the dot on every row (NeuroSync Player's) was read as
               seconds and milliseconds (another note)
index_column   pandas' index column before Timecode (header ``""`` or ``Unnamed: 0``) was dropped
bad_values_widespread, bad_timecodes_widespread  most frames lost their values, or over 5 % of the rows
               their timecodes (a file read wrongly, not a damaged row: import prints it as a warning)
timecode_rate  FF counts at a lower rate than the app's 60 (another writer of the format): times were
               read as FF/rate (``read_timecode_rate``); or FF fits no standard rate (read at 60);
               or drop-frame timecodes (``HH:MM:SS;FF`` on every row, at 30 or 60) were read as frames
               counted at 29.97 or 59.94 fps from the first row's label (``drop_frame_seconds``), not
               as labels with gaps
============== ================================================================================

Notes, which ``strict=True`` lets pass (nothing was changed): ``trailing_comma`` (every line ends with a
comma), ``unknown_columns`` (header names that are not Live Link channels, kept under their own names),
``row_rate_change`` (the rows come at another rate for a while: ``note_row_rate_changes``), ``text_column``
(a column that is no channel holds text: left out if it holds no number, else NaN there; never a frame's
damage), ``channel_typo`` (a column named close to a channel the header lacks), ``empty_channel``
(channels with no value on any row, as a writer of the 52 shapes alone leaves the head and eye angles:
left out, and no frame's damage; in a take of one row with values they are that frame's), ``value_range``
(channel values beyond ``VALUE_LIMIT``), ``gap`` (no rows for ``GAP_NOTE_S`` or more).

Errors: missing, empty or binary file (a run of NUL bytes to its end, as a power loss leaves, is no
binary: the row it cuts is a ``truncated_row``), or UTF-16 text, with or without its byte-order mark
(``utf16_csv_error``); a Timecode column of plain numbers (another tool's seconds or frame numbers:
import it as paired data); a header that is not a Live Link Face header, or that names a column twice or
leaves one empty (saying how to fix it); a file re-saved with ``;`` or tabs between the fields whose
numbers are written with both ``,`` and ``.`` as the decimal point; the header again further down (two
files joined); no usable data rows (naming the first rejected row); values written with unquoted decimal
commas (``0,1421`` split in two fields) on most rows; a timecode going backwards (other than across midnight)
or jumping forward by more than ``MAX_GAP_S`` (a clock jump or two files joined: the app writes a row for
every frame, so such a gap would become thousands of dropped frames). ``strict=True`` turns every repair
into an error as well.
"""

from __future__ import annotations

import csv
import math
import mmap
import re
import sys
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import channels as ch
from .atomic import atomic_write
from .errors import InputError
from .growing import GrowingRows
from .numbers import is_finite_number
from .runs import run_bounds
from .take import FrameStatus, SourceFile, Take, TakeMeta, safe_id, source_file
from .timecode import (
    CSV_TIMECODE_RATE,
    Timecode,
    at_timecode_rate,
    clock_seconds,
    drop_frame_seconds,
    fixed_width_seconds,
    millisecond_seconds,
    timecode_frames,
    timecode_rate_of,
    unwrap_midnight,
)

COUNT_NAMES = ("BlendShapeCount", "BlendshapeCount")
VARIANTS = ("cal", "raw", "neutral")
# a name may hold any character, a newline too (DOTALL; fullmatch: ``$`` matches before a last newline)
_VARIANT_RE = re.compile(r"(?P<prefix>.*?)(?:_(?P<variant>cal|raw|neutral))?", re.IGNORECASE | re.DOTALL)
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
    lines: np.ndarray | None = None  # each row's line in the file, when the careful parser read it
    drop_frame: bool = False  # every timecode written HH:MM:SS;FF, the drop-frame notation


def repair(repairs: list, line: int | None, kind: str, message: str) -> None:
    """Note a repair in ``repairs``: the record every importer writes to a take's ``meta.repairs``
    (``line`` is the file's line it concerns, or None for the file as a whole)."""
    repairs.append({"line": line, "kind": kind, "message": message})


_LINE_END = re.compile(r"\r\n|\r|\n")
UTF8_BOM = b"\xef\xbb\xbf"


def text_lines(text: str) -> list[str]:
    """The lines of a text file, split at ``\\n``, ``\\r\\n`` or a lone ``\\r`` only: ``str.splitlines``
    also splits at form feeds, ``\\x1c``-``\\x1e``, ``\\x85`` and ``\\u2028``, which would shift every
    later line number and cut a row holding one in two."""
    if "\r" not in text:
        lines = text.split("\n")  # the app's LF: str.split is 6x the regex's speed
    else:
        lines = text.split("\r\n")  # a spreadsheet's CRLF, unless a line holds a lone CR or LF
        if any("\r" in line or "\n" in line for line in lines):
            lines = _LINE_END.split(text)
    if lines[-1] == "":
        lines.pop()  # the line end closing the last line starts no line
    return lines


def _fields(line: str, sep: str = ",") -> list[str]:
    """A line's fields. A spreadsheet's re-save may quote them (``"Timecode","BlendshapeCount",...``):
    the quotes go, as the csv module reads them; the app itself never quotes."""
    if '"' not in line:
        return line.split(sep)
    try:
        return next(csv.reader([line], delimiter=sep))
    except csv.Error:  # a damaged line (a huge quoted field): the row checks say what is wrong with it
        return line.split(sep)


def _decimal_mark(cell: str) -> str | None:
    """``,`` or ``.``: the decimal mark of a cell holding a number written with one (``0,5``, ``-1.2E-05``),
    else None (a whole number, a timecode, text). Spaces around it and a U+2212 minus sign count as
    ``_cell_value`` reads them."""
    number = cell.strip().replace("\u2212", "-")
    for mark in ",.":
        if mark in number and plain_number(number):
            try:
                float(number.replace(mark, ".", 1))
            except ValueError:
                continue
            return mark
    return None


# A timecode whose sub-frame a decimal-comma locale wrote after a comma (``14:58:02:44,643``).
_COMMA_SUB_FRAME = re.compile(r"(\s*\d{1,2}:\d{1,2}:\d{1,2}[:;]\d{1,3}),(\d*\s*)", re.ASCII)


# A spreadsheet's re-save with another separator than the app's comma: ``;`` (a locale with decimal
# commas) or a tab ("Text (Tab delimited)", a TSV export), as a message names it.
RESAVE_SEPARATORS = {";": "';'", "\t": "tabs"}


def _resaved_cell(cell: str, number: int, first: dict[str, tuple[str, int]]) -> str:
    """A cell of line ``number`` of a re-saved CSV as the app writes it (``_resaved_lines``), each decimal
    mark's first number and its line noted in ``first``."""
    if (timecode := _COMMA_SUB_FRAME.fullmatch(cell)) is not None:
        cell = f"{timecode[1]}.{timecode[2]}"
    elif (mark := _decimal_mark(cell)) is not None and number > 1:
        first.setdefault(mark, (cell, number))
        cell = cell.replace(",", ".")
    return '"' + cell.replace('"', '""') + '"' if "," in cell or '"' in cell else cell


def _resaved_lines(
    lines: list[str], sep: str, path: Path, first: dict[str, tuple[str, int]], start: int = 1
) -> None:
    """Lines ``start``, ``start + 1``, ... of a CSV a spreadsheet re-saved with ``sep`` between the fields
    (``;`` in a locale with a decimal comma, or a tab: ``RESAVE_SEPARATORS``) turned, in place, into the
    app's layout: ``,`` between the fields, ``.`` for the decimal point of numbers written with ``,``
    (``0,5``; those written with ``.`` stay), a timecode's sub-frame after a point (``44,643``: a timecode's
    comma is no separator). Each decimal mark's first number and its line are noted in ``first`` (kept
    from one block of lines to the next); an ``InputError`` when the numbers are written with both marks
    (which one a cell means is a guess)."""
    for i, line in enumerate(lines):
        number = start + i
        head, found, numbers = line.partition(sep)
        # a row as nearly all are: no quotes, the cells after its first (count, values) holding no decimal
        # mark but that of the numbers met (read cell by cell, below): two replaces do what the cells one by
        # one would (a cell no number, "0,5x", is none either way; messages quote the file's own cells)
        if (
            number > 1
            and found
            and '"' not in line
            and all(mark in first for mark in ",." if mark in numbers)
        ):
            lines[i] = _resaved_cell(head, number, first) + "," + numbers.replace(",", ".").replace(sep, ",")
        else:
            lines[i] = ",".join(_resaved_cell(cell, number, first) for cell in _fields(line, sep))
        if len(first) == 2:
            (comma, at_comma), (point, at_point) = first[","], first["."]
            raise InputError(
                f"re-saved with {RESAVE_SEPARATORS[sep]} between the fields, its numbers written with both "
                f"',' ({_shown(comma)} on line {at_comma}) and '.' ({_shown(point)} on line {at_point}) as "
                "the decimal point: "
                "export it with commas between the fields and '.' as the decimal point, as the app writes it",
                path,
                number,
            )


def _separator_note(sep: str, first: dict[str, tuple[str, int]], repairs: list) -> None:
    """Repair ``separator`` of a re-save with ``sep`` between the fields, whose numbers' decimal marks
    ``_resaved_lines`` noted in ``first``."""
    mark = "," if "," in first else "."
    between = RESAVE_SEPARATORS[sep]
    message = f"re-saved with {between} between the fields and {mark!r} as the decimal point: read so"
    repair(repairs, 1, "separator", message)


# A re-save's text is read, decoded and converted this many bytes at a time (whole lines): never held whole
TEXT_BLOCK_BYTES = 1 << 22


def _text_blocks(path: Path) -> Iterator[tuple[list[str], bool]]:
    """The lines of a text file as ``text_lines`` splits them (a UTF-8 byte-order mark left out, bytes no
    UTF-8 read as U+FFFD), a block of about ``TEXT_BLOCK_BYTES`` at a time, with whether the block's last
    line has its line end (every block's but perhaps the file's last)."""
    with open(path, "rb") as f:
        rest = f.read(len(UTF8_BOM))
        if rest == UTF8_BOM:
            rest = b""
        while True:
            chunk = f.read(TEXT_BLOCK_BYTES)
            data = rest + chunk
            cut = data.rfind(b"\n") + 1 if chunk else len(data)  # a block ends after a line's \n
            block, rest = data[:cut], data[cut:]
            if block:
                yield text_lines(block.decode("utf-8", errors="replace")), block.endswith((b"\n", b"\r"))
            if not chunk:
                return


class _WrittenLines:
    """The lines of a re-save with another separator (``RESAVE_SEPARATORS``) as the file writes them, read
    from the file a block at a time (``_text_blocks``) as messages quote their cells, in the order of
    their lines (the reader reads them converted)."""

    def __init__(self, path: Path, sep: str) -> None:
        self.path, self.sep = path, sep
        self.blocks: Iterator[tuple[list[str], bool]] = iter(())
        self.block: list[str] = []  # the block of lines read last, its first line's number ``start``
        self.start = 1

    def cell(self, number: int, index: int, converted: str) -> str:
        """Field ``index`` of line ``number`` as written, read as ``converted``."""
        if number < self.start or not self.block:  # an earlier line (the file read again): from its start
            self.blocks, self.block, self.start = _text_blocks(self.path), [], 1
        while number >= self.start + len(self.block):
            lines, _ = next(self.blocks, ([], False))
            if not lines:  # past the file's end
                return converted
            self.start, self.block = self.start + len(self.block), lines
        fields = _fields(self.block[number - self.start], self.sep)
        return fields[index] if index < len(fields) else converted


# What pandas writes above the index column of a table it saves with one (``df.to_csv()``): nothing, or
# ``Unnamed: 0`` for a table read from such a file and saved again (compared without spaces, any case).
INDEX_NAMES = ("", "unnamed:0")


def _index_name(name: str) -> bool:
    return name.strip().strip('"').replace(" ", "").lower() in INDEX_NAMES


def app_header_separator(line: str) -> str | None:
    """The separator of a line that starts like the app's header (``Timecode,BlendShapeCount``, any
    case and spacing, quoted or not, perhaps after pandas' index column, as a spreadsheet or script may
    re-save it): ``,``, or ``;`` or a tab from a spreadsheet's re-save; None for any other line."""
    for sep in (",", ";", "\t"):
        cells = [c.strip().strip('"').replace(" ", "").lower() for c in line.split(sep)[:3]]
        if len(cells) == 3 and _index_name(cells[0]):
            cells = cells[1:]
        if cells[:2] == ["timecode", "blendshapecount"]:
            return sep
    return None


_UTF16_BOMS = ((b"\xff\xfe", "utf-16-le"), (b"\xfe\xff", "utf-16-be"))


def _utf16_without_mark(head: bytes) -> str | None:
    """The codec of ASCII text saved as UTF-16 without its byte-order mark (Python's ``utf-16-le``,
    .NET's ``UnicodeEncoding`` without a preamble), from its first bytes: every other byte is NUL."""
    pairs = head[:64]
    if len(pairs) < 8 or pairs.count(0) != len(pairs) // 2:
        return None
    if not pairs[1::2].strip(b"\0"):
        return "utf-16-le"
    return "utf-16-be" if not pairs[::2].strip(b"\0") else None


def utf16_csv_error(head: bytes, path: str | Path) -> InputError | None:
    """The error for a Live Link Face CSV saved as UTF-16 text with its byte-order mark (Windows'
    "Unicode" text; Excel's "Unicode Text", which also puts tabs between the fields), from its first
    bytes; None for any other file. One message wherever the file is met: loose or in a take folder."""
    codec = next((codec for bom, codec in _UTF16_BOMS if head.startswith(bom)), None)
    start = 2
    if codec is None:
        codec, start = _utf16_without_mark(head), 0
    if codec is None:
        return None
    text = head[start : len(head) // 2 * 2].decode(codec, "replace")
    sep = app_header_separator(next((line for line in text_lines(text) if line.strip()), ""))
    if sep is None:
        return None
    if sep == "\t":
        return InputError(
            "a Live Link Face CSV saved as UTF-16 text with tabs between the fields (Excel's \"Unicode "
            'Text"): save it as CSV UTF-8, with commas between the fields (as the app writes it)',
            path,
        )
    return InputError(
        "a Live Link Face CSV saved as UTF-16 text: save it as UTF-8 (as the app writes it)", path
    )


@dataclass
class CsvHeader:
    """What a Live Link Face CSV's header says."""

    count_name: str  # BlendShapeCount as spelled
    columns: list[str]  # value column names as written
    trailing_comma: bool  # every line ends with a comma (a spreadsheet's re-save): that last column is none
    index_column: str | None = None  # pandas' index column before Timecode ("" or "Unnamed: 0"), if any


def _parse_header(text: str, path: Path) -> CsvHeader:
    """The header, or an ``InputError`` saying what is wrong with it."""
    names = [c.strip() for c in _fields(text.rstrip("\r\n"))]
    index_column = None
    if (
        len(names) > 3
        and _index_name(names[0])
        and [n.lower() for n in names[1:3]]
        == [
            "timecode",
            "blendshapecount",
        ]
    ):
        index_column = names.pop(0)  # pandas' row index (df.to_csv()): dropped from every row
    if len(names) < 3 or names[0].lower() != "timecode" or names[1].lower() != "blendshapecount":
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
    return CsvHeader(names[1], values, trailing_comma, index_column)


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
    utf16 = utf16_csv_error(head, path)
    if utf16 is not None:
        raise utf16
    if b"\x00" in head and not _zero_tail(path, head):
        raise InputError("binary data, not a CSV text file", path, 1)
    return head


def _zero_tail(path: Path, head: bytes) -> bool:
    """Whether the NUL bytes in a file's first bytes (``head``) start a run of them to its end, after
    text: what a phone's file system leaves of a recording cut by a power loss (the file's length written,
    its last blocks not). The rows before it are read, the row the run cuts is a ``truncated_row``."""
    first = head.index(b"\x00")
    if not head[:first].strip() or head[first:].count(0) != len(head) - first:
        return False
    with open(path, "rb") as f:
        f.seek(len(head))
        while block := f.read(1 << 20):
            if block.count(0) != len(block):
                return False
    return True


def read_csv_rows(path: str | Path, strict: bool = False) -> CsvRows:
    """Parse a Live Link Face CSV into rows (times of day in seconds, values, per-row status)."""
    path = Path(path)
    head = _read_head(path)
    if b"\x00" in head:  # NUL bytes from there to the end (_zero_tail): the text before, the run as one byte
        return _read_careful(path, strict, head[: head.index(b"\x00") + 1])
    bom = head.startswith(UTF8_BOM)
    first, _, rest = head[3 if bom else 0 :].partition(b"\n")
    # pyarrow reading no rows can abort the process at exit (apache/arrow#38676): the careful parser
    # reports a file without data rows. A header line ending at a lone CR is the careful parser's too.
    if b"\r" not in first[:-1] and rest.strip():
        try:
            text = first.decode("utf-8")
        except UnicodeDecodeError:
            text = "\ufffd"
        if "\ufffd" in text:  # as the careful parser decodes it: a header of replacement characters
            raise InputError("binary data, not a CSV text file", path, 1)
        sep = app_header_separator(text)
        if sep in RESAVE_SEPARATORS:  # a spreadsheet's re-save: converted, then read as the app's CSV
            rows = None if strict else _read_resaved(path, sep, bom, head)
            return rows if rows is not None else _read_careful(path, strict)
        header = _parse_header(text, path)
        rows = _read_fast(path, header, bom, len(first) + 1, strict)
        if rows is not None:
            return rows
    return _read_careful(path, strict)


def _read_resaved(path: Path, sep: str, bom: bool, head: bytes) -> CsvRows | None:
    """The rows of a spreadsheet's re-save with ``sep`` between the fields, its text converted a block at a
    time (``_text_blocks``, ``_resaved_lines``) into the app's layout and read as the app's CSV is
    (``_read_fast``, its messages quoting the file's own cells); ``None`` where that sends a file to the
    careful parser. Only the converted copy is held whole (the careful parser held the file's text and its
    lines)."""
    repairs: list[dict[str, Any]] = []
    if bom:
        repair(repairs, 1, "bom", "UTF-8 byte-order mark before the header ignored")
    line_ending = "\r\n" if b"\r\n" in head else "\n"  # _read_head's bytes
    first: dict[str, tuple[str, int]] = {}
    converted, header_line, start = bytearray(), "", 1
    for lines, closed in _text_blocks(path):  # (its header line read_csv_rows found no binary data in)
        _resaved_lines(lines, sep, path, first, start)
        if start == 1:
            header_line = lines[0]
            body_start = len(header_line.encode()) + len(line_ending)
        start += len(lines)
        converted += (line_ending.join(lines) + (line_ending if closed else "")).encode()
        del lines
    _separator_note(sep, first, repairs)
    header = _parse_header(header_line, path)
    rows = _read_fast(path, header, False, body_start, False, converted, _WrittenLines(path, sep))
    if rows is not None:
        rows.repairs[:0] = repairs
    return rows


# A file whose lines with other bytes than a number's split it into more pieces than this is damaged all
# over: the careful parser reads it whole rather than pyarrow piece by piece.
MAX_PIECES = 256
# The pieces of a file up to this size are read by pyarrow as one copy of them (each read of a piece costs
# about a millisecond of setup; a copy of a small file costs less).
JOIN_PIECES_BYTES = 1 << 24
# A file where more than this share of the data lines must be read by the careful parser's per-row logic
# (a text cell on most lines) is read by the careful parser whole: merging pyarrow's few rows into it costs
# more than it saves.
MAX_MENDED_SHARE = 0.5
MERGE_ROWS = 1 << 14  # pyarrow's rows copied at a time into the merged rows (a 4 MB block)


def _read_fast(
    path: Path,
    header: CsvHeader,
    bom: bool,
    body_start: int,
    strict: bool,
    converted: bytearray | None = None,
    written_lines: _WrittenLines | None = None,
) -> CsvRows | None:
    """pyarrow's parse, with the careful parser's per-row logic for the rows pyarrow cannot take, so that
    a long take with a damaged row costs what an intact one does (``_read_mended``). A whole file's re-save
    (a BOM, CRLF line ends, a comma ending every line, pandas' index column, cells in quotes, from the first
    line or further on) is read so too. ``None`` sends the whole file to the careful parser (one that
    pyarrow cannot read even without its odd lines, or one with a line ending at a lone CR). A re-save's text
    ``converted`` into the app's layout is read in place of the file's, its ``written_lines`` quoted."""
    mapped = _MappedFile(path, converted)
    data = mapped.buffer  # no copy: numpy and pyarrow read the mapped file
    if bom:
        data = data.slice(3)  # line 1 starts after the byte-order mark, as for the careful parser
    # as the careful parser tells the file's line ends
    crlf = b"\r\n" in data.slice(0, min(data.size, 65536)).to_pybytes()
    resaved = bom or crlf or header.trailing_comma or header.index_column is not None
    lines, screened = None, np.empty(0, np.int64)
    invalid: list[str] = []  # the cells pyarrow named no number, read after read
    read = _arrow_rows([data.slice(body_start)], header, mapped, invalid)
    if read is None:  # a cell that is no number: again without the lines holding a non-number byte
        lines = _Lines(data, mapped.release)
        if lines.has_cr:
            return None
        screened = lines.with_other_bytes(quotes=True)
        # none to leave out: the lines are those just read (a quoted cell no number: not read twice)
        read = _read_screened(lines, screened, header, mapped, invalid) if screened.size else None
        if read is None:  # then also without those holding a quote: a quoted cell no number ("0,1421")
            with_quotes = lines.with_other_bytes(quotes=False)
            if with_quotes.size > screened.size:
                screened = with_quotes
                read = _read_screened(lines, screened, header, mapped, invalid)
        # then also without the lines holding a cell pyarrow named, made of a number's bytes only ("-",
        # "0.1.2", "1e"), each met found in one scan of the file
        for _ in range(MAX_NUMBER_LIKE):
            if read is not None or not invalid:
                break
            holding = np.union1d(screened, _lines_holding(lines, mapped, invalid))
            invalid.clear()
            if holding.size == screened.size:  # none found (a quoted one): the careful parser reads it
                return None
            screened = holding
            read = _read_screened(lines, screened, header, mapped, invalid)
        if read is None:
            return None
    rows, odd, quoted = read
    del read
    # quotes (pyarrow may carry one left open into the next line): the rows are matched to the lines; a
    # channel empty on every row: the careful parser's checks leave it out (_read_mended)
    if lines is None and not (resaved or quoted) and not rows[3].any() and not rows[5].any():
        plain = _plain_rows(path, header, *rows[:3], odd)
        if plain is not None:
            return plain
    lines = lines or _Lines(data, mapped.release)
    if lines.has_cr:
        return None
    line_ending = "\r\n" if crlf else "\n"
    mended = _read_mended(path, header, lines, screened, odd, rows, bom, line_ending, strict, written_lines)
    if mended is None and quoted:
        # A quote pyarrow carried past its line's end (a stray one: damage, an edit) swallowed the lines
        # after it: again without the lines holding a quote, which the careful parser's per-row logic
        # reads, as before quotes past the first 64 kB were read by pyarrow (not the whole file line by
        # line: 4-8x the time and 1.7x the peak of an hour).
        del rows
        screened = lines.with_other_bytes(quotes=False)
        read = _read_screened(lines, screened, header, mapped, [])
        if read is not None:
            rows, odd, _ = read
            del read
            mended = _read_mended(
                path, header, lines, screened, odd, rows, bom, line_ending, strict, written_lines
            )
    return mended


# How many cells pyarrow names no number though made of a number's bytes (``-``, ``0.1.2``) the lines
# holding them are looked for: pyarrow names one at a time, each costs a read of the file.
MAX_NUMBER_LIKE = 8


def _lines_holding(lines: _Lines, mapped: _MappedFile, cells: list[str]) -> np.ndarray:
    """The data lines holding one of ``cells`` as a whole value cell (after a comma, before a comma or the
    line's end), found by one scan of the mapped file per cell."""
    offset = lines.bytes.ctypes.data - mapped.start  # the byte-order mark before the lines, if any
    found = []
    for cell in set(cells):
        pattern = re.compile(b"," + re.escape(cell.encode()) + rb"(?=[,\r\n]|\Z)")
        found += [m.start() - offset for m in pattern.finditer(mapped.map)]
    mapped.release(mapped.start, len(mapped.map))
    numbers = np.searchsorted(lines.starts, np.asarray(found, np.int64), side="right")
    return np.unique(numbers[numbers > 1])  # the header is no data line


def _read_screened(
    lines: _Lines, screened: np.ndarray, header: CsvHeader, mapped: _MappedFile, invalid: list[str]
) -> _ArrowRead | None:
    """``_arrow_rows`` of the data lines but ``screened``; ``None`` when it cannot read them, or when they
    leave too many lines (``MAX_MENDED_SHARE``) or pieces (``MAX_PIECES``) for the careful parser."""
    import pyarrow as pa

    if screened.size > MAX_MENDED_SHARE * (lines.count - 1):
        return None
    pieces = lines.pieces_without(screened)
    if not pieces or len(pieces) > MAX_PIECES:
        return None
    if len(pieces) > 1 and lines.bytes.size <= JOIN_PIECES_BYTES:  # one read: each costs pyarrow's setup
        pieces = [pa.py_buffer(b"".join(piece.to_pybytes() for piece in pieces))]
    return _arrow_rows(pieces, header, mapped, invalid)


class _MappedFile:
    """A file mapped into memory read-only, whose pages can be given back once read: mapped pages count in
    the process's resident memory (an hour's 176 MB CSV would add its size to the peak of its parse),
    though the kernel's page cache keeps them; a page read again is mapped again from there."""

    def __init__(self, path: Path, text: bytearray | None = None) -> None:
        import pyarrow as pa

        if text is not None:  # a file's text converted in memory (``_read_resaved``): read as if mapped
            self.map: mmap.mmap | bytearray = text
        else:
            with open(path, "rb") as f:
                self.map = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        self.buffer = pa.py_buffer(self.map)
        self.start = self.buffer.address

    def release(self, address: int, size: int) -> None:
        """Give back the pages of the ``size`` bytes at ``address`` (a part of the map, else nothing)."""
        start, stop = address - self.start, min(address - self.start + size, len(self.map))
        if _DONTNEED is not None and isinstance(self.map, mmap.mmap) and 0 <= start < stop:
            start -= start % mmap.PAGESIZE  # a page read again (the next part's first line) is mapped again
            self.map.madvise(_DONTNEED, start, stop - start)

    def holds_quote(self, part: Any) -> bool:
        """Whether the buffer ``part`` (a part of the map, or of pieces joined in memory) holds a quote."""
        start = part.address - self.start
        if 0 <= start and start + part.size <= len(self.map):
            return self.map.find(b'"', start, start + part.size) >= 0  # memchr over the mapped pages
        return b'"' in part.to_pybytes()  # pieces joined: a small file's (JOIN_PIECES_BYTES)


_DONTNEED = getattr(mmap, "MADV_DONTNEED", None)  # Linux, the BSDs, macOS; elsewhere pages stay mapped
# pyarrow reads a long file this many bytes (of whole lines) at a time, each part's table turned into the
# take's arrays before the next: the float64 table of the whole file and its mapped pages would double
# the peak memory of its parse. A part's read (its mapped pages, pyarrow's buffers, its float64 table) is
# the peak's part beyond the values: 32 MB parts took an hour's parse to 220-235 MB, 16 MB to 185-205,
# at the same speed.
PART_BYTES = 1 << 24


def _parts(piece: Any) -> Iterator[Any]:
    """A buffer of whole lines as parts of whole lines of about ``PART_BYTES`` each (no copy), each cut
    found when the part before it is wanted (only then are the pages past the cut read)."""
    at = 0
    while piece.size - at > 2 * PART_BYTES:
        cut = at + PART_BYTES
        found = piece.slice(cut, min(1 << 16, piece.size - cut)).to_pybytes().find(b"\n")
        if found < 0:  # no line end for 64 kB: no part of this file is cut there
            break
        yield piece.slice(at, cut + found + 1 - at)
        at = cut + found + 1
    yield piece.slice(at)


# pyarrow's rows (times, values, status, trouble, pandas' index or None, the columns of empty cells only),
# the text of the lines it skipped, and whether a part was read with quoting on
_ArrowRead = tuple[
    tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray], list[str], bool
]


def _arrow_rows(
    pieces: list[Any], header: CsvHeader, mapped: _MappedFile, invalid: list[str]
) -> _ArrowRead | None:
    """pyarrow's rows of whole lines of the file (``_table_rows``, read part by part: ``_parts``, each
    part's mapped pages given back once read), the text of the lines it skipped, and whether a part was
    read with quoting on (one holding a quote: a spreadsheet's re-save of the whole file or of its later
    rows, a quoted cell anywhere; the others are read without, the least work); ``None`` as for
    ``_arrow_read`` (the cell it could not convert added to ``invalid``), or when it reads no row. The
    columns whose every cell is empty (a channel the writer left out) make no row trouble; in a part where
    other columns are empty too, every row is (the careful parser reads them)."""
    import pyarrow as pa

    odd: list[str] = []
    parts, quoted = [], False
    values = _ValueRows(len(header.columns), sum(piece.size for piece in pieces))
    for piece in pieces:
        for part in _parts(piece):
            quotes = mapped.holds_quote(part)
            table = _arrow_read(part, header, quotes, odd, invalid)
            if table is None:
                return None
            quoted |= quotes
            mapped.release(part.address, part.size)
            block = values.block(table.num_rows, part.size)
            if table.num_rows:
                parts.append(_table_rows(table, header, block))
            del block
            del table  # its float64 columns: freed before the next part is read
            pa.default_memory_pool().release_unused()  # what pyarrow's allocator would keep for reuse
    if not values.n:
        return None
    blank = np.logical_and.reduce([part[4] for part in parts])
    for part in parts:
        if (part[4] != blank).any():
            part[2][:] = True
    times, status, trouble, index = (
        np.concatenate([part[k] for part in parts]) if parts[0][k] is not None else None for k in range(4)
    )
    return (times, values.trimmed(), status, trouble, index, blank), odd, quoted


# The share of rows the first part's bytes per row foretell that the values' array is allocated for beyond
# them: the app's rows differ in length by a minus sign here and there, not more (pages of the array that
# no row reaches are never touched, and given back when it is trimmed).
ROWS_MARGIN = 1.03


class _ValueRows:
    """The values of pyarrow's rows, part after part, in one array: allocated once for the rows the file's
    bytes hold at the first part's bytes per row, grown in place if later rows are shorter, trimmed in
    place at the end. The values are held once: the parts' arrays joined at the end held them twice, at
    the peak of an hour's parse."""

    def __init__(self, columns: int, size: int) -> None:
        self.size = size  # bytes of the lines to read
        self.rows = GrowingRows(0, columns, np.float32)
        self.n = 0  # rows written
        self.bytes_read = 0

    def block(self, rows: int, part_bytes: int) -> np.ndarray:
        """Where the next ``rows`` rows go (a view), read from ``part_bytes`` bytes."""
        self.bytes_read += part_bytes
        start, self.n = self.n, self.n + rows
        if self.n > len(self.rows):
            left = max(self.size - self.bytes_read, 0)
            estimate = self.n + math.ceil(left * self.n / self.bytes_read * ROWS_MARGIN)
            if len(self.rows):
                self.rows.resize(estimate)
            else:  # the first part: allocated for the estimate, untouched rows costing nothing
                self.rows = GrowingRows(estimate, self.rows.array.shape[1], np.float32)
        return self.rows.array[start : self.n]

    def trimmed(self) -> np.ndarray:
        """The rows written, an array of their size owning its memory (trimmed in place when nothing else
        holds the array: no copy)."""
        if len(self.rows) != self.n:
            self.rows.resize(self.n)
        return self.rows.array


def _arrow_names(header: CsvHeader) -> list[str]:
    """pyarrow's names of a row's fields: pandas' index column, timecode, count, values, the comma ending
    every line (an empty field)."""
    names = ["tc", "count"] + [f"v{i}" for i in range(len(header.columns))]
    if header.index_column is not None:
        names.insert(0, "index")
    return names + ["comma"] if header.trailing_comma else names


def _arrow_read(piece: Any, header: CsvHeader, quoted: bool, odd: list[str], invalid: list[str]) -> Any:
    """pyarrow's table of whole lines of the file (``piece``: a buffer of whole lines); the text of the
    lines it skipped for another number of fields than the header's is added to ``odd``. ``None`` when a
    cell is no number, or a skipped line is not UTF-8. ``quoted``: cells may be in quotes, which go as the
    careful parser's csv module takes them (a quote opening a cell, ``""`` within one); a quote left open,
    which pyarrow carries into the next line, leaves fewer rows than lines (``_read_mended`` gives up, and
    ``_read_fast`` reads the file again without the lines holding a quote). A value cell pyarrow cannot
    convert is added to ``invalid`` (its error names the first it meets); only an empty one is null."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    def on_invalid(row: Any) -> str:
        odd.append(row.text or "")
        return "skip"

    names = _arrow_names(header)
    # Parsed as float64 and narrowed on the copy in _table_rows: pyarrow parses doubles faster than floats,
    # and the careful parser rounds the same way (decimal -> double -> float32).
    types = {n: pa.float64() for n in names if n.startswith("v")}
    # Text, not int32: pyarrow's integers also take "-0" and "0x3d", which the careful parser does not (the
    # count, pandas' index); the comma ending every line must leave an empty field, checked by its length.
    types.update((n, pa.string()) for n in ("tc", "count", "index", "comma") if n in names)
    undecodable = []
    previous_hook = sys.unraisablehook
    # A row that is not UTF-8 makes pyarrow fail inside our handler; that failure only tells us to use
    # the careful parser, so keep it from being printed.
    sys.unraisablehook = undecodable.append
    try:
        # Fixed types, no quoting (unless the file has quotes), no UTF-8 re-validation: the least work
        # pyarrow can do. 2 MB blocks keep both cores busy to the end (16 MB blocks left one idle for the
        # last ones: 0.76x pyarrow's default read of a 176 MB hour, against 1.0-1.1x now).
        table = pacsv.read_csv(
            pa.BufferReader(piece),
            read_options=pacsv.ReadOptions(column_names=names, block_size=1 << 21),
            parse_options=pacsv.ParseOptions(
                quote_char='"' if quoted else False, invalid_row_handler=on_invalid
            ),
            convert_options=pacsv.ConvertOptions(
                column_types=types, null_values=[""], strings_can_be_null=False, check_utf8=False
            ),
        )
    except (pa.ArrowException, UnicodeDecodeError, OSError) as exc:
        if (cell := _INVALID_VALUE.search(str(exc))) is not None:
            invalid.append(cell.group(1))
        return None
    finally:
        sys.unraisablehook = previous_hook
    return None if undecodable else table


_INVALID_VALUE = re.compile(r"conversion error to double: invalid value '(.*)'$", re.DOTALL)


def _table_rows(
    table: Any, header: CsvHeader, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """Times of day and status of pyarrow's rows (their values written into ``values``, rows x columns),
    which of them the careful parser must read instead (``trouble``: a timecode not in the app's exact
    layout (or at FF 60.000), an empty, NaN or infinite cell or one beyond float32, a count that is none a
    row may carry (0 over values not all 0), a cell where the comma ending every line should leave none),
    the number in pandas' index column (-1 where it is not written as ``str`` writes a number; None
    without that column), and which columns hold empty cells only (``blank``: no row's trouble)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    columns = header.columns
    n = table.num_rows
    tc = table.column("tc").combine_chunks()
    offsets = _offsets(tc)
    chars = np.frombuffer(tc.buffers()[2], dtype=np.uint8)
    app_width = np.diff(offsets) == 15
    times = np.full(n, np.nan)
    if app_width.all():
        times, ok = fixed_width_seconds(chars[offsets[0] : offsets[-1]].reshape(-1, 15))
    else:
        ok = np.zeros(n, bool)
        starts = offsets[:-1][app_width]
        times[app_width], ok[app_width] = fixed_width_seconds(chars[starts[:, None] + np.arange(15)])
    trouble = ~ok
    with np.errstate(over="ignore"):  # beyond float32 becomes inf (an empty cell NaN): trouble
        start = 0
        # A batch (a 2 MB block of lines: _arrow_read) at a time, column after column: the batch's rows
        # stay in the cache while each column is written across them.
        for batch in table.to_batches():
            rows = values[start : start + batch.num_rows]
            for i in range(len(columns)):
                rows[:, i] = batch.column(f"v{i}").to_numpy(zero_copy_only=False)
            start += batch.num_rows
    # NaN, infinite (beyond float32 once narrowed) and float32's largest, which 3.4028235e38 (beyond it)
    # also rounds to: the careful parser decides those rows. The common file has none: three passes over
    # the values, no per-row mask.
    blank = np.array([table.column(f"v{i}").null_count == n for i in range(len(columns))], bool)
    if not np.isfinite(values).all() or values.max() >= _FLOAT32_MAX or values.min() <= -_FLOAT32_MAX:
        with np.errstate(invalid="ignore"):
            damaged = ~(np.abs(values) < _FLOAT32_MAX)
        damaged[:, blank] = False
        trouble |= damaged.any(axis=1)
    count = table.column("count").combine_chunks()
    digits = _only_digits(count)
    if digits.all():
        counts = pc.cast(count, pa.int32()).to_numpy()
    else:  # a count written otherwise (61.0, -0, 0x3d, empty): the careful parser reads those rows
        trouble |= ~digits
        counts = np.where(digits, pc.cast(pc.if_else(digits, count, "0"), pa.int32()).to_numpy(), -1)
    status = np.zeros(n, dtype=np.uint8)
    off = counts != len(columns)
    if off.any():  # the common file has every count right: nothing more to look at
        zero = counts == 0
        trouble |= off & ~zero & ~np.isin(counts, list(blendshape_counts(columns)))
        # A count of 0 over values is read by the careful parser (face lost when they are all 0 as
        # written, not only once rounded to float32: 1e-46 is no 0)
        trouble |= zero
    if header.trailing_comma:
        comma = table.column("comma").combine_chunks()
        trouble |= np.diff(_offsets(comma)) > 0
    index = (
        _index_numbers(table.column("index").combine_chunks()) if header.index_column is not None else None
    )
    return times, status, trouble, index, blank


def _index_numbers(cells: Any) -> np.ndarray:
    """The numbers of a pyarrow string array's cells written as ``str`` writes a count (digits, no leading
    zero), -1 for the others (``01``, ``1.0``, empty)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    digits = _only_digits(cells)
    if len(cells):
        lengths = np.diff(_offsets(cells))
        digits &= ~(pc.starts_with(cells, "0").to_numpy(zero_copy_only=False) & (lengths > 1))
    numbers = pc.cast(pc.if_else(pa.array(digits), cells, "0"), pa.int64()).to_numpy()
    return np.where(digits, numbers, -1)


def _offsets(cells: Any) -> np.ndarray:
    """Where each cell of a pyarrow string array starts in its data buffer, and where the last ends (n + 1
    int32 offsets, read from its buffers: no copy)."""
    return np.frombuffer(cells.buffers()[1], dtype=np.int32)[cells.offset : cells.offset + len(cells) + 1]


def _only_digits(cells: Any) -> np.ndarray:
    """Which of a pyarrow string array's cells are 1 to 9 decimal digits, from its buffers (no copy)."""
    offsets = _offsets(cells)
    chars = np.frombuffer(cells.buffers()[2], dtype=np.uint8)[offsets[0] : offsets[-1]]
    lengths = np.diff(offsets)
    other = (chars < ord("0")) | (chars > ord("9"))
    if not other.any():
        return (lengths >= 1) & (lengths <= 9)
    per_cell = np.add.reduceat(other, np.minimum(offsets[:-1] - offsets[0], max(chars.size - 1, 0)))
    return (lengths >= 1) & (lengths <= 9) & ~(per_cell.astype(bool) & (lengths > 0))


def _plain_rows(
    path: Path, header: CsvHeader, times: np.ndarray, values: np.ndarray, status: np.ndarray, odd: list[str]
) -> CsvRows | None:
    """The rows of a file pyarrow read whole, when it skipped no line and the times run forward; ``None``
    sends the file to ``_read_mended``, which places skipped lines (the app's face-lost rows ``<timecode>,0``
    among them) by their line numbers: placing them by their timecodes would silently put rows in order
    that the file has out of order."""
    if odd:
        return None
    t = unwrap_midnight(times)
    if t.size > 1 and not (np.all(np.diff(t) > 0) and np.diff(t).max() <= MAX_GAP_S):
        return None
    return CsvRows(path, header.count_name, header.columns, t, values, status)


class _Lines:
    """Where each line of a file starts and ends (LF or CRLF), found by numpy in pyarrow's memory map (no
    copy): the lines pyarrow could not take are named by these numbers and read again from here."""

    CHUNK = 1 << 20  # bytes scanned at a time: the comparison's temporary stays in the cache

    def __init__(self, data: Any, release: Any = None) -> None:
        self.bytes = np.frombuffer(data, dtype=np.uint8)
        self.release = release or (lambda address, size: None)  # a chunk's mapped pages, once scanned
        size = self.bytes.size
        found, after_cr, crs = [], [], 0
        last = 0  # the byte before the chunk (none before the file's first)
        for i in range(0, size, self.CHUNK):
            chunk = self.bytes[i : i + self.CHUNK]
            at = np.flatnonzero(chunk == 10)
            # a CR before a line's LF is part of its line end (CRLF), as for pyarrow and the careful parser
            before = chunk[np.maximum(at - 1, 0)]
            if at.size and at[0] == 0:
                before[0] = last
            found.append(at + i)
            after_cr.append(before == 13)
            crs += int(np.count_nonzero(chunk == 13))
            last = chunk[-1]
            self.release(chunk.ctypes.data, chunk.size)  # scanned once: not mapped again but for odd lines
        newlines = np.concatenate(found) if found else np.empty(0, np.int64)
        crlf = np.concatenate(after_cr) if after_cr else np.empty(0, bool)
        self.ends = newlines - crlf
        self.ends_with_newline = bool(size) and self.bytes[-1] == 10
        if not self.ends_with_newline:
            newlines = np.append(newlines, size)  # the last line, without its line end
            self.ends = np.append(self.ends, size)
        self.newlines = newlines  # each line's LF (the file's size for a last line without one)
        self.starts = np.concatenate([[0], newlines[:-1] + 1])
        self.count = self.ends.size
        # a lone CR, a line end the careful parser splits at and this index does not: that file is read whole
        self.has_cr = crs > int(crlf.sum())

    def text(self, number: int) -> str:
        """Line ``number`` (from 1), decoded as the careful parser decodes the file."""
        return self.raw(number).decode("utf-8", errors="replace")

    def raw(self, number: int) -> bytes:
        return self.bytes[self.starts[number - 1] : self.ends[number - 1]].tobytes()

    def with_other_bytes(self, quotes: bool) -> np.ndarray:
        """The data lines holding a byte that no number of the app's rows holds (a letter, a space, any
        non-ASCII byte, a quote unless ``quotes`` pass: a piece holding one is read with quoting on, as the
        csv module reads it): those where pyarrow meets a cell it cannot convert, found without parsing. (A
        CR passes: a file with one that is not part of a CRLF is read whole by the careful parser.)"""
        passing = np.frombuffer(b'\r\neE"' if quotes else b"\r\neE", np.uint8)
        found = []
        for i in range(0, self.bytes.size, self.CHUNK):
            chunk = self.bytes[i : i + self.CHUNK]
            at = np.flatnonzero((chunk < ord("+")) | (chunk > ord(":")))  # + , - . / 0-9 : pass
            found.append(at[~np.isin(chunk[at], passing)] + i)
            self.release(chunk.ctypes.data, chunk.size)
        numbers = np.unique(np.searchsorted(self.starts, np.concatenate(found), side="right"))
        return numbers[numbers > 1]  # the header is no data line

    def pieces_without(self, numbers: np.ndarray) -> list[Any]:
        """The data lines but ``numbers``, as runs of whole lines: slices of the mapped file, no copy."""
        import pyarrow as pa

        buffer = pa.py_buffer(self.bytes)
        bounds = np.concatenate([[1], numbers, [self.count + 1]])
        pieces = []
        for before, after in zip(bounds[:-1], bounds[1:]):
            if after - before > 1:  # lines before + 1 .. after - 1
                start, stop = self.starts[before], min(self.newlines[after - 2] + 1, self.bytes.size)
                pieces.append(buffer.slice(int(start), int(stop - start)))
        return pieces

    def table_lines(self, odd: list[str], screened: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The line numbers of pyarrow's rows, and of the lines it skipped for their number of fields (whose
        text is ``odd``), among the data lines but ``screened``. pyarrow also skips empty lines."""
        numbers = np.arange(2, self.count + 1)
        length = (self.ends - self.starts)[1:]
        outside = np.zeros(numbers.size, bool)
        outside[screened - 2] = True
        texts = {text.encode() for text in odd}
        maybe = np.isin(length, [len(t) for t in texts]) & ~outside  # a line's length, then its bytes
        skipped = [n for n in numbers[maybe].tolist() if self.raw(n) in texts]
        outside[np.asarray(skipped, dtype=np.int64) - 2] = True
        return numbers[~outside & (length > 0)], np.asarray(skipped, dtype=np.int64)


def _read_mended(
    path: Path,
    header: CsvHeader,
    lines: _Lines,
    screened: np.ndarray,
    odd: list[str],
    table: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray],
    bom: bool,
    line_ending: str,
    strict: bool,
    written_lines: _WrittenLines | None = None,
) -> CsvRows | None:
    """The rows of pyarrow's table that need no repair, and the lines it could not take read by the careful
    parser's per-row logic (``_RowReader``), merged in file order: the careful parser's result at the cost
    of reading these lines. ``None`` when the table's rows cannot be matched to the file's lines, when
    most lines would have to be read line by line, or when the careful parser's checks would not leave out
    every channel pyarrow's rows leave empty (``_empty_channels``: a row read here has a cell there, or
    too few rows have values, or every channel is empty)."""
    times, values, status, trouble, index, blank = table
    numbers, skipped = lines.table_lines(odd, screened)
    if numbers.size != times.size:
        return None
    is_channel = np.array([ch.is_known(c) for c in header.columns], bool)
    empty = blank & is_channel
    if empty.any() and ((empty == is_channel).all() or int((~trouble).sum()) < 2):
        return None
    again = np.union1d(np.union1d(skipped, screened), numbers[trouble])
    if again.size > MAX_MENDED_SHARE * (lines.count - 1):
        return None
    data_lines, index_start = None, 0
    if index is not None:  # pandas' index column: it must count the data lines, the careful parser's too
        texts = {n: lines.text(n) for n in again.tolist()}
        read_here = [n for n, text in texts.items() if not _ONLY_SEPARATORS.fullmatch(text)]
        # two sorted runs of other lines: a merge (union1d would hash every line number)
        data_lines = np.concatenate([numbers[~trouble], np.asarray(read_here, np.int64)])
        data_lines.sort(kind="stable")
        if data_lines.size:
            first = int(data_lines[0])
            if first in texts:
                index_start = int(_fields(texts[first])[0].strip() == "1")
            else:
                index_start = int(index[np.searchsorted(numbers, first)] == 1)
        miscounted = index != np.searchsorted(data_lines, numbers) + index_start
        if (miscounted & ~trouble).any():  # the careful parser notes the first such row
            again = np.union1d(again, numbers[miscounted & ~trouble])
            trouble = trouble | miscounted
    repairs: list[dict[str, Any]] = []
    if bom:
        repair(repairs, 1, "bom", "UTF-8 byte-order mark before the header ignored")
    reader = _RowReader(
        path, header, lines.text(1), again.size, lines.count, lines.ends_with_newline, repairs
    )
    reader.index_start, reader.written_lines = index_start, written_lines
    for number in again.tolist():
        if data_lines is not None:
            reader.data_rows = int(np.searchsorted(data_lines, number))  # data lines before this one
        reader.read(number, lines.text(number))
    if empty.any() and (reader.written[empty].any() or not np.isnan(reader.values[: reader.n, empty]).all()):
        return None
    good = ~trouble
    n_good, n = int(good.sum()), reader.n
    data_rows = data_lines.size if data_lines is not None else n_good + reader.data_rows
    if header.trailing_comma:
        reader.comma_rows += n_good  # pyarrow's rows all ended with the comma (an empty field)
    if n == 0 and n_good == times.size:  # nothing to merge: pyarrow's rows are all the rows
        return _finish(reader, times, values, status, numbers, data_rows, line_ending, strict)
    numbers = np.concatenate([numbers[good], reader.lines[:n]])
    order = np.argsort(numbers, kind="stable")
    where = np.empty(order.size, dtype=np.intp)  # each row's place in file order
    where[order] = np.arange(order.size)
    merged = np.empty((order.size, len(header.columns)), dtype=np.float32)
    # pyarrow's good rows a block at a time: their copy (values[good]) would hold the values a third time
    good_rows = np.flatnonzero(good)
    for start in range(0, n_good, MERGE_ROWS):
        at = good_rows[start : start + MERGE_ROWS]
        merged[where[start : start + at.size]] = values[at]
    merged[where[n_good:]] = reader.values[:n]
    return _finish(
        reader,
        np.concatenate([times[good], reader.times[:n]])[order],
        merged,
        np.concatenate([status[good], reader.status[:n]])[order],
        numbers[order],
        data_rows,
        line_ending,
        strict,
    )


@dataclass
class _Seen:
    """How often something was met in a file, and where first: its text, line and column."""

    count: int = 0
    text: str = ""
    line: int = 0
    column: str = ""

    def add(self, text: str, line: int, column: str = "") -> None:
        if not self.count:
            self.text, self.line, self.column = text, line, column
        self.count += 1

    def first(self) -> str:
        """The first one met, for a message: ``'0,1421' in EyeBlinkLeft on line 2``."""
        return (
            f"{_shown(self.text)}" + (f" in {self.column}" if self.column else "") + f" on line {self.line}"
        )


def _shown(cell: str) -> str:
    return repr(cell.strip()[:40])


# A cell of a row split at unquoted decimal commas: each piece of a value, and the count, is a whole number.
_WHOLE_NUMBER = re.compile(r"\s*[+-]?\d+\s*", re.ASCII)
# A row that is nothing but separators (and quotes): the empty rows of a spreadsheet's used range.
_ONLY_SEPARATORS = re.compile(r'[\s,"]*')
_COUNT = re.compile(r"\s*(\d+)(?:\.0*)?\s*", re.ASCII)


def _count_of(cell: str) -> int | None:
    """A BlendShapeCount cell's number: ``61``, or ``61.0`` as pandas and spreadsheets re-save it."""
    m = _COUNT.fullmatch(cell)
    return int(m.group(1)) if m else None


# Of the shares of a take's rows lost to damage: more than these are said as a warning, not only counted.
BAD_VALUE_SHARE = 0.5
BAD_TIMECODE_SHARE = 0.05


def _read_careful(path: Path, strict: bool, raw: bytes | None = None) -> CsvRows:
    """The careful parser's rows of the file (of its bytes ``raw``, when given)."""
    raw = path.read_bytes() if raw is None else raw
    repairs: list[dict[str, Any]] = []
    if raw.startswith(UTF8_BOM):
        raw = raw[3:]
        repair(repairs, 1, "bom", "UTF-8 byte-order mark before the header ignored")
    line_ending = "\r\n" if b"\r\n" in raw[:65536] else "\n"
    text = raw.decode("utf-8", errors="replace")
    del raw  # of the file's three copies (bytes, text, lines), one at a time is enough
    ends_with_newline = text.endswith(("\n", "\r"))
    lines = text_lines(text)
    del text
    if not lines or "\ufffd" in lines[0]:
        raise InputError("binary data, not a CSV text file", path, 1)
    sep = app_header_separator(lines[0])
    written_lines = None
    if sep in RESAVE_SEPARATORS:
        first: dict[str, tuple[str, int]] = {}
        _resaved_lines(lines, sep, path, first)
        _separator_note(sep, first, repairs)
        written_lines = _WrittenLines(path, sep)
    header = _parse_header(lines[0], path)
    reader = _RowReader(path, header, lines[0], len(lines) - 1, len(lines), ends_with_newline, repairs)
    reader.written_lines = written_lines
    for number in range(2, len(lines) + 1):
        reader.read(number, lines[number - 1])
    n = reader.n
    return _finish(
        reader,
        reader.times[:n],
        reader.values[:n],
        reader.status[:n],
        reader.lines[:n],
        reader.data_rows,
        line_ending,
        strict,
    )


class _RowReader:
    """The careful parser's reading of data lines, one at a time: each problem repaired with a note in
    ``repairs`` (what it met counted in ``seen``), or an ``InputError``. Rows land in arrays allocated for
    ``capacity`` of them: a Python list of floats per row would cost 8 times the float32 array (22 MB a
    minute of CSV). It reads a whole file, or only the lines pyarrow could not take (``_read_mended``)."""

    def __init__(
        self,
        path: Path,
        header: CsvHeader,
        header_line: str,
        capacity: int,
        last: int,
        ends_with_newline: bool,
        repairs: list,
    ) -> None:
        self.path, self.header, self.header_line = path, header, header_line.strip()
        self.last, self.ends_with_newline = last, ends_with_newline  # to tell a last line cut short
        self.ncols = len(header.columns) + 2
        self.counts = blendshape_counts(header.columns)
        self.is_channel = [ch.is_known(c) for c in header.columns]
        self.repairs = repairs
        self.seen: dict[str, _Seen] = {}  # what the file holds that is read with a repair, by kind
        self.times = np.empty(capacity)
        self.values = np.full((capacity, len(header.columns)), np.nan, dtype=np.float32)
        self.status = np.empty(capacity, dtype=np.uint8)
        self.lines = np.empty(capacity, dtype=np.int64)  # each row's line in the file
        self.n = 0  # rows read
        self.data_rows = 0  # lines holding a row (not blank)
        self.comma_rows = 0  # rows whose comma ending the line was dropped (``trailing_comma``)
        self.index_start = 0  # what pandas' index column counts from (0, or 1 when its first row says so)
        self.split_fields = 0  # fields of the first row whose values split at unquoted decimal commas
        self.written = np.zeros(len(header.columns), dtype=bool)  # a column held a cell that is no number
        self.first_bad: dict[int, tuple[str, int]] = {}  # each channel's first cell no number, and its line
        # by line, a damaged row's first cell no number but written (column, text), when it has blank ones too
        self.first_written: dict[int, tuple[int, str]] = {}
        self.written_lines: _WrittenLines | None = None  # a re-save's lines as the file writes them

    def read(self, number: int, line: str) -> None:
        """Read line ``number`` of the file (a row, a blank line, or a damaged one)."""
        header, columns, ncols, seen = self.header, self.header.columns, self.ncols, self.seen
        if _ONLY_SEPARATORS.fullmatch(line):
            return  # empty lines carry nothing (pyarrow's fast path skips them too); nor do ",,,,"
        if line.strip() == self.header_line:
            raise InputError(
                "the header repeats here: two recordings joined into one file? Split it at this line",
                self.path,
                number,
            )
        fields = _fields(line)
        if header.index_column is not None:
            cell = fields.pop(0).strip()
            if self.data_rows == 0 and cell == "1":
                self.index_start = 1
            if cell != str(self.data_rows + self.index_start):
                seen.setdefault("index", _Seen()).add(cell, number)
        self.data_rows += 1
        if header.trailing_comma and len(fields) == ncols + 1 and fields[-1].strip():
            raise InputError(
                "the header's last column is empty but this row has a value there: name it in the header, "
                "or delete that column from every row",
                self.path,
                number,
            )
        if header.trailing_comma and len(fields) in (3, ncols + 1) and not fields[-1].strip():
            fields.pop()  # the comma ending every line, a face-lost row's too
            self.comma_rows += 1
        count = _count_of(fields[1]) if len(fields) > 1 else None
        lost = len(fields) == 2 and count == 0
        if not lost and len(fields) != ncols:
            if number == self.last and not self.ends_with_newline and len(fields) < ncols:
                message = f"last row cut short ({len(fields)} of {ncols} fields) dropped"
                repair(self.repairs, number, "truncated_row", message)
            elif len(fields) > ncols and all(_WHOLE_NUMBER.fullmatch(cell) for cell in fields[1:]):
                # every cell past the timecode a whole number, and too many: values split at their decimal
                # commas (a script writing "0,1421" unquoted into a comma-separated file)
                if "unquoted_decimal_comma" not in seen:
                    self.split_fields = len(fields)
                seen.setdefault("unquoted_decimal_comma", _Seen()).add(",".join(fields[2:4]), number)
                message = f"row has {len(fields)} fields, expected {ncols}"
                message += " (decimal commas without quotes?): dropped"
                repair(self.repairs, number, "wrong_fields", message)
            else:
                message = f"row has {len(fields)} fields, expected {ncols}: dropped"
                repair(self.repairs, number, "wrong_fields", message)
            return
        tod = self.time_of_day(number, fields[0])
        if tod is None:
            return
        cells = fields[2:]
        vals = [] if lost else _row_values(line, cells, columns, number, seen)
        # Count 0 is the app's face-lost marker; a writer that fills the row with zeros, or (pandas, a
        # spreadsheet) with empty cells, means the same
        if lost or (count == 0 and all(v == 0 or not c.strip() for v, c in zip(vals, cells))):
            self._add(number, tod, None, FrameStatus.FACE_LOST)
            return
        row_status = FrameStatus.TRACKED
        if count not in self.counts:
            expected = " or ".join(map(str, sorted(self.counts)))
            shown = self.as_written(number, 1, fields[1]).strip()
            message = f"{header.count_name} is {shown!r} but the row has {len(columns)} values"
            message += f" ({expected} expected)"
            repair(self.repairs, number, "bad_count", message)
        bad, texts = [], {}  # the channels of cells no number, and these cells as the file writes them
        for i, v in enumerate(vals):
            if not abs(v) <= _FLOAT32_MAX:
                vals[i] = math.nan
                text = texts[i] = self.as_written(number, i + 2, cells[i]) if cells[i].strip() else cells[i]
                if self.is_channel[i]:
                    bad.append(i)
                    self.written[i] |= bool(cells[i].strip())
                    self.first_bad.setdefault(i, (text, number))
                elif cells[i].strip():  # another column's non-number is no channel's damage (_other_columns)
                    seen.setdefault(f"text {columns[i]}", _Seen()).add(text, number)
        if bad:
            row_status = FrameStatus.BAD_VALUE
            seen.setdefault("bad_value", _Seen()).add(texts[bad[0]], number, columns[bad[0]])
            written = [i for i in bad if cells[i].strip()]
            if written and len(written) < len(bad):  # blank ones may be a channel left out (_empty_channels)
                self.first_written[number] = (written[0], texts[written[0]])
            names = [columns[i] for i in bad]
            repair(self.repairs, number, "bad_value", _bad_value_message(names, texts[bad[0]]))
        self._add(number, tod, vals, row_status)

    def time_of_day(self, number: int, cell: str) -> float | None:
        """Seconds since midnight of a row's timecode cell (the app's ``HH:MM:SS:FF.fff``, or a clock time
        ``HH:MM:SS.fff`` as other writers put there), each unusual way of writing it counted in ``seen``;
        None for a cell that is neither (the row is dropped with a repair)."""
        seen = self.seen
        try:
            timecode = Timecode.parse(cell)
        except ValueError as exc:
            if (clock := clock_seconds(cell)) is not None:
                seen.setdefault("clock_time", _Seen()).add(cell, number)
                return clock
            written = self.as_written(number, 0, cell)
            message = str(exc).replace(repr(cell), repr(written), 1)
            repair(self.repairs, number, "bad_timecode", f"{message}: row dropped")
            seen.setdefault("bad_timecode", _Seen()).add(written, number)
            return None
        if not Timecode.is_zero_padded(cell):
            seen.setdefault("unpadded", _Seen()).add(cell, number)
        if ";" in cell:
            seen.setdefault("drop_frame", _Seen()).add(cell, number)
        if timecode.is_whole_second:
            seen.setdefault("whole_second", _Seen()).add(cell, number)
        return timecode.seconds_of_day

    def as_written(self, number: int, index: int, cell: str) -> str:
        """Field ``index`` (after pandas' index column) of line ``number``, read as ``cell``, as the file
        writes it: a re-save's cells are read converted (``_resaved_lines``), its messages quote its own."""
        if self.written_lines is None:
            return cell
        return self.written_lines.cell(number, index + (self.header.index_column is not None), cell)

    def _add(self, number: int, tod: float, vals: list[float] | None, status: int) -> None:
        i = self.n
        self.times[i], self.status[i], self.lines[i] = tod, status, number
        if vals is not None:
            self.values[i] = vals
        self.n += 1


def _bad_value_message(names: list[str], cell: str) -> str:
    """A damaged row's ``bad_value`` note: the channels whose cells are no number, the first one's text."""
    more = f" and {len(names) - 5} more" if len(names) > 5 else ""
    return (
        f"non-numeric, non-finite or out-of-range value in {', '.join(names[:5])}{more} ({_shown(cell)}): "
        "set to NaN, frame marked invalid"
    )


def _finish(
    reader: _RowReader,
    times: np.ndarray,
    values: np.ndarray,
    status: np.ndarray,
    numbers: np.ndarray,
    data_rows: int,
    line_ending: str,
    strict: bool,
) -> CsvRows:
    """The careful parser's checks of the rows as a whole (in file order: ``times`` of day, ``values``,
    ``status`` and line ``numbers`` of each row, what ``reader`` met), and its result: the notes of what was
    read with a repair, duplicate rows dropped, timecodes going back or jumping refused, other columns."""
    path, header, repairs, seen = reader.path, reader.header, reader.repairs, reader.seen
    split = seen.get("unquoted_decimal_comma")
    if split and (split.count > BAD_VALUE_SHARE * data_rows or not times.size):
        raise InputError(
            f"values written with a decimal comma and without quotes ({split.first()}): each splits in two "
            f"fields ({reader.split_fields} fields where the header has {reader.ncols}; {split.count} of "
            f"{data_rows} rows): save it with '.' as the decimal point, as the app writes it",
            path,
            split.line,
        )
    _note_read_with_repairs(seen, header, reader.index_start, repairs)
    # before the strict check: a channel no row fills is a note (nothing was changed), its cells no damage
    values, columns, is_channel = _empty_channels(reader, values, status, numbers)
    changed = [r for r in repairs if r["kind"] != "empty_channel"]
    if strict and changed:
        first = changed[0]
        raise InputError(f"{first['message']} (strict mode)", path, first["line"])
    if not times.size:
        _refuse_plain_number_times(
            seen.get("bad_timecode"), data_rows, path, reader.written_lines is not None
        )
        rejected = [r for r in repairs if r["kind"] not in ("bom", "separator")]
        if rejected:
            first = rejected[0]
            raise InputError(f"no usable data rows; the first: {first['message']}", path, first["line"])
        raise InputError("no data rows after the header", path)
    _warn_widespread(seen, times.size, data_rows, repairs)
    t = unwrap_midnight(times)
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
                int(numbers[i]),
                "duplicate_row",
                "row repeats the previous timecode"
                + (" with the same values" if same else " with different values")
                + f" (line {numbers[prev]}): dropped",
            )
            if strict:
                raise InputError("duplicate timecode (strict mode)", path, int(numbers[i]))
        elif t[i] < t[prev]:
            raise InputError(
                f"timecode {fields_tc(t[i])} goes back from {fields_tc(t[prev])} on line "
                f"{numbers[prev]} (a clock jump?); split the file there or fix the timecodes",
                path,
                int(numbers[i]),
            )
    kept = np.flatnonzero(keep)
    gaps = np.diff(t[kept])
    if gaps.size and gaps.max() > MAX_GAP_S:
        a, b = kept[np.argmax(gaps)], kept[np.argmax(gaps) + 1]
        raise InputError(
            f"timecode {fields_tc(t[b])} jumps {gaps.max():,.0f} s forward from {fields_tc(t[a])} on line "
            f"{numbers[a]} (a clock jump, or files joined?); gaps over {MAX_GAP_S:g} s are refused: "
            "split the file there or fix the timecodes",
            path,
            int(numbers[b]),
        )
    if header.trailing_comma:  # after the strict check: nothing was changed, so strict mode reads it too
        lines_with = "every line ends" if reader.comma_rows else "the header ends"
        repair(repairs, 1, "trailing_comma", f"{lines_with} with a comma: no column, ignored")
    values, columns = _other_columns(values, columns, is_channel, status, seen, repairs)
    if not keep.all():
        t, values, status, numbers = t[keep], values[keep], status[keep], numbers[keep]
    drop_frame = "drop_frame" in seen and seen["drop_frame"].count == times.size
    return CsvRows(
        path, header.count_name, columns, t, values, status, repairs, line_ending, numbers, drop_frame
    )


def _refuse_plain_number_times(bad: _Seen | None, data_rows: int, path: Path, resaved: bool = False) -> None:
    """The error for a file in the app's layout whose every row's Timecode is a plain number (seconds or
    a frame number, as other tools write their times; ``resaved``: a re-save's, perhaps with a decimal
    comma): it says how to import it as paired data."""
    if bad is None or bad.count != data_rows or not plain_number(bad.text):
        return
    try:
        float(bad.text.replace(",", ".", 1) if resaved else bad.text)  # a re-save's own text: 1,5
    except ValueError:
        return
    raise InputError(
        f"its Timecode column holds plain numbers ({_shown(bad.text)} on line {bad.line}), not the app's "
        "HH:MM:SS:FF.fff timecodes: another tool's CSV in the app's layout. Import it as paired data with "
        "its audio: --matrix FILE --audio AUDIO (times in seconds are read as such; add --fps for frame "
        "numbers)",
        path,
        bad.line,
    )


def _row_values(
    line: str, cells: list[str], columns: list[str], number: int, seen: dict[str, _Seen]
) -> list[float]:
    """A row's value cells as floats, NaN where a cell holds no number. Cells a spreadsheet's locale
    wrote otherwise than the app are read (``_cell_value``), and counted in ``seen`` by how."""
    if plain_number(line):
        try:
            return [float(x) for x in cells]
        except ValueError:
            pass
    vals = []
    for cell, column in zip(cells, columns):
        value, hows = _cell_value(cell)
        for how in hows:
            seen.setdefault(how, _Seen()).add(cell, number, column)
        vals.append(value)
    return vals


def _note_read_with_repairs(
    seen: dict[str, _Seen], header: CsvHeader, index_start: int, repairs: list
) -> None:
    """One repair for each way of writing the file's cells that was read otherwise than as they stand:
    number formats of a spreadsheet's locale, timecodes without zero padding, pandas' index column."""
    for how, (kind, done) in _NUMBER_FORMATS.items():
        if how in seen:
            s = seen[how]
            repair(
                repairs,
                s.line,
                "number_format",
                f"{counted(s.count, 'value')} written {kind} ({s.first()}): {done}",
            )
    if "unpadded" in seen:
        s = seen["unpadded"]
        padded = Timecode.parse(s.text).format()
        repair(
            repairs,
            s.line,
            "timecode_format",
            f"{counted(s.count, 'timecode')} written without zero padding ({s.first()}): read as {padded} "
            "would be",
        )
    if "clock_time" in seen:
        s = seen["clock_time"]
        repair(
            repairs,
            s.line,
            "timecode_format",
            f"{counted(s.count, 'timecode')} written as a clock time HH:MM:SS.fff ({s.first()}), not the "
            "app's HH:MM:SS:FF.fff: read as seconds and their fraction",
        )
    if "whole_second" in seen:
        s = seen["whole_second"]
        repair(
            repairs,
            s.line,
            "timecode_format",
            f"{counted(s.count, 'timecode')} with FF {CSV_TIMECODE_RATE:.3f} ({s.first()}), which the app "
            "never writes (its FF stops at 59.999; a writer rounding up?): read as the next second's frame 0",
        )
    if header.index_column is not None:
        name = repr(header.index_column) if header.index_column else "no name"
        what = f"a column before Timecode ({name} in the header: pandas' row index)"
        if "index" in seen:
            repair(
                repairs,
                1,
                "index_column",
                f"{what} dropped, though it does not count the rows ({seen['index'].first()})",
            )
        else:
            repair(repairs, 1, "index_column", f"{what} counting the rows from {index_start}: dropped")


def _empty_channels(
    reader: _RowReader, values: np.ndarray, status: np.ndarray, numbers: np.ndarray
) -> tuple[np.ndarray, list[str], list[bool]]:
    """The values, columns and which are channels, without the channel columns whose every cell on the
    rows with values is empty (a writer that leaves the head and eye angles empty: those channels have
    no data), each left out with a note (kind ``empty_channel``); never all of them. The rows they alone
    made BAD_VALUE are tracked again, their ``bad_value`` repairs withdrawn; the others' name the channels
    kept only, as does the first damaged cell ``seen`` quotes (``_warn_widespread``). A take of one row with
    values keeps them: its empty cell is as likely that row's damage."""
    columns, is_channel, repairs, seen = reader.header.columns, reader.is_channel, reader.repairs, reader.seen
    rows = np.flatnonzero(status != FrameStatus.FACE_LOST)
    # candidates first (no number in the first row with values), then each checked: no copy of the array
    candidates = [] if rows.size < 2 else np.flatnonzero(np.isnan(values[rows[0]]) & ~reader.written)
    empty = [j for j in candidates if is_channel[j] and np.isnan(values[rows, j]).all()]
    if not empty or len(empty) == sum(is_channel):
        return values, columns, is_channel
    keep = [j for j in range(len(columns)) if j not in empty]
    values = values[:, keep]
    names = [columns[j] for j in empty]
    columns, is_channel = [columns[j] for j in keep], [is_channel[j] for j in keep]
    message = f"{counted(len(names), 'channel')} with no value on any row ({', '.join(names)}): left out"
    repair(repairs, 1, "empty_channel", message)
    bad = np.flatnonzero(status == FrameStatus.BAD_VALUE)
    channels = np.flatnonzero(is_channel)
    damaged = np.isnan(values[np.ix_(bad, channels)])
    still = damaged.any(axis=1)
    restored = bad[~still]
    _renote_bad_values(
        reader, numbers[bad[still]], damaged[still], numbers[restored], [keep[j] for j in channels]
    )
    status[restored] = FrameStatus.TRACKED
    if bad.size:
        was = seen.pop("bad_value")
        # the first of the others: a kept channel's first cell no number (the rows before it are tracked
        # again), not the blank cell of a channel left out, whether or not any row is tracked again
        kept = [(line, j, text) for j, (text, line) in reader.first_bad.items() if j not in empty]
        if kept:
            line, j, text = min(kept)
            seen["bad_value"] = _Seen(was.count - restored.size, text, line, reader.header.columns[j])
    return values, columns, is_channel


def _renote_bad_values(
    reader: _RowReader, lines: np.ndarray, damaged: np.ndarray, restored: np.ndarray, kept: list[int]
) -> None:
    """The ``bad_value`` notes of the rows still damaged, on ``lines``, name only the channels kept
    (``kept``: their columns in the header; ``damaged``: which of them hold no number, rows x kept), quoting
    the first of those cells (blank, or the row's first cell written: ``first_written``); the rows tracked
    again, on ``restored``, lose their note. Only the rows still damaged are looked at one by one."""
    row_of = {line: k for k, line in enumerate(lines.tolist())}
    gone = set(restored.tolist())
    notes = []
    for note in reader.repairs:
        line = note["line"] if note["kind"] == "bad_value" else None
        if line in gone:
            continue
        k = row_of.get(line)
        if k is not None:
            columns = [kept[j] for j in np.flatnonzero(damaged[k])]
            first, text = reader.first_written.get(line, (None, ""))
            names = [reader.header.columns[j] for j in columns]
            note["message"] = _bad_value_message(names, text if first == columns[0] else "")
        notes.append(note)
    reader.repairs[:] = notes


def _warn_widespread(seen: dict[str, _Seen], frames: int, data_rows: int, repairs: list) -> None:
    """Say when damage is no longer the odd row: more than ``BAD_VALUE_SHARE`` of the frames lost their
    values, or more than ``BAD_TIMECODE_SHARE`` of the rows their timecodes (printed by import as
    warnings: a whole take of NaN is a file read wrongly, not a damaged row)."""
    bad = seen.get("bad_value")
    if bad and bad.count > max(1, BAD_VALUE_SHARE * frames):
        hint = ": a decimal comma?" if "," in bad.text else ": empty cells?" if not bad.text.strip() else ""
        message = f"{bad.count} of {frames} frames have non-numeric values ({bad.first()}){hint}"
        repair(repairs, None, "bad_values_widespread", message)
    tc = seen.get("bad_timecode")
    if tc and tc.count > max(1, BAD_TIMECODE_SHARE * data_rows):
        message = f"{tc.count} of {data_rows} rows dropped for timecodes that do not parse ({tc.first()})"
        repair(repairs, None, "bad_timecodes_widespread", message)


def _other_columns(
    values: np.ndarray,
    columns: list[str],
    is_channel: list[bool],
    status: np.ndarray,
    seen: dict[str, _Seen],
    repairs: list,
) -> tuple[np.ndarray, list[str]]:
    """The values and columns without the columns that are no channel and hold no number (a user's
    ``Notes``, empty or text), each left out with a note; another such column holding some cells that
    are not numbers keeps NaN there, also with a note. (Kind ``text_column``: a note, as nothing a
    channel holds was changed.)"""
    with_values = status != FrameStatus.FACE_LOST
    keep = []
    for j, name in enumerate(columns):
        missing = int(np.isnan(values[with_values, j]).sum()) if not is_channel[j] else 0
        if missing == 0:
            keep.append(j)
            continue
        text = seen.get(f"text {name}")
        example = f" ({text.first()})" if text else ""
        if missing == int(with_values.sum()):
            repair(repairs, 1, "text_column", f"column {name!r} holds no numbers{example}: left out")
        else:
            keep.append(j)
            repair(
                repairs,
                1,
                "text_column",
                f"column {name!r}: {missing} cells are not numbers{example}: NaN there",
            )
    if len(keep) == len(columns):
        return values, columns
    return values[:, keep], [columns[j] for j in keep]


def plain_number(text: str) -> bool:
    """Whether ``float()`` may read ``text`` (a cell, or a row of them): it reads ``1_0`` as 10.0 and
    U+0661 (an Arabic-Indic one) as 1.0, which no writer of numbers means; ASCII without ``_`` only."""
    return "_" not in text and text.isascii()


# How a spreadsheet's locale may write a number the app writes as ``-0.1421131641``: what ``_cell_value``
# reads, and the words of its repair (kind ``number_format``): how it was written, what was done.
_NUMBER_FORMATS = {
    "decimal_comma": ("with a decimal comma", "read with a decimal point"),
    "minus": ("with a U+2212 minus sign", "read as '-'"),
    "spaces": ("with non-breaking or narrow spaces around them", "spaces ignored"),
}
# A quoted cell of a comma-separated file holding one comma between digits: a decimal comma (a number
# with digit groups has more, or a point too).
_DECIMAL_COMMA = re.compile(r"[+-]?\d+,\d+", re.ASCII)


def _cell_value(text: str) -> tuple[float, tuple[str, ...]]:
    """A value cell as a float, and each way a spreadsheet's locale wrote it otherwise than the app does
    (keys of ``_NUMBER_FORMATS``: ``"\u22120,5"`` is two); NaN when it is not a decimal number of ASCII
    digits written in these ways."""
    try:
        if plain_number(text):
            return float(text), ()
    except ValueError:
        pass
    cell, hows = text.strip(), []  # str.strip also takes no-break and narrow spaces
    if cell != text.strip(" \t"):
        hows.append("spaces")
    if "\u2212" in cell:
        cell = cell.replace("\u2212", "-")
        hows.append("minus")
    if _DECIMAL_COMMA.fullmatch(cell):
        cell = cell.replace(",", ".")
        hows.append("decimal_comma")
    if not hows or not plain_number(cell):
        return math.nan, ()
    try:
        return float(cell), tuple(hows)
    except ValueError:
        return math.nan, ()


def fields_tc(seconds_of_day: float) -> str:
    return Timecode.from_seconds(seconds_of_day).format()


# A measured rate this close (relative) to a standard rate is that rate: the app writes 59.90 rows/s for 60.
STANDARD_TOLERANCE = 0.03


def nearest_standard(rate: float) -> float | None:
    """The standard frame rate nearest ``rate`` when within ``STANDARD_TOLERANCE`` of it (24 and 25 are
    4 % apart: the nearest, not the first), else None."""
    std = min(STANDARD_FPS, key=lambda s: abs(rate / s - 1))
    return std if abs(rate - std) / std < STANDARD_TOLERANCE else None


# Row steps beside a row with values that the frame rate is measured on (else on every row step).
MIN_RATE_STEPS = 10


def detect_fps(times: np.ndarray, with_values: np.ndarray | None = None) -> tuple[float, float]:
    """Nominal frame rate and the measured median frame period (s) from row times.

    ``with_values`` (a mask of the rows): the period is the median of the steps next to a row with
    values, when there are ``MIN_RATE_STEPS`` of them and it is the shorter: a take whose face is lost for
    most of it, its face-lost rows written at a slower cadence than its tracked ones, has the tracked rows'
    rate; one whose tracked rows were dropped (every other one, at the phone's busiest) keeps the rate of
    its face-lost rows (dropped rows only lengthen the steps).

    The nominal rate snaps to the nearest standard rate when within 3 % (the app writes 59.90 rows/s for
    "60"). The phone's own rates are 30 and 60 (formats doc §0.11): a Live Link Face take whose rows come
    at 59.94/s is a "60" take, as one at 59.90/s is. (Paired data from video tools, whose times may keep
    an NTSC rate, is measured by ``paired.column_rate``.)
    """
    if times.size < 2:
        return 60.0, 1 / 60.0
    steps = np.diff(times)
    period = float(np.median(steps))
    if with_values is not None:
        beside = with_values[:-1] | with_values[1:]
        if int(beside.sum()) >= MIN_RATE_STEPS:
            period = min(period, float(np.median(steps[beside])))
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
    """Say where the rows come at another rate than the take's (repair ``row_rate_change``), or unevenly
    at its rate (most steps half a frame or more off one period). The frames stay as they are: a slower
    stretch's rows with DROPPED frames between them."""
    stretches = row_rate_changes(times, period)
    for first, last, rate in stretches[:3]:
        until = "the end" if last == times.size - 1 else f"{times[last] - times[0]:.1f} s"
        gaps = int(missing_frames(times[first : last + 1], period).sum())
        how = f"at {rate:g}/s, not {fps:g}/s"
        if round(rate, 1) == round(fps, 1):
            how = f"unevenly (most steps half a frame or more off 1/{fps:g} s, {rate:g} rows/s in all)"
        repair(
            repairs,
            None,
            "row_rate_change",
            f"rows come {how}, from about {times[first] - times[0]:.1f} s "
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
    m = _VARIANT_RE.fullmatch(stem)
    assert m is not None
    variant = m.group("variant")
    return m.group("prefix"), variant.lower() if variant else None


def read_timecode_rate(rows: CsvRows, rate: float | None = None) -> float:
    """The rate the CSV's FF field counts at: ``rate`` if given, else the one ``timecode_rate_of``
    finds. Rows counted at another rate than the app's 60 get their times re-read at it (repair
    ``timecode_rate``); a rate FF passes is an ``InputError``. Rows whose part after the dot is the
    milliseconds of the second (NeuroSync Player's: ``millisecond_seconds``) are read so, at 60 (repair
    ``timecode_format``)."""
    t = rows.seconds_of_day
    fields = timecode_frames(t)  # split once, judged and re-read from
    if rate in (None, CSV_TIMECODE_RATE) and not rows.drop_frame:
        in_milliseconds = millisecond_seconds(fields)
        if in_milliseconds is not None:
            rows.seconds_of_day = in_milliseconds
            repair(
                rows.repairs,
                None,
                "timecode_format",
                f"timecodes written HH:MM:SS:FF.mmm with the milliseconds of the second after the dot (the "
                f"first: {fields_tc(t[0])}; on all {t.size} rows FF is within a frame of them at "
                f"{CSV_TIMECODE_RATE:g} fps, as NeuroSync Player writes them), not the app's sub-frame: "
                "read as seconds and milliseconds",
            )
            return CSV_TIMECODE_RATE
    top = float(fields.frames.max())
    if rate is None:
        rate = timecode_rate_of(fields)
        seen = f"FF never passes {top:.3f} over {fields.whole_seconds} whole seconds"
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
        rows.seconds_of_day = at_timecode_rate(fields, rate)
        message = f"timecode frames (FF) count at {rate:g} fps, not the app's {CSV_TIMECODE_RATE:g} ({seen})"
        repair(rows.repairs, None, "timecode_rate", f"{message}: times read as FF/{rate:g}")
    if rows.drop_frame and (real := drop_frame_seconds(rows.seconds_of_day, rate)) is not None:
        rows.seconds_of_day = real
        repair(
            rows.repairs,
            None,
            "timecode_rate",
            f"drop-frame timecodes (HH:MM:SS;FF) at {rate * 1000 / 1001:.2f} fps: the labels each minute "
            "skips are no dropped frames, times read as frames counted at that rate from the first row's "
            "label",
        )
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
    # every row's timecode, damaged rows' too (a take whose rows are mostly damaged has its rate, not the
    # one its few intact rows come at), face-lost rows' beside them (not those of a long loss alone)
    fps, period = detect_fps(rows.seconds_of_day, rows.status != FrameStatus.FACE_LOST)
    repairs = list(rows.repairs)
    note_far_values(rows, values[:, : len(known)], channels[: len(known)], repairs)
    note_gaps(rows, period, repairs)
    t, v, st, dropped = fill_dropped(rows.seconds_of_day, values, rows.status, period)
    t0 = float(t[0])
    prefix, variant = split_variant(rows.path.stem)
    slate, take_number, subject = parse_take_prefix(prefix)
    if unknown:
        repair(repairs, 1, "unknown_columns", f"columns kept under their own names: {unknown}")
        note_channel_typos(known, unknown, repairs)
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


# A value of a Live Link channel beyond this is no measurement: the app's shapes reach 1.05, its head and eye
# rotations about 0.7 (formats doc §2). A value typed without its decimal point (12 for 0.12) is one.
VALUE_LIMIT = 10.0
# A gap between rows this long is noted: the app drops a row now and then, never a second's worth.
GAP_NOTE_S = 1.0


def _row_line(rows: CsvRows, i: int) -> tuple[int | None, str]:
    """The file's line of row ``i`` (None if not found) and the words saying it. The fast path keeps no
    line numbers: the line is looked up by its timecode, once for each note that names one."""
    if rows.lines is not None:
        line: int | None = int(rows.lines[i])
    else:
        data = rows.path.read_bytes()
        at = data.find(b"\n" + fields_tc(rows.seconds_of_day[i]).encode() + b",")
        line = data.count(b"\n", 0, at) + 2 if at >= 0 else None
    return line, f" on line {line}" if line else ""


def counted(n: int, word: str) -> str:
    """``1 value``, ``2 values``."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def note_far_values(rows: CsvRows, values: np.ndarray, names: list[str], repairs: list) -> None:
    """Say (repair ``value_range``, a warning of import) when channel ``values`` (rows x ``names``) go
    beyond ``VALUE_LIMIT``: kept as they are, as the file may mean them, but no face makes them."""
    if not values.size:
        return
    with np.errstate(invalid="ignore"):
        # per column NaN-skipping, then across columns NaN-skipping too (a column of NaN only)
        top, bottom = (
            np.fmax.reduce(np.fmax.reduce(values, axis=0)),
            np.fmin.reduce(np.fmin.reduce(values, axis=0)),
        )
        if not (top > VALUE_LIMIT or bottom < -VALUE_LIMIT):
            return  # the common take: two passes over the values, no copy
        far = np.abs(values) > VALUE_LIMIT
    row, col = (int(i[0]) for i in np.nonzero(far))
    line, on_line = _row_line(rows, row)
    which = [ch.livelink_name(names[j]) for j in np.flatnonzero(far.any(axis=0))]
    more = f" and {len(which) - 5} more channels" if len(which) > 5 else ""
    first = f"{values[row, col]:g} in {ch.livelink_name(names[col])} at {fields_tc(rows.seconds_of_day[row])}"
    repair(
        repairs,
        line,
        "value_range",
        f"{counted(int(far.sum()), 'value')} beyond ±{VALUE_LIMIT:g} in {', '.join(which[:5])}{more} (the "
        f"first: {first}{on_line}), where the app's values stay within about ±1.05: typed without a decimal "
        "point? Kept as they are",
    )


def note_gaps(rows: CsvRows, period: float, repairs: list) -> None:
    """Note (repair ``gap``) where no rows come for ``GAP_NOTE_S`` or more (rows deleted from the middle):
    such a gap becomes DROPPED frames like any, but not the odd dropped row's."""
    t = rows.seconds_of_day
    steps = np.diff(t)
    at = np.flatnonzero(steps >= GAP_NOTE_S)
    for i in at[:3]:
        line, on_line = _row_line(rows, int(i) + 1)
        frames = int(np.rint(steps[i] / period)) - 1
        repair(
            repairs,
            line,
            "gap",
            f"a gap of {steps[i]:.1f} s with no rows, from {fields_tc(t[i])} to {fields_tc(t[i + 1])}"
            f"{on_line}: {frames} DROPPED frames (rows deleted?)",
        )
    if at.size > 3:
        repair(repairs, None, "gap", f"and {at.size - 3} more gaps of {GAP_NOTE_S:g} s or more")


def note_channel_typos(known: list[str], unknown: list[str], repairs: list) -> None:
    """Say (repair ``channel_typo``, a warning of import) when a column that is no channel is close to a
    channel the header lacks (``JawOpne`` without ``JawOpen``): it stays a column of its own name, as a
    rig's control would, but the take has no such channel."""
    present = {ch.udp_index(c) for c in known}
    missing = [name for i, name in enumerate(ch.LIVELINK_ORDER) if i not in present]
    for name in unknown:
        meant = ch.meant_channel(name, missing)
        if meant is not None:
            repair(
                repairs,
                1,
                "channel_typo",
                f"no {meant} column; {name} is not a channel: did you mean {meant}? (rename the column to "
                f"import it as {meant})",
            )


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
    # strict mode refused the careful parser's timecode_format notes before: this is the milliseconds' one
    in_milliseconds = [r for r in take.meta.repairs if r["kind"] == "timecode_format"]
    if strict and in_milliseconds:
        raise InputError(f"{in_milliseconds[0]['message']} (strict mode)", path)
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
