"""Live Link Face CSVs a spreadsheet or script re-saved whole (a UTF-8 BOM, CRLF line ends, a comma ending
every line, pandas' index column, the header's names in quotes, and these together) are read by pyarrow
with the careful parser's per-row logic for the odd lines only, to exactly the careful parser's result:
differential tests over re-saves of the real samples, intact and with a few damaged rows. Also: values
written with unquoted decimal commas are one error saying so, and a cell written with a U+2212 minus and
a decimal comma gets both notes."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLES
from test_csv_long_damaged import assert_same, read_counting_careful_lines

from capture import csv_take
from capture.csv_take import CsvRows, _read_careful, read_csv_rows
from capture.errors import InputError

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


def resave(lines: list[str], ways: tuple[str, ...], index_from: int = 0) -> bytes:
    """The file of ``lines`` (header first) as a spreadsheet or script re-saves it in ``ways``."""
    header, body = lines[0], lines[1:]
    if "quoted" in ways:
        header = ",".join(f'"{name}"' for name in header.split(","))
    if "index" in ways:
        header = ('""' if "quoted" in ways else "") + "," + header
        counted, out = index_from, []
        for line in body:
            if line:  # pandas counts its rows; an empty line here stands for one the file has damaged
                out.append(f"{counted},{line}")
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


@pytest.mark.parametrize("damaged", [False, True], ids=["intact", "damaged"])
@pytest.mark.parametrize("ways", VARIANTS, ids=["+".join(v) for v in VARIANTS])
@pytest.mark.parametrize("sample", sorted(REAL))
def test_a_resaved_file_takes_the_fast_path_to_the_careful_parsers_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sample: str, ways: tuple[str, ...], damaged: bool
) -> None:
    lines = REAL[sample].read_text().splitlines()
    path = tmp_path / f"{sample}.csv"
    path.write_bytes(resave(damage(lines) if damaged else lines, ways))
    fast, want = read_without_careful(path, monkeypatch), careful(path)
    assert not isinstance(want, str), want
    assert not isinstance(fast, str), fast
    assert_same(fast, want, lines_kept=False)
    kinds = {r["kind"] for r in want.repairs}
    assert ("bom" in kinds) == ("bom" in ways) and ("index_column" in kinds) == ("index" in ways)
    assert ("trailing_comma" in kinds) == ("comma" in ways)
    assert want.line_ending == ("\r\n" if "crlf" in ways else "\n")
    if damaged:
        assert {"bad_timecode", "wrong_fields", "duplicate_row", "bad_value", "bad_count"} <= kinds


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


def test_a_resaved_file_costs_what_the_apps_does_in_the_per_row_reader(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Only the damaged lines go through the careful parser's per-row logic, as in the app's own file."""
    lines = damage(REAL["S07"].read_text().splitlines())
    path = tmp_path / "t.csv"
    path.write_bytes(resave(lines, WAYS))
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
