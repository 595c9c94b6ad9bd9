"""Live Link Face CSVs a spreadsheet or script re-saved whole (a UTF-8 BOM, CRLF line ends, a comma ending
every line, pandas' index column, the header's names in quotes, every cell or the timecodes in quotes, and
these together) are read by pyarrow with the careful parser's per-row logic for the odd lines only, to
exactly the careful parser's result: differential tests over re-saves of the real samples, intact and with
a few damaged rows. A long file is read a part at a time, its peak memory about its values. Also: values
written with unquoted decimal commas are one error saying so, and a cell written with a U+2212 minus and
a decimal comma gets both notes."""

from __future__ import annotations

import itertools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLES
from test_csv_long_damaged import assert_same, read_counting_careful_lines
from test_long_take_memory import _traced_peak

from capture import csv_take
from capture.csv_take import CsvRows, _read_careful, read_csv_rows
from capture.errors import InputError
from capture.timecode import Timecode

REAL = {
    "S07": SAMPLES / "livelinkface/alexdjulin_S07/S07-001.csv",
    "S88": SAMPLES / "livelinkface/alexdjulin_S88/S88-001.csv",
    "MySlate": SAMPLES / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv",
    "testset": SAMPLES / "paired/neurosync-trainer-lite-testset/testset.csv",
}
pytestmark = pytest.mark.skipif(
    not all(p.is_file() for p in REAL.values()), reason="the real Live Link Face samples are not here"
)

WAYS = ("bom", "crlf", "comma", "index", "quoted")
# each way alone, each pair, all together
VARIANTS = [(w,) for w in WAYS] + list(itertools.combinations(WAYS, 2)) + [WAYS]


def quote(cells: list[str]) -> str:
    return ",".join(f'"{cell}"' for cell in cells)


def resave(lines: list[str], ways: tuple[str, ...], index_from: int = 0) -> bytes:
    """The file of ``lines`` (header first) as a spreadsheet or script re-saves it in ``ways``: ``quoted``
    the header's names in quotes; ``cells`` every cell in quotes (pandas' ``quoting=csv.QUOTE_ALL``, Google
    Sheets); ``tc`` the header's names and the timecodes (pandas' ``QUOTE_NONNUMERIC``)."""
    header, body = lines[0], lines[1:]
    quoting = {"quoted", "cells", "tc"} & set(ways)
    if quoting:
        header = quote(header.split(","))
    if "cells" in ways:
        body = [quote(line.split(",")) if line else line for line in body]
    elif "tc" in ways:
        body = ['"{}"{}{}'.format(*line.partition(",")) if line else line for line in body]
    if "index" in ways:
        header = ('""' if quoting else "") + "," + header
        counted, out = index_from, []
        for line in body:
            if line:  # pandas counts its rows; an empty line here stands for one the file has damaged
                out.append(f'"{counted}",{line}' if "cells" in ways else f"{counted},{line}")
                counted += 1
            else:
                out.append(line)
        body = out
    out = [header, *body]
    if "comma" in ways:
        out = [line + "," if line else line for line in out]
    end = "\r\n" if "crlf" in ways else "\n"
    return (b"\xef\xbb\xbf" if "bom" in ways else b"") + (end.join(out) + end).encode()


def damage(lines: list[str]) -> list[str]:
    """A few damaged rows, as a long take may hold: a text cell, a bad timecode, a row of too few fields,
    a duplicated row, an empty line, a NaN and an empty cell, a face-lost row, a count of 60."""
    lines = list(lines)
    n = len(lines)

    with_values = [i for i in range(1, n) if lines[i].count(",") > 1]  # S88 has runs of face-lost rows

    def tracked(at: int) -> int:  # the row holding values at about ``at / n`` of them
        return with_values[at * len(with_values) // n]

    def cell(at: int, column: int, text: str) -> None:
        cells = lines[tracked(at)].split(",")
        cells[column] = text
        lines[tracked(at)] = ",".join(cells)

    cell(n // 7, 20, "abc")
    lines[tracked(n // 5)] = "12:3x:" + lines[tracked(n // 5)][6:]
    lines[tracked(n // 4)] = lines[tracked(n // 4)][:200]
    lines[n // 3] = lines[n // 3 - 1]
    lines[n // 2] = ""
    cell(n * 3 // 5, 40, "nan")
    cell(n * 3 // 5 + 5, 41, "")
    lines[n * 2 // 3] = lines[n * 2 // 3].split(",")[0] + ",0"
    lines[tracked(n * 3 // 4)] = lines[tracked(n * 3 // 4)].replace(",61,", ",60,", 1)
    return lines


def read_without_careful(path: Path, monkeypatch: pytest.MonkeyPatch, strict: bool = False) -> CsvRows | str:
    """``read_csv_rows(path)`` (or its error's text), failing if the careful parser read the file whole."""

    def whole(*args: object) -> None:
        raise AssertionError("the careful parser read the whole file")

    with monkeypatch.context() as patched:
        patched.setattr(csv_take, "_read_careful", whole)
        try:
            return read_csv_rows(path, strict)
        except InputError as exc:
            return str(exc)


def careful(path: Path, strict: bool = False) -> CsvRows | str:
    try:
        return _read_careful(path, strict)
    except InputError as exc:
        return str(exc)


def same_both_ways(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sample: str, ways: tuple[str, ...], damaged: bool
) -> CsvRows:
    """The careful parser's reading of the sample re-saved ``ways`` (damaged or not), checked to be the
    fast path's too."""
    lines = REAL[sample].read_text().splitlines()
    path = tmp_path / f"{sample}.csv"
    path.write_bytes(resave(damage(lines) if damaged else lines, ways))
    fast, want = read_without_careful(path, monkeypatch), careful(path)
    assert not isinstance(want, str), want
    assert not isinstance(fast, str), fast
    assert_same(fast, want, lines_kept=False)
    return want


@pytest.mark.parametrize("damaged", [False, True], ids=["intact", "damaged"])
@pytest.mark.parametrize("ways", VARIANTS, ids=["+".join(v) for v in VARIANTS])
@pytest.mark.parametrize("sample", sorted(REAL))
def test_a_resaved_file_takes_the_fast_path_to_the_careful_parsers_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sample: str, ways: tuple[str, ...], damaged: bool
) -> None:
    want = same_both_ways(tmp_path, monkeypatch, sample, ways, damaged)
    kinds = {r["kind"] for r in want.repairs}
    assert ("bom" in kinds) == ("bom" in ways) and ("index_column" in kinds) == ("index" in ways)
    assert ("trailing_comma" in kinds) == ("comma" in ways)
    assert want.line_ending == ("\r\n" if "crlf" in ways else "\n")
    if damaged:
        assert {"bad_timecode", "wrong_fields", "duplicate_row", "bad_value", "bad_count"} <= kinds


# Every cell quoted, or the timecodes (and the header's names): alone, and with the other ways of a re-save.
QUOTED = [("cells",), ("tc",), ("cells", "bom", "crlf", "comma", "index"), ("tc", "index", "crlf")]


@pytest.mark.parametrize("damaged", [False, True], ids=["intact", "damaged"])
@pytest.mark.parametrize("ways", QUOTED, ids=["+".join(v) for v in QUOTED])
@pytest.mark.parametrize("sample", ["S88", "testset"])  # runs of face-lost rows; the paired data's writer
def test_a_file_of_quoted_cells_takes_the_fast_path_to_the_careful_parsers_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sample: str, ways: tuple[str, ...], damaged: bool
) -> None:
    """Quotes are read as the careful parser's csv module reads them, with no note (nothing was changed)."""
    want = same_both_ways(tmp_path, monkeypatch, sample, ways, damaged)
    if not damaged:
        notes = [("bom", "bom"), ("index", "index_column"), ("comma", "trailing_comma")]
        assert [r["kind"] for r in want.repairs] == [kind for way, kind in notes if way in ways]


@pytest.mark.parametrize("ways", [("cells",), ("cells", "index", "crlf")], ids=["cells", "cells+index+crlf"])
def test_strict_mode_reads_a_file_of_quoted_cells_as_the_careful_parser_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ways: tuple[str, ...]
) -> None:
    """Quotes are no repair: strict mode reads the file; pandas' index column is one, as for the careful
    parser."""
    path = tmp_path / "t.csv"
    path.write_bytes(resave(REAL["S07"].read_text().splitlines(), ways))
    fast, want = read_without_careful(path, monkeypatch, True), careful(path, True)
    if "index" in ways:
        assert isinstance(fast, str) and "pandas' row index" in fast and fast == want
    else:
        assert_same(fast, want, lines_kept=False)


def test_odd_quotes_in_a_file_of_quoted_cells_are_read_as_the_careful_parser_reads_them(
    tmp_path: Path,
) -> None:
    """A quote left open (pyarrow carries it into the next line), a cell not quoted, text after a closing
    quote, a quoted decimal comma, a quote inside a cell: what the careful parser makes of each."""
    lines = REAL["S07"].read_text().splitlines()
    text = resave(lines, ("cells", "crlf")).decode().split("\r\n")

    def cell(at: int, column: int, written: str) -> None:  # a cell of line ``at + 1`` written otherwise
        row = [f'"{c}"' for c in text[at][1:-1].split('","')]
        row[column] = written.format(row[column][1:-1])
        text[at] = ",".join(row)

    text[300] = text[300][:-1]  # the last cell's closing quote lost: the csv module closes it at the line end
    cell(400, 2, "{}")  # the first value not quoted
    cell(450, 0, '"{}"x')  # text after the timecode's closing quote: a bad timecode
    cell(500, 3, '"{}"5')  # text after a closing quote: "0.1234"5 is 0.12345, as the csv module reads it
    text[600] = text[600].replace('","0.', '","0,', 1)  # "0,1421": a quoted decimal comma
    cell(700, 4, '0."{}"')  # quotes inside a cell that no quote opens: a text cell
    path = tmp_path / "t.csv"
    path.write_bytes("\r\n".join(text).encode())
    want = _read_careful(path, False)
    assert_same(read_csv_rows(path), want, lines_kept=False)
    assert {"bad_timecode", "bad_value", "number_format"} <= {r["kind"] for r in want.repairs}


@pytest.mark.parametrize("ways", [("index",), ("index", "crlf", "comma")], ids=["index", "index+crlf+comma"])
def test_pandas_index_counting_from_1_or_miscounting_is_noted_as_the_careful_parser_notes_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ways: tuple[str, ...]
) -> None:
    lines = REAL["S88"].read_text().splitlines()  # face-lost rows among pyarrow's: read line by line
    path = tmp_path / "from1.csv"
    path.write_bytes(resave(lines, ways, index_from=1))
    fast = read_without_careful(path, monkeypatch)
    assert_same(fast, careful(path), lines_kept=False)
    assert "counting the rows from 1" in fast.repairs[0]["message"]
    # a row of pyarrow's whose index does not count the rows: the careful parser's note, naming it
    text = resave(lines, ways).decode().replace("\n1000,", "\n1001,", 1)
    path.write_bytes(text.encode())
    fast = read_without_careful(path, monkeypatch)
    assert_same(fast, careful(path), lines_kept=False)
    (note,) = [r for r in fast.repairs if r["kind"] == "index_column"]
    assert "does not count the rows ('1001' on line 1002)" in note["message"]
    # the first data line read line by line (a face-lost row) starting the count at 1
    first_lost = lines[1].split(",")[0] + ",0"
    path.write_bytes(resave([lines[0], first_lost, *lines[2:]], ways, index_from=1))
    assert_same(read_without_careful(path, monkeypatch), careful(path), lines_kept=False)


@pytest.mark.parametrize("strict", [False, True])
def test_errors_and_strict_mode_are_the_careful_parsers_on_a_resaved_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, strict: bool
) -> None:
    lines = REAL["S07"].read_text().splitlines()
    path = tmp_path / "t.csv"
    path.write_bytes(resave(lines, WAYS))
    fast, want = read_without_careful(path, monkeypatch, strict), careful(path, strict)
    if strict:  # the BOM is the first repair
        assert isinstance(fast, str) and "byte-order mark" in fast and fast == want
    else:
        assert_same(fast, want, lines_kept=False)
    # a value where the comma ending every line should leave none: the careful parser's error
    text = resave(lines, ("comma", "crlf")).decode()
    at = text.index("\r\n", 100_000)
    path.write_bytes((text[:at] + "5" + text[at:]).encode())
    fast = read_without_careful(path, monkeypatch, strict)
    assert isinstance(fast, str) and "header's last column is empty" in fast and fast == careful(path, strict)
    # a timecode going back
    damaged = list(lines)
    damaged[1500], damaged[1501] = damaged[1501], damaged[1500]
    path.write_bytes(resave(damaged, ("bom", "crlf")))
    fast = read_without_careful(path, monkeypatch, strict)
    assert isinstance(fast, str) and fast == careful(path, strict)


def test_a_lone_cr_sends_the_file_to_the_careful_parser(tmp_path: Path) -> None:
    lines = REAL["S07"].read_text().splitlines()
    text = resave(lines, ("crlf",)).decode()
    at = text.index("\r\n", 200_000)
    path = tmp_path / "t.csv"
    path.write_bytes((text[:at] + "\r" + text[at + 2 :]).encode())  # one line ending at a lone CR
    assert_same(read_csv_rows(path), _read_careful(path, False), lines_kept=False)


@pytest.mark.parametrize("ways", [WAYS, QUOTED[2]], ids=["+".join(WAYS), "+".join(QUOTED[2])])
def test_a_resaved_file_costs_what_the_apps_does_in_the_per_row_reader(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ways: tuple[str, ...]
) -> None:
    """Only the damaged lines go through the careful parser's per-row logic, as in the app's own file."""
    lines = damage(REAL["S07"].read_text().splitlines())
    path = tmp_path / "t.csv"
    path.write_bytes(resave(lines, ways))
    _, careful_lines = read_counting_careful_lines(path, monkeypatch)
    assert 5 <= careful_lines <= 12


# Unquoted decimal commas: each value splits in two fields.
def decimal_comma_lines(lines: list[str], quote: bool = False) -> list[str]:
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        if len(cells) > 2:
            cells[2:] = [(f'"{x}"' if quote else x).replace(".", ",") for x in cells[2:]]
        out.append(",".join(cells))
    return out


@pytest.mark.parametrize("sample", ["S07", "S88"])
@pytest.mark.parametrize("strict", [False, True])
def test_unquoted_decimal_commas_are_one_error_saying_so(tmp_path: Path, sample: str, strict: bool) -> None:
    path = tmp_path / "t.csv"
    path.write_text("\n".join(decimal_comma_lines(REAL[sample].read_text().splitlines())) + "\n")
    for read in (read_csv_rows, _read_careful):
        with pytest.raises(InputError) as exc:
            read(path, strict)
        message = str(exc.value)
        assert "decimal comma" in message and "without quotes" in message and "line 2" in message
        assert "save it with '.' as the decimal point" in message and "124 fields" in message
        assert "\n" not in message


def test_a_few_rows_of_unquoted_decimal_commas_are_dropped_saying_why(tmp_path: Path) -> None:
    lines = REAL["S07"].read_text().splitlines()
    lines[10] = decimal_comma_lines([lines[0], lines[10]])[1]
    path = tmp_path / "t.csv"
    path.write_text("\n".join(lines) + "\n")
    rows = read_csv_rows(path)
    assert_same(rows, _read_careful(path, False), lines_kept=False)
    (note,) = rows.repairs
    assert note["kind"] == "wrong_fields" and note["line"] == 11
    assert "decimal commas without quotes?" in note["message"]


def test_quoted_decimal_commas_are_still_read(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    path.write_text("\n".join(decimal_comma_lines(REAL["S07"].read_text().splitlines(), quote=True)) + "\n")
    rows = read_csv_rows(path)
    assert [r["kind"] for r in rows.repairs] == ["number_format"]


def test_a_cell_with_a_unicode_minus_and_a_decimal_comma_gets_both_notes(tmp_path: Path) -> None:
    lines = REAL["testset"].read_text().splitlines()
    cells = lines[5].split(",")
    at = next(i for i, c in enumerate(cells) if c.startswith("-") and i > 1)
    cells[at] = '"\u2212' + cells[at][1:].replace(".", ",") + '"'
    lines[5] = ",".join(cells)
    path = tmp_path / "t.csv"
    path.write_text("\n".join(lines) + "\n")
    rows = read_csv_rows(path)
    assert_same(rows, _read_careful(path, False), lines_kept=False)
    notes = [r["message"] for r in rows.repairs if r["kind"] == "number_format"]
    assert len(notes) == 2
    assert any("decimal comma" in m for m in notes) and any("U+2212 minus" in m for m in notes)
    assert all("on line 6" in m for m in notes)
    want = float(REAL["testset"].read_text().splitlines()[5].split(",")[at])
    assert rows.values[4, at - 2] == np.float32(want) < 0


@pytest.mark.parametrize("rows, share", [(300, 0.6), (1000, 0.6), (1000, 0.9)])
def test_a_file_with_text_on_most_lines_is_read_by_the_careful_parser_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, rows: int, share: float
) -> None:
    """Merging pyarrow's few rows into the careful parser's many cost 4-6 times the careful parser's whole
    read: most lines to read line by line send the file to it (``MAX_MENDED_SHARE``)."""
    lines = REAL["S07"].read_text().splitlines()
    rng = np.random.default_rng(rows)
    texts = rng.random(rows) < share
    body = [line + "," + ("said hi" if text else "0") for line, text in zip(lines[1 : rows + 1], texts)]
    path = tmp_path / "t.csv"
    path.write_text("\n".join([lines[0] + ",Notes", *body]) + "\n")
    whole = []
    read_whole = csv_take._read_careful
    monkeypatch.setattr(csv_take, "_read_careful", lambda *args: whole.append(1) or read_whole(*args))
    rows_read = read_csv_rows(path)
    assert whole == [1]
    assert_same(rows_read, read_whole(path, False), lines_kept=False)
    assert [r["kind"] for r in rows_read.repairs] == ["text_column"]


@pytest.mark.parametrize("ways", [WAYS, QUOTED[2]], ids=["+".join(WAYS), "+".join(QUOTED[2])])
def test_a_long_file_read_part_by_part_is_read_as_in_one_piece(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ways: tuple[str, ...]
) -> None:
    """pyarrow reads a long file in parts (``PART_BYTES``), and the line index scans it in chunks, each
    given back once read: with both made small, part and chunk bounds fall everywhere (a CRLF's CR ending
    one chunk, its LF starting the next), and the result is the careful parser's still."""
    lines = damage(REAL["S07"].read_text().splitlines())
    path = tmp_path / "t.csv"
    path.write_bytes(resave(lines, ways))
    monkeypatch.setattr(csv_take, "PART_BYTES", 40_000)
    monkeypatch.setattr(csv_take._Lines, "CHUNK", 4093)
    fast, careful_lines = read_counting_careful_lines(path, monkeypatch)
    assert_same(fast, _read_careful(path, False), lines_kept=False)
    assert 5 <= careful_lines <= 12


# Reads a CSV (argv[1]) in a fresh process, pyarrow reading a part of PART_BYTES (argv[3]) at a time, and
# prints how much its peak resident memory grew (MB), and its values' size: a short file (argv[2]) read
# first, so that the libraries' code and pyarrow's threads are no part of the growth.
PEAK_GROWTH = """
import sys
from capture import csv_take

def peak():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM")) / 1024

csv_take.read_csv_rows(sys.argv[2])
csv_take.PART_BYTES = int(sys.argv[3])
before = peak()
rows = csv_take.read_csv_rows(sys.argv[1])
print(peak() - before, rows.values.nbytes / 2**20)
"""


@pytest.fixture(scope="module")
def long_resaved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 60,000-row take (47 MB) re-saved with a BOM, CRLF, a comma ending every line and pandas' index
    column, and the sample it repeats re-saved so (a short file)."""
    lines = REAL["S07"].read_text().splitlines()
    header, body = lines[0], lines[1:]
    t0 = Timecode.parse(body[0].split(",", 1)[0]).seconds_of_day
    rows = [
        Timecode.from_seconds(t0 + i / 60).format() + "," + body[i % len(body)].split(",", 1)[1]
        for i in range(60_000)
    ]
    ways = ("bom", "crlf", "comma", "index")
    folder = tmp_path_factory.mktemp("long")
    path, short = folder / "long.csv", folder / "short.csv"
    path.write_bytes(resave([header, *rows], ways))
    short.write_bytes(resave(lines, ways))
    return path, short


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads the peak memory from /proc")
def test_the_parse_of_a_long_resaved_file_holds_little_more_than_its_values(
    long_resaved: tuple[Path, Path],
) -> None:
    """Read a part at a time, each part's float64 table turned into the values and its mapped pages given
    back before the next: the peak grows by the values and about one part's read, not by the file and a
    float64 table of it besides (the whole-file read grew by 116-138 MB here, 2.5-2.9 times the file's 47
    MB; the parts' values joined at the end by 42-48 MB; now by 30-39 MB)."""
    path, short = long_resaved
    size_mb = path.stat().st_size / 2**20
    run = subprocess.run(
        [sys.executable, "-c", PEAK_GROWTH, str(path), str(short), str(1 << 22)],
        capture_output=True,
        text=True,
        cwd=Path(csv_take.__file__).parents[1],
        check=True,
    )
    growth, values_mb = map(float, run.stdout.split())
    assert growth < values_mb + size_mb, (growth, values_mb, size_mb)


def test_the_parts_values_are_written_into_one_array_not_joined(
    long_resaved: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each part's values go straight into the one array of the take's values (allocated for the rows the
    file's bytes hold, trimmed in place), not into an array per part joined at the end, which held them
    twice: NumPy's traced peak of the parse was 3.2 times the values here, now 1.4 (pyarrow's own buffers
    are not traced: the figure is the same on every run)."""
    path, short = long_resaved
    read_csv_rows(short)  # the libraries' first use: no part of the peak
    monkeypatch.setattr(csv_take, "PART_BYTES", 1 << 22)
    rows, peak = _traced_peak(read_csv_rows, path)
    assert rows.values.shape == (60_000, 61) and not rows.repairs[3:]  # bom, index_column, trailing_comma
    assert peak < 1.6 * rows.values.nbytes, peak / rows.values.nbytes
