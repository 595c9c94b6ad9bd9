"""Review of the CSV fast path's parts (quotes anywhere read by pyarrow part by part, the values written into
one array): a stray quote (damage, an edit) that pyarrow carries past its line's end no longer sends the
whole file to the careful parser; quotes opened in one part and closed in the next, and quoted line ends
across a part's edge, read to the careful parser's result; the values' array is the careful parser's kind
(float32, C-contiguous, writable, owning its memory) when rows get shorter or longer from part to part."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from test_csv_long_damaged import assert_same, read_counting_careful_lines
from test_csv_resaved_fast import REAL, careful, damage, read_without_careful, resave

from capture import csv_take
from capture.errors import InputError

pytestmark = pytest.mark.skipif(
    not all(p.is_file() for p in REAL.values()), reason="the real Live Link Face samples are not here"
)


def full_row(lines: list[str], start: int) -> int:
    """The first line from ``start`` that is a whole row (not one ``damage`` cut short)."""
    return next(i for i in range(start, len(lines)) if lines[i].count(",") > 50)


def stray(lines: list[str], way: str) -> list[str]:
    """``lines`` with one quote that nothing closes, half way in: opening a value cell, the timecode, or a
    line of its own."""
    out = list(lines)
    k = full_row(out, len(out) // 2)
    if way == "value":
        cells = out[k].split(",")
        cells[5] = '"' + cells[5]
        out[k] = ",".join(cells)
    elif way == "tc":
        out[k] = '"' + out[k]
    else:
        out.insert(k, '"')
    return out


@pytest.mark.parametrize(
    ("way", "ways", "damaged"),
    [
        ("value", (), False),
        ("tc", (), True),
        ("line", (), False),
        ("value", ("bom", "crlf", "comma", "index"), True),
    ],
)
def test_a_stray_quote_is_read_line_by_line_not_the_whole_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, way: str, ways: tuple[str, ...], damaged: bool
) -> None:
    """pyarrow, reading the part holding the quote with quoting on, carries it into the lines after it (its
    rows are no longer the file's lines): the lines holding a quote go to the careful parser's per-row
    logic, the others to pyarrow, as the same file without the quote. (The whole file went to the careful
    parser: on an hour 4-8x the time, 1.7x the peak memory.)"""
    lines = REAL["S07"].read_text().splitlines()
    if damaged:
        lines = damage(lines)
    plain = tmp_path / "plain.csv"
    plain.write_bytes(resave(lines, ways))
    path = tmp_path / "stray.csv"
    path.write_bytes(resave(stray(lines, way), ways))
    fast, want = read_without_careful(path, monkeypatch), careful(path)
    assert not isinstance(fast, str), fast
    assert_same(fast, want, lines_kept=False)
    _, without_quote = read_counting_careful_lines(plain, monkeypatch)
    _, with_quote = read_counting_careful_lines(path, monkeypatch)
    assert with_quote == without_quote + 1


def test_a_stray_quote_in_strict_mode_is_the_careful_parsers_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "stray.csv"
    path.write_text("\n".join(stray(REAL["S07"].read_text().splitlines(), "value")) + "\n")
    fast, want = read_without_careful(path, monkeypatch, True), careful(path, True)
    assert isinstance(want, str) and fast == want


def part_ends(data: bytes, body_start: int) -> list[int]:
    """The file's offsets where the fast path's parts of its data lines end (all but the last)."""
    buffer = pa.py_buffer(data)
    parts = list(csv_take._parts(buffer.slice(body_start)))
    return [part.address - buffer.address + part.size for part in parts[:-1]]


EDGES = ("open_close", "quoted_newline", "quoted_newline_all", "open_never_closed")


@pytest.mark.parametrize("edge", EDGES)
def test_quotes_across_a_parts_edge_read_as_the_careful_parser_reads_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, edge: str
) -> None:
    """A quote opened on a part's last line and closed on the next part's first (or never), a quoted line
    end at the edge, in small parts: each part read with quoting on or off as it holds a quote or not."""
    monkeypatch.setattr(csv_take, "PART_BYTES", 50_000)
    lines = REAL["S07"].read_text().splitlines()
    ends = part_ends(("\n".join(lines) + "\n").encode(), len(lines[0]) + 1)
    assert len(ends) > 3
    offsets = np.cumsum([len(line) + 1 for line in lines])
    k = int(np.searchsorted(offsets, ends[1]))  # the second part's last line
    assert offsets[k] == ends[1]
    if edge == "quoted_newline_all":
        lines = [",".join(f'"{c}"' for c in line.split(",")) for line in lines]
    cells, after = lines[k].split(","), lines[k + 1].split(",")
    if edge == "quoted_newline_all":
        cells[-1] = cells[-1][:-1] + "\n" + after[-1][1:]  # the last cell's quote closes on the next line
        del lines[k + 1]
    else:
        cells[-1] = '"' + cells[-1]
        if edge == "open_close":
            after[0] += '"'
        elif edge == "quoted_newline":
            cells[-1] += "\n" + after[-1] + '"'
    lines[k], lines[k + 1] = ",".join(cells), ",".join(after)
    path = tmp_path / f"{edge}.csv"
    path.write_text("\n".join(lines) + "\n")
    for strict in (False, True):
        want = careful(path, strict)
        assert strict or not isinstance(want, str), want
        try:
            fast = csv_take.read_csv_rows(path, strict)
        except InputError as exc:
            fast = str(exc)
        if isinstance(want, str):
            assert fast == want
        else:
            assert not isinstance(fast, str), fast
            assert_same(fast, want, lines_kept=False)


@pytest.mark.parametrize("order", ["shorter_later", "longer_later"])
def test_values_are_one_c_contiguous_float32_array_owning_its_memory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, order: str
) -> None:
    """Rows with fewer digits after the first part (the array grown) or before it (allocated beyond the rows,
    then trimmed): the values are the careful parser's, in an array of their size, no view of a larger
    one."""
    monkeypatch.setattr(csv_take, "PART_BYTES", 60_000)
    lines = REAL["S07"].read_text().splitlines()

    def short(line: str) -> str:
        cells = line.split(",")
        return ",".join(cells[:2] + [f"{float(c):.2g}" for c in cells[2:]])

    third = len(lines) // 3
    if order == "shorter_later":
        lines = lines[:third] + [short(line) for line in lines[third:]]
    else:
        lines = [lines[0]] + [short(line) for line in lines[1:third]] + lines[third:]
    path = tmp_path / "rows.csv"
    path.write_text("\n".join(lines) + "\n")
    fast = read_without_careful(path, monkeypatch)
    assert not isinstance(fast, str), fast
    assert_same(fast, csv_take._read_careful(path, False), lines_kept=False)
    values = fast.values
    assert values.dtype == np.float32 and values.shape == (len(lines) - 1, 61)
    assert (
        values.flags.c_contiguous and values.flags.writeable and values.flags.owndata and values.base is None
    )


def test_values_own_their_memory_under_a_debugger(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A tracer reading the frames' locals (as a debugger's variable view does) keeps a view of the values'
    array alive, so that it cannot be trimmed in place: it is copied, not returned as a view of the larger
    array."""
    monkeypatch.setattr(csv_take, "PART_BYTES", 60_000)
    path = REAL["S07"]

    def tracer(frame: Any, event: str, arg: Any) -> Any:
        frame.f_locals  # noqa: B018
        return tracer

    previous = sys.gettrace()
    sys.settrace(tracer)
    try:
        fast = csv_take.read_csv_rows(path)
    finally:
        sys.settrace(previous)
    assert fast.lines is None  # the fast path, pyarrow's rows only
    assert fast.values.base is None and fast.values.flags.owndata and fast.values.flags.c_contiguous
    assert_same(fast, csv_take._read_careful(path, False), lines_kept=False)
