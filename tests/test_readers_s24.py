"""Leftovers of the s23 readers: a cell made of a number's bytes that is no number (``-``, ``0.1.2``) or a
channel empty on every row kept a long CSV from pyarrow's read (every line read by the careful parser's
per-row logic, ~10x the time); face-lost rows written at half the tracked rows' cadence, most of a take,
gave it their rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_csv_long_damaged import ROWS, SAMPLE, assert_same, long_take, read_counting_careful_lines, write
from test_readers_review_s22 import rows, rows_at, write_csv

from capture import read_livelink_csv
from capture.csv_take import _read_careful, read_csv_rows
from capture.take import FrameStatus
from capture.take_folder import read_frame_log
from capture.timecode import Timecode

needs_sample = pytest.mark.skipif(not SAMPLE.is_file(), reason="the real Live Link Face sample is not here")


def with_cells(lines: list[str], cells: dict[tuple[int, int], str]) -> list[str]:
    """``lines`` with the value cells at (line index, value column) replaced."""
    for (at, column), text in cells.items():
        fields = lines[at].split(",")
        fields[2 + column] = text
        lines[at] = ",".join(fields)
    return lines


# 1. pyarrow names the first cell it cannot convert; the lines holding it are left out of its read, as
# lines holding a letter are, and read by the careful parser's per-row logic alone.
NUMBER_LIKE = {
    "dash": {(5_000, 10): "-"},
    "two_points": {(7_000, 3): "0.1.2"},
    "exponent_cut": {(9_000, 60): "1e"},
    "several": {
        (1_000, 0): "--",
        (1_001, 0): "--",
        (12_000, 30): "1e",
        (15_000, 40): "0.1.2",
        (18_000, 2): "-",
    },
    "with_a_letter": {(3_000, 5): "abc", (4_000, 6): "-"},
}


@needs_sample
@pytest.mark.parametrize("cells", NUMBER_LIKE.values(), ids=NUMBER_LIKE)
def test_a_number_like_cell_keeps_pyarrows_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, cells
) -> None:
    lines = with_cells(long_take(tmp_path / "intact.csv"), cells)
    path = write(tmp_path / "S07-001.csv", lines)
    fast, careful_lines = read_counting_careful_lines(path, monkeypatch)
    assert_same(fast, _read_careful(path, False))
    assert careful_lines == len(cells)  # was every line (the careful parser read the file whole)
    kinds = [r["kind"] for r in fast.repairs]
    assert kinds == ["bad_value"] * len({at for at, _ in cells})
    for at, _ in cells:
        assert fast.status[at - 1] == FrameStatus.BAD_VALUE  # line index at is row at - 1


# 2. A channel no row fills (a writer leaving the head angles out): pyarrow's rows hold no value there, which
# made every row one for the careful parser; its checks leave the channel out as before.
@needs_sample
@pytest.mark.parametrize("damage", ["none", "damaged_row", "a_cell_in_it"])
def test_a_channel_empty_on_every_row_keeps_pyarrows_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage: str
) -> None:
    lines = long_take(tmp_path / "intact.csv")
    with_cells(lines, {(at, 52): "" for at in range(1, len(lines))})  # HeadYaw
    if damage == "damaged_row":
        with_cells(lines, {(6_000, 17): "abc"})  # JawOpen
    elif damage == "a_cell_in_it":  # on a line the careful parser reads: the channel is not empty
        with_cells(lines, {(6_000, 17): "abc", (6_000, 52): "0.5"})
    path = write(tmp_path / "S07-001.csv", lines)
    fast, careful_lines = read_counting_careful_lines(path, monkeypatch)
    assert_same(fast, _read_careful(path, False))
    if damage == "a_cell_in_it":
        assert "HeadYaw" in fast.columns  # every other row is damaged there: read as the careful parser does
        return
    assert careful_lines <= 1  # was every line
    assert "HeadYaw" not in fast.columns and len(fast.columns) == 60
    assert [r["kind"] for r in fast.repairs][-1:] == ["empty_channel"]
    assert int((fast.status == FrameStatus.TRACKED).sum()) == ROWS - (damage == "damaged_row")


# A channel empty in a short take, where pyarrow reads the whole file in one part, or in a take of two rows.
@pytest.mark.parametrize("n", [2, 3, 300])
def test_an_empty_channel_in_a_short_take_reads_as_the_careful_parser_does(tmp_path: Path, n: int) -> None:
    lines = with_cells(rows(n), {(at, 55): "" for at in range(n)})
    path = write_csv(tmp_path / "take.csv", lines)
    take = read_livelink_csv(path)
    assert "LeftEyeYaw" not in take.meta.channels and take.valid.all()
    assert_same(read_csv_rows(path), _read_careful(path, False))


# 3. A 60 fps take whose face is lost for most of it, its face-lost rows written 30 a second (not the
# formats doc's: the app writes them at the tracked rows' cadence), was read as 30 fps: its tracked rows,
# 1/60 s apart, then shared frames. Its rate is the tracked rows' now; the face-lost rows are DROPPED frames
# apart.
def test_face_lost_rows_at_half_the_cadence_do_not_set_the_rate(tmp_path: Path) -> None:
    t0 = 14 * 3600 + 58 * 60
    tracked = [t0 + i / 60 for i in range(120)]  # 2 s tracked
    lost = [tracked[-1] + (i + 1) / 30 for i in range(240)]  # 8 s lost, 30 rows/s
    after = [lost[-1] + (i + 1) / 60 for i in range(60)]  # 1 s tracked
    lines = rows_at(tracked) + rows_at(lost, tracked=False) + rows_at(after)
    take = read_livelink_csv(write_csv(tmp_path / "MySlate_7_iPhone.csv", lines))
    assert take.meta.fps == 60.0  # was 30
    assert np.allclose(np.diff(take.time), 1 / 60, atol=2e-3)  # one frame per 1/60 s, none shared
    assert int(take.valid.sum()) == 180
    assert int((take.frame_status == FrameStatus.FACE_LOST).sum()) == 240
    assert take.meta.extra["dropped_frames_inserted"] == 240
    assert [r["kind"] for r in take.meta.repairs] == ["row_rate_change"]


# The documented face-lost rows (S88: 277 of 1,939 rows, at the tracked rows' 30 a second) keep its rate.
def test_the_real_face_lost_sample_keeps_its_rate() -> None:
    sample = SAMPLE.parent.parent / "alexdjulin_S88/S88-001.csv"
    if not sample.is_file():
        pytest.skip("the real S88 sample is not here")
    take = read_livelink_csv(sample)
    assert take.meta.fps == 30.0 and round(take.meta.csv["measured_fps"]) == 30
    assert int((take.frame_status == FrameStatus.FACE_LOST).sum()) == 277


# frame_log.csv's media times (num/den, formats doc §3) of a phone whose frames come at 29.97 (59.94) a second
# under labels counted at 30 (60), never drop-frame (formats doc §0.11 [TDC]: Epic's ingest reads them at
# 30/1 or 60/1 and uses num/den only to pair video with depth frames): the labels' rate is the video's, no
# note. (No change: a pin of what the media times may tell.)
@pytest.mark.parametrize("rate", [30, 60])
def test_ntsc_media_times_leave_the_logs_timecode_rate_alone(tmp_path: Path, rate: int) -> None:
    t0 = 14 * 3600 + 58 * 60
    rows_ = [
        f"V,{i},{i * 1001},{rate * 1000},{Timecode.from_seconds(t0 + i / rate, rate).format(0)},0"
        for i in range(10 * rate)
    ]
    (tmp_path / "frame_log.csv").write_text("\n".join(rows_) + "\n")
    repairs: list = []
    log = read_frame_log(tmp_path / "frame_log.csv", repairs)
    assert not repairs and np.allclose(np.diff(log.times_s), 1001 / (rate * 1000))
    assert log.timecode_rate(float(rate)) == rate
