"""Leftovers of the s22 reader reviews, on inputs built from the documented formats (formats doc §2):
``;`` timecodes whose labels show a drop-frame count at a minute start, ``bad_value`` notes naming channels
left out, the frame rate of a take whose rows are mostly damaged, and a quoted cell no number parsed twice."""

from __future__ import annotations

import numpy as np
import pyarrow.csv as pacsv
import pytest
from test_csv_long_damaged import assert_same
from test_readers_review_s22 import rows, write_csv

from capture import read_livelink_csv
from capture.channels import CSV_ORDER
from capture.csv_take import _read_careful, read_csv_rows
from capture.take import FrameStatus


def drop_frame_label(n: int, rate: int) -> str:
    """SMPTE drop-frame timecode of frame ``n`` from midnight at 29.97 (``rate`` 30, 2 labels skipped each
    minute but every tenth) or 59.94 (``rate`` 60, 4 skipped)."""
    drop = rate // 15
    per_ten, per_minute = 600 * rate - 9 * drop, 60 * rate - drop
    tens, rest = divmod(n, per_ten)
    n += 9 * drop * tens + (drop * ((rest - drop) // per_minute) if rest >= drop else 0)
    return f"{n // (3600 * rate):02d}:{n // (60 * rate) % 60:02d}:{n // rate % 60:02d};{n % rate:02d}"


def drop_frame_notes(take) -> list[str]:
    return [r["message"] for r in take.meta.repairs if "drop-frame" in r["message"]]


# 1. ';' is SMPTE's mark of a drop-frame count: a take written so is read at 29.97 (59.94) from its first
# label whether or not its labels cross a minute start where the count skips (the s22 test reads a take that
# crosses none); one that crosses it skipping the labels, as a drop-frame count does, is read so too.
@pytest.mark.parametrize("rate", [30, 60])
def test_labels_showing_the_skip_at_a_minute_start_are_drop_frame(tmp_path, rate):
    first = int((14 * 3600 + 58 * 60 + 50) * rate * 1000 / 1001)  # about 14:58:50, 10 s before 14:59
    labels = [drop_frame_label(first + i, rate) for i in range(20 * rate)]
    skip = rate // 15
    assert f"14:59:00;{skip:02d}" in labels and "14:59:00;00" not in labels
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", rows(len(labels), times=labels)))
    assert take.time.size == len(labels) and take.valid.all()
    assert np.allclose(np.diff(take.time), 1001 / (rate * 1000), atol=1e-9)
    assert drop_frame_notes(take)


# 2. With channels empty on every row left out (empty_channel), a row still damaged in a kept channel was
# noted as damaged in the channels left out too, and quoted the empty cell of the first of them.
def test_bad_value_notes_name_only_the_channels_kept(tmp_path):
    def cell(row: int, name: str, text: str) -> None:
        cells = lines[row].split(",")
        cells[2 + CSV_ORDER.index(name)] = text
        lines[row] = ",".join(cells)

    lines = rows(50)
    for row in range(50):
        cell(row, "EyeBlinkLeft", "")  # never written
    cell(7, "JawOpen", "abc")
    cell(20, "JawForward", "")
    cell(20, "JawOpen", "xyz")
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", lines))
    assert "EyeBlinkLeft" not in take.meta.channels and len(take.meta.channels) == len(CSV_ORDER) - 1
    assert list(take.frame_status[[7, 20]]) == [FrameStatus.BAD_VALUE] * 2 and int(take.valid.sum()) == 48
    notes = {r["line"]: r["message"] for r in take.meta.repairs if r["kind"] == "bad_value"}
    done = "set to NaN, frame marked invalid"
    assert notes == {
        9: f"non-numeric, non-finite or out-of-range value in JawOpen ('abc'): {done}",
        22: f"non-numeric, non-finite or out-of-range value in JawForward, JawOpen (''): {done}",
    }


# 3. A 60 fps take with 3 rows in 4 damaged: its rate was measured on the intact rows alone, 15 fps, though
# every row's timecode was read.
def test_a_take_of_mostly_damaged_rows_has_its_rows_rate(tmp_path):
    lines = rows(240)
    for i in range(240):
        if i % 4:
            lines[i] = lines[i].replace("0.1000000000", "abc", 1)
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", lines))
    assert take.meta.fps == 60.0  # was 15.0
    assert take.time.size == 240 and int(take.valid.sum()) == 60
    assert take.meta.extra["dropped_frames_inserted"] == 0
    assert any(r["kind"] == "bad_values_widespread" for r in take.meta.repairs)


# 4. A file holding a quoted cell that is no number to pyarrow (a quoted decimal comma): its lines were read
# by pyarrow whole, then again whole (no line held another byte to leave out), then without the quoted line.
def test_a_quoted_cell_no_number_is_not_parsed_twice(tmp_path, monkeypatch):
    lines = rows(300)
    cells = lines[150].split(",")
    cells[12] = '"0,1421"'
    lines[150] = ",".join(cells)
    path = write_csv(tmp_path / "take.csv", lines)
    parsed = []
    read_csv = pacsv.read_csv

    def counting(source, *args, **kwargs):
        parsed.append((kwargs["parse_options"].quote_char, source.size()))
        return read_csv(source, *args, **kwargs)

    monkeypatch.setattr(pacsv, "read_csv", counting)
    fast = read_csv_rows(path)
    monkeypatch.undo()
    assert len(parsed) == len(set(parsed)) == 2  # was 3: the same bytes with quoting on, twice
    assert_same(fast, _read_careful(path, False))
    assert fast.values[150, 10] == np.float32(0.1421)
    assert [r["kind"] for r in fast.repairs] == ["number_format"]
