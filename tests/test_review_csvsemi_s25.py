"""Review of reading a Live Link Face CSV re-saved with ``;`` between the fields: the spellings a
spreadsheet writes that ``test_csvsemi_s25`` leaves out (scientific notation and negative numbers with a
decimal comma, a row in quotes, a face-lost row of empty cells, a count written ``61,0``, a number with
digit groups, a lone cell with the other decimal mark on a later row), each row read as the app's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_csvsemi_s25 import SEPARATOR_NOTE, app_csv, resaved, same_take

from capture import FrameStatus, InputError, read_livelink_csv


def resaved_rows(samples: Path, tmp_path: Path, decimal: str = ",") -> list[list[str]]:
    """The real take re-saved with ``;`` and ``decimal``, as lists of cells (the header first)."""
    path = resaved(app_csv(samples), tmp_path / "resaved.csv", decimal=decimal, line_end="\n")
    return [line.split(";") for line in path.read_text().splitlines()]


def write(path: Path, rows: list[list[str]]) -> Path:
    path.write_bytes("".join(";".join(cells) + "\r\n" for cells in rows).encode())
    return path


def test_every_spelling_of_a_decimal_comma_row_reads_as_the_apps_row(tmp_path, samples):
    """Rows a spreadsheet writes otherwise than plain ``0,5`` among the plain ones: each read as the app's."""
    clean = read_livelink_csv(app_csv(samples))
    rows = resaved_rows(samples, tmp_path)
    tracked = [i for i, cells in enumerate(rows) if i and cells[1] == "61"]
    lost = [i for i, cells in enumerate(rows) if i and cells[1] == "0"]
    assert any(c.startswith("-") for i in tracked for c in rows[i])  # negative numbers: '-0,25'
    scientific, quoted, count = tracked[5], tracked[6], tracked[7]
    rows[scientific][2:] = [
        f"{float(c.replace(',', '.')):.17E}".replace(".", ",") for c in rows[scientific][2:]
    ]
    rows[quoted] = [f'"{c}"' for c in rows[quoted]]
    rows[quoted][0] = rows[quoted][0].replace(".", ",")  # the timecode's sub-frame after a comma too
    rows[count][1] = "61,0"
    rows[lost[0]] += [""] * 61  # a face-lost row as a spreadsheet fills it: empty cells
    take = read_livelink_csv(write(tmp_path / "t.csv", rows))
    same_take(take, clean)
    assert [r for r in take.meta.repairs if r not in clean.meta.repairs] == [SEPARATOR_NOTE]


def test_a_number_with_digit_groups_is_a_bad_value_named_as_written(tmp_path, samples):
    rows = resaved_rows(samples, tmp_path)
    row = next(i for i, cells in enumerate(rows) if i > 10 and cells[1] == "61")
    rows[row][5] = "1.234,5"  # a weight is never above 1: no number the app wrote
    take = read_livelink_csv(write(tmp_path / "t.csv", rows))
    notes = [r for r in take.meta.repairs if r["kind"] == "bad_value"]
    assert [r["line"] for r in notes] == [row + 1] and "'1.234,5'" in notes[0]["message"]
    assert np.count_nonzero(take.frame_status == FrameStatus.BAD_VALUE) == 1


@pytest.mark.parametrize("decimal, other", [(",", "0.5"), (".", "0,5")])
def test_one_cell_with_the_other_decimal_mark_on_a_later_row_is_refused(tmp_path, samples, decimal, other):
    rows = resaved_rows(samples, tmp_path, decimal)
    row = next(i for i, cells in enumerate(rows) if i > 1000 and cells[1] == "61")
    rows[row][30] = other
    with pytest.raises(
        InputError, match=r"both ',' \('0,.*' on line \d+\) and '\.' \('0\..*' on line"
    ) as err:
        read_livelink_csv(write(tmp_path / "t.csv", rows))
    assert f"{other!r} on line {row + 1})" in str(err.value)
    assert err.value.line == row + 1 and "\n" not in str(err.value)


def test_spaces_and_minus_signs_leave_a_numbers_decimal_comma_seen(tmp_path, samples):
    """Numbers in no-break spaces (``\u00a00,5``), negative ones with U+2212: their decimal comma is the
    file's, said once in the ``separator`` note (not ``'.'``, nor again in a ``number_format`` note)."""
    clean = read_livelink_csv(app_csv(samples))
    rows = resaved_rows(samples, tmp_path)
    rows[1:] = [cells[:2] + ["\u00a0" + c.replace("-", "\u2212") for c in cells[2:]] for cells in rows[1:]]
    take = read_livelink_csv(write(tmp_path / "t.csv", rows))
    same_take(take, clean)
    new = [r for r in take.meta.repairs if r not in clean.meta.repairs]
    assert new[0] == SEPARATOR_NOTE
    assert [r["message"].split(" (")[0] for r in new[1:]] == [
        "6442 values written with a U+2212 minus sign",
        "101382 values written with non-breaking or narrow spaces around them",
    ]
