"""A long Live Link Face CSV with a few damaged rows is read by pyarrow for its good rows and by the careful
parser's per-row logic for the damaged ones only: the careful parser's result (times, values, statuses,
repairs and their lines), at the cost of an intact file rather than of reading every row in Python."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLES

from capture import csv_take
from capture.csv_take import CsvRows, _read_careful, read_csv_rows
from capture.errors import InputError
from capture.take import FrameStatus
from capture.timecode import Timecode

SAMPLE = SAMPLES / "livelinkface/alexdjulin_S07/S07-001.csv"
ROWS = 20_000
pytestmark = pytest.mark.skipif(not SAMPLE.is_file(), reason="the real Live Link Face sample is not here")


def long_take(path: Path, rows: int = ROWS) -> list[str]:
    """The real sample's rows repeated to ``rows`` rows, with timecodes continuing at its 30 rows/s (FF
    steps of 2): the lines of the file written to ``path``, header first."""
    lines = SAMPLE.read_text().splitlines()
    header, body = lines[0], [line.split(",", 1)[1] for line in lines[1:]]
    t0 = Timecode.parse(lines[1].split(",", 1)[0]).seconds_of_day
    out = [header]
    for i in range(rows):
        out.append(Timecode.from_seconds(t0 + i * 2 / 60).format() + "," + body[i % len(body)])
    write(path, out)
    return out


def write(path: Path, lines: list[str], end: str = "\n") -> Path:
    path.write_text("\n".join(lines) + end)
    return path


def assert_same(fast: CsvRows, careful: CsvRows, lines_kept: bool = True) -> None:
    """The fast (or mended) path's rows are the careful parser's; ``lines_kept=False``: unless the fast
    path kept no line numbers (the app's clean file, read by pyarrow whole)."""
    assert fast.columns == careful.columns and fast.count_name == careful.count_name
    np.testing.assert_array_equal(fast.seconds_of_day, careful.seconds_of_day)  # to the bit
    np.testing.assert_array_equal(fast.values, careful.values)  # NaN where NaN
    np.testing.assert_array_equal(fast.status, careful.status)
    if lines_kept or fast.lines is not None:
        np.testing.assert_array_equal(fast.lines, careful.lines)
    assert fast.line_ending == careful.line_ending
    assert fast.repairs == careful.repairs


def read_counting_careful_lines(path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[CsvRows, int]:
    """``read_csv_rows(path)`` and how many lines went through the careful parser's per-row logic."""
    calls = []
    read = csv_take._RowReader.read

    def counting(self: csv_take._RowReader, number: int, line: str) -> None:
        calls.append(number)
        read(self, number, line)

    monkeypatch.setattr(csv_take._RowReader, "read", counting)
    rows = read_csv_rows(path)
    monkeypatch.undo()
    return rows, len(calls)


def cut_last_line(lines: list[str]) -> tuple[list[str], str]:
    return lines[:-1] + [lines[-1][:300]], ""


def bad_timecode(lines: list[str]) -> tuple[list[str], str]:
    lines[9_000] = "12:3x:" + lines[9_000][6:]
    return lines, "\n"


def text_cell(lines: list[str]) -> tuple[list[str], str]:
    cells = lines[12_345].split(",")
    cells[20] = "abc"  # pyarrow cannot convert the column: read again without this line
    lines[12_345] = ",".join(cells)
    return lines, "\n"


def nan_and_empty_cells(lines: list[str]) -> tuple[list[str], str]:
    for at, cell in ((5_000, "nan"), (15_000, "")):
        cells = lines[at].split(",")
        cells[40] = cell
        lines[at] = ",".join(cells)
    return lines, "\n"


def face_lost_and_more(lines: list[str]) -> tuple[list[str], str]:
    """A face-lost row, a row of too few fields, a duplicated row, an empty line, a count of 60."""
    lines[10_000] = lines[10_000].split(",")[0] + ",0"
    lines[10_500] = lines[10_500][:200]
    lines[11_000] = lines[10_999]
    lines[11_500] = ""
    lines[12_000] = lines[12_000].replace(",61,", ",60,", 1)
    return lines, "\n"


@pytest.mark.parametrize(
    "damage", [cut_last_line, bad_timecode, text_cell, nan_and_empty_cells, face_lost_and_more]
)
def test_a_long_file_with_a_damaged_row_reads_as_the_careful_parser_reads_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage
) -> None:
    lines, end = damage(long_take(tmp_path / "intact.csv"))
    path = write(tmp_path / "S07-001.csv", lines, end)
    rows, careful_lines = read_counting_careful_lines(path, monkeypatch)
    assert_same(rows, _read_careful(path, False))
    assert rows.repairs  # the damage was met, and said
    # pyarrow read the good rows: only the damaged lines (the duplicate's, a few) went through Python
    assert 1 <= careful_lines <= 5


def test_the_damaged_rows_are_where_the_careful_parser_puts_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    lines, _ = face_lost_and_more(long_take(tmp_path / "intact.csv"))
    rows, _ = read_counting_careful_lines(write(tmp_path / "S07-001.csv", lines), monkeypatch)
    kinds = {(r["line"], r["kind"]) for r in rows.repairs}
    # list index i is line i + 1
    assert kinds == {(10_501, "wrong_fields"), (11_001, "duplicate_row"), (12_001, "bad_count")}
    at = int(np.flatnonzero(rows.lines == 10_001)[0])
    assert rows.status[at] == FrameStatus.FACE_LOST and np.isnan(rows.values[at]).all()
    assert rows.seconds_of_day.size == ROWS - 3  # the row of too few fields, the duplicate, the empty line


def test_a_cut_short_last_line_costs_what_the_intact_file_does(tmp_path: Path) -> None:
    """Memory as Python sees it (numpy's arrays, Python's objects; pyarrow's own is not traced): the careful
    parser's lists of floats held about 20 times an intact file's."""
    intact = long_take(tmp_path / "intact.csv")
    lines, end = cut_last_line(list(intact))
    damaged = write(tmp_path / "cut.csv", lines, end)

    def peak(path: Path) -> int:
        tracemalloc.start()
        try:
            read_csv_rows(path)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    assert peak(damaged) < 3 * peak(tmp_path / "intact.csv")


def whole_second_take(tmp_path: Path) -> Path:
    """A take whose row on line 101 is its second's last (FF 59.169, the next row's 01.169), moved to FF
    60.000: the next second's frame 0, as a writer rounding up would write it."""
    lines = long_take(tmp_path / "intact.csv", rows=300)
    at = next(i for i in range(100, 300) if lines[i].startswith("59.169", 9))
    lines = [lines[0]] + lines[at - 99 :]  # that row on line 101
    lines[100] = lines[100][:9] + "60.000" + lines[100][15:]
    return write(tmp_path / "S07-001.csv", lines)


def test_ff_60_000_is_the_next_second_in_both_paths_with_a_note(tmp_path: Path) -> None:
    """The app's FF runs 0..59.999: 60.000 comes from a writer rounding 59.9996 up. Both parsers read it as
    the next second's frame 0 and say so once; neither drops the row."""
    path = whole_second_take(tmp_path)
    rows, careful = read_csv_rows(path), _read_careful(path, False)
    assert_same(rows, careful)
    at = int(np.flatnonzero(rows.lines == 101)[0])
    second = Timecode.parse(path.read_text().splitlines()[100][:8] + ":00.000").seconds_of_day
    assert rows.seconds_of_day[at] == second + 1
    assert rows.status[at] == FrameStatus.TRACKED
    assert rows.seconds_of_day.size == path.read_text().count("\n") - 1  # no row dropped
    (note,) = rows.repairs
    assert note["kind"] == "timecode_format" and note["line"] == 101 and "60.000" in note["message"]
    with pytest.raises(InputError, match="strict mode"):
        read_csv_rows(path, strict=True)


def test_timecode_parse_reads_ff_equal_to_the_rate_and_refuses_beyond() -> None:
    tc = Timecode.parse("10:00:00:60.000")
    assert tc.is_whole_second and tc.seconds_of_day == 36001.0
    assert not Timecode.parse("10:00:00:59.999").is_whole_second
    with pytest.raises(ValueError):
        Timecode.parse("10:00:00:60.0001")
    assert Timecode.parse("10:00:00:30.000", rate=30).is_whole_second


# Files on which the fast and mended paths gave other results than the careful parser (differential
# fuzzing): a row out of order in a file with face-lost rows was put in order silently; counts pyarrow's
# integers take and the careful parser does not; a count of 0 over a value that rounds to 0 in float32;
# a value just beyond float32 rounding to its largest; a replacement character in the header.
HEADER = "Timecode,BlendShapeCount,EyeBlinkLeft\n"
DIFFERENTIAL = {
    "tracked_back_among_face_lost": "00:00:01:02.000,1,0.5\n00:00:01:01.000,1,0.5\n00:00:01:03.000,0\n",
    "face_lost_back": "00:00:01:02.000,1,0.5\n00:00:01:03.000,0\n00:00:01:01.000,0\n",
    "count_hex": "00:00:01:02.000,0x1,0.5\n",
    "count_minus_0": "00:00:01:02.000,-0,0\n",
    "count_0_tiny_value": "00:00:01:02.000,0,1e-46\n",
    "just_over_float32": "00:00:01:02.000,1,3.4028235e38\n00:00:01:03.000,1,-3.4028235e38\n",
    "float32_max": "00:00:01:02.000,1,3.4028234663852886e38\n",
}


def _either(read, path, strict):
    try:
        return read(path, strict)
    except InputError as exc:
        return str(exc)


@pytest.mark.parametrize("strict", [False, True])
@pytest.mark.parametrize("case", sorted(DIFFERENTIAL))
def test_the_fast_path_reads_as_the_careful_parser(tmp_path, case, strict):
    path = tmp_path / f"{case}.csv"
    path.write_text(HEADER + DIFFERENTIAL[case] * (1 if "face_lost" in case or "back" in case else 3))
    fast, careful = _either(read_csv_rows, path, strict), _either(_read_careful, path, strict)
    if isinstance(careful, str) or isinstance(fast, str):
        assert fast == careful
    else:
        assert np.array_equal(fast.seconds_of_day, careful.seconds_of_day)
        assert np.array_equal(fast.values, careful.values, equal_nan=True)
        assert np.array_equal(fast.status, careful.status) and fast.repairs == careful.repairs


def test_a_replacement_character_in_the_header_is_binary_data_on_both_paths(tmp_path):
    path = tmp_path / "fffd.csv"
    path.write_bytes("Timecode,BlendShapeCount,EyeBlink\ufffdLeft\n00:00:01:02.000,1,0.5\n".encode())
    with pytest.raises(InputError, match="binary data"):
        read_csv_rows(path)
    with pytest.raises(InputError, match="binary data"):
        _read_careful(path, False)
