"""Quotes first met past the first 64 kB of a Live Link Face CSV (a spreadsheet's re-save of the later rows, a
quoted timecode or cell here and there) are read by pyarrow, with quoting on in the parts of the file that
hold them, to exactly the careful parser's result: differential tests over the real samples, intact and
damaged, in strict mode too, with the careful parser's per-row logic for no more lines than the same file
without quotes needs. Also: rows that get shorter further on (fewer digits) grow the values' array that
pyarrow's parts are written into."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_csv_long_damaged import assert_same, read_counting_careful_lines
from test_csv_resaved_fast import REAL, careful, damage, quote, read_without_careful

from capture import csv_take
from capture.csv_take import _read_careful

pytestmark = pytest.mark.skipif(
    not all(p.is_file() for p in REAL.values()), reason="the real Live Link Face samples are not here"
)

# How quotes come late into a file: every cell of its later rows (a spreadsheet's re-save of them), their
# timecodes only, one value cell, every 50th timecode, one quoted decimal comma (a number pyarrow cannot
# read even with quoting on: that line goes to the careful parser's per-row logic).
LATE = ("cells", "tc", "one", "scattered", "decimal_comma")


def late_quotes(lines: list[str], way: str) -> list[str]:
    """``lines`` (header first) with quotes ``way`` from a third of the way in (well past 64 kB)."""
    out = list(lines)
    start = len(lines) // 3
    tracked = [i for i in range(start, len(lines)) if lines[i].count(",") > 2]

    def quoted_timecode(i: int) -> None:
        out[i] = '"{}"{}{}'.format(*out[i].partition(","))

    if way == "cells":
        out[start:] = [quote(line.split(",")) if line else line for line in out[start:]]
    elif way == "tc":
        for i in range(start, len(lines)):
            if out[i]:
                quoted_timecode(i)
    elif way == "scattered":
        for i in tracked[::50]:
            quoted_timecode(i)
    else:
        cells = out[tracked[0]].split(",")
        number = cells[7].lstrip("-")
        cells[7] = '"' + (number.replace(".", ",") if way == "decimal_comma" else number) + '"'
        out[tracked[0]] = ",".join(cells)
    return out


def write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("damaged", [False, True], ids=["intact", "damaged"])
@pytest.mark.parametrize("way", LATE)
@pytest.mark.parametrize("sample", ["S88", "testset"])  # runs of face-lost rows; the paired data's writer
def test_late_quotes_take_the_fast_path_to_the_careful_parsers_result(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sample: str, way: str, damaged: bool
) -> None:
    lines = REAL[sample].read_text().splitlines()
    if damaged:
        lines = damage(lines)
    plain = write(tmp_path / "plain.csv", lines)
    path = write(tmp_path / "late.csv", late_quotes(lines, way))
    assert b'"' not in path.read_bytes()[:65536]
    fast, want = read_without_careful(path, monkeypatch), careful(path)
    assert not isinstance(want, str), want
    assert not isinstance(fast, str), fast
    assert_same(fast, want, lines_kept=False)
    # the per-row logic reads the lines it reads in the file without quotes (damaged, face-lost), no more
    _, without_quotes = read_counting_careful_lines(plain, monkeypatch)
    _, with_quotes = read_counting_careful_lines(path, monkeypatch)
    assert with_quotes == without_quotes + (way == "decimal_comma")
    if way == "decimal_comma":
        assert "number_format" in {r["kind"] for r in want.repairs}


@pytest.mark.parametrize("damaged", [False, True], ids=["intact", "damaged"])
@pytest.mark.parametrize("way", ["cells", "scattered"])
def test_strict_mode_reads_late_quotes_as_the_careful_parser_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, way: str, damaged: bool
) -> None:
    """Quotes are no repair: strict mode reads the intact file, and refuses the damaged one with the careful
    parser's error."""
    lines = REAL["S07"].read_text().splitlines()
    path = write(tmp_path / "late.csv", late_quotes(damage(lines) if damaged else lines, way))
    fast, want = read_without_careful(path, monkeypatch, True), careful(path, True)
    if damaged:
        assert isinstance(fast, str) and "strict mode" in fast and fast == want
    else:
        assert_same(fast, want, lines_kept=False)


@pytest.mark.parametrize("way", ["cells", "one"])
def test_parts_with_and_without_quotes_read_as_the_careful_parser_reads_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, way: str
) -> None:
    """Read in small parts, those before the quotes are read without quoting, the others with: the result
    is the careful parser's still, damaged rows in both kinds of part."""
    lines = late_quotes(damage(REAL["S07"].read_text().splitlines()), way)
    path = write(tmp_path / "late.csv", lines)
    monkeypatch.setattr(csv_take, "PART_BYTES", 40_000)
    fast = read_without_careful(path, monkeypatch)
    monkeypatch.undo()
    assert_same(fast, _read_careful(path, False), lines_kept=False)


def test_rows_getting_shorter_further_on_grow_the_values_array(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The values' array is allocated for the rows the first part's bytes per row foretell: later rows with
    fewer digits (a re-save writing 0.25 for 0.2500000000) hold more rows than that, which grow it."""
    lines = REAL["S07"].read_text().splitlines()
    short = [lines[0], *lines[1:200]]
    for line in lines[200:]:
        cells = line.split(",")
        short.append(",".join(cells[:2] + [f"{float(c):.2g}" for c in cells[2:]]))
    path = write(tmp_path / "short.csv", short)
    monkeypatch.setattr(csv_take, "PART_BYTES", 60_000)
    resized = []  # (rows before, rows after)
    resize = csv_take.GrowingRows.resize
    monkeypatch.setattr(
        csv_take.GrowingRows,
        "resize",
        lambda self, rows: resized.append((len(self), rows)) or resize(self, rows),
    )
    fast = read_without_careful(path, monkeypatch)
    monkeypatch.undo()
    assert any(after > before > 0 for before, after in resized)  # grown in place
    assert_same(fast, _read_careful(path, False), lines_kept=False)
