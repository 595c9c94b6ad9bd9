"""Second review of the s22 reader changes (drop-frame timecodes, channels empty on every row), on inputs
built from the documented formats (formats doc §2, §3): what the first round's rules did to a take folder's
clock, to the warning quoting a damaged cell, and to a take of one row."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import run_python
from test_readers_review_s22 import drop_frame_label, rows, write_csv

from capture import Audio, InputError, read_livelink_csv, read_take_folder, write_reference_mov
from capture.channels import CSV_ORDER
from capture.take import FrameStatus
from capture.timecode import Timecode

EMPTY_ANGLES = 9  # the head and eye angles: the last 9 of the 61 columns


def without_angles(row: str) -> str:
    """A row as a writer of the 52 shapes alone leaves it: the angle cells empty."""
    return row.rsplit(",", EMPTY_ANGLES)[0] + "," * EMPTY_ANGLES


# 1. Drop-frame rows were read as frames from midnight at 29.97 fps: their first row's time moved off its
# label (105 ms at 14:58), where frame_log.csv's rows, read as written, still put it: in a take folder whose
# frame_log.csv carries the same drop-frame labels (formats doc §3), the audio was placed 105 ms late.
def test_drop_frame_rows_keep_the_first_rows_label_as_frame_log_does(tmp_path):
    folder = tmp_path / "20250101_DF_1"
    folder.mkdir()
    first = 1_615_445  # 14:58:02;03, drop-frame
    labels = [drop_frame_label(first + i) for i in range(300)]
    write_csv(folder / "DF_1_iPhone.csv", rows(300, times=labels))
    (folder / "frame_log.csv").write_text(f"V,0,0,30,{labels[0]},0\nA,0,0,48000,{labels[0]},0\n")
    (folder / "take.json").write_text(json.dumps({"slate": "DF", "take": 1}))
    write_reference_mov(folder / "DF_1_iPhone.mov", 30, 10, Audio(np.zeros((48000, 1), np.int16), 48000))
    take = read_take_folder(folder)
    assert take.meta.audio.start_source == "frame_log_audio"
    assert take.meta.audio.start_s == pytest.approx(0.0, abs=1e-6)
    assert take.meta.csv["start_seconds_of_day"] == pytest.approx(
        Timecode.parse(labels[0], 30).seconds_of_day
    )
    assert np.allclose(np.diff(take.time), 1001 / 30000, atol=1e-9)


# 2. With channels empty on every row left out, the warning that most frames lost their values quoted the
# damaged cell as '?' (its text was not kept): a text the file does not hold.
def test_the_widespread_damage_warning_quotes_the_cell_itself(tmp_path):
    lines = [without_angles(row) for row in rows(100)]
    for i in range(1, 100, 4):
        lines[i] = lines[i].replace("0.1000000000", "abc", 1)
    for i in [*range(2, 100, 4), *range(3, 100, 4)]:
        lines[i] = lines[i].replace("0.1000000000", "", 1)
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", lines))
    assert len(take.meta.channels) == len(CSV_ORDER) - EMPTY_ANGLES
    (note,) = [r["message"] for r in take.meta.repairs if r["kind"] == "bad_values_widespread"]
    assert note.startswith("75 of 100 frames") and "('abc' in EyeBlinkLeft on line 3)" in note


# 3. A take of one row (or one row with values among face-lost ones) whose angle cells are empty: one cell is
# as likely that row's damage as a channel no writer fills; the channels were left out and the frame counted
# valid. It stays as before the rule: 61 channels, the frame BAD_VALUE.
@pytest.mark.parametrize("face_lost", [0, 5])
def test_one_row_with_values_keeps_its_empty_channels_as_damage(tmp_path, face_lost):
    cells = rows(face_lost + 1)
    lines = [f"{row.split(',')[0]},0" for row in cells[:face_lost]] + [without_angles(cells[-1])]
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", lines))
    assert len(take.meta.channels) == len(CSV_ORDER)
    assert take.frame_status[-1] == FrameStatus.BAD_VALUE
    assert [r["kind"] for r in take.meta.repairs] == ["bad_value"]


def test_two_rows_with_values_leave_an_empty_channel_out(tmp_path):
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", [without_angles(row) for row in rows(2)]))
    assert len(take.meta.channels) == len(CSV_ORDER) - EMPTY_ANGLES and take.valid.all()


# 4. --strict lets notes pass, empty_channel among them (module doc, take-format.md), but the empty cells
# were each a bad_value repair by then: a take of the 52 shapes alone was refused in strict mode.
def test_strict_mode_reads_channels_no_row_fills_and_refuses_a_damaged_cell(tmp_path):
    lines = [without_angles(row) for row in rows(50)]
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", lines), strict=True)
    assert len(take.meta.channels) == len(CSV_ORDER) - EMPTY_ANGLES and take.valid.all()
    assert [r["kind"] for r in take.meta.repairs] == ["empty_channel"]
    lines[7] = lines[7].replace("0.1000000000", "abc", 1)
    with pytest.raises(InputError, match=r"non-numeric.*'abc'.*\(strict mode\)"):
        read_livelink_csv(write_csv(tmp_path / "take.csv", lines), strict=True)


# 5. A short take's text followed by NUL bytes to the end (a power loss, _zero_tail): the whole file was then
# parsed, the run as one line: a 32 MB run took 7 s and 877 MB (the rows before it: 46 MB, 0.8 s).
def test_a_long_nul_run_after_a_short_take_is_not_read_as_text(tmp_path):
    path = write_csv(tmp_path / "MySlate_3_iPhone.csv", rows(20))
    run = 16 << 20
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size + run)  # NUL bytes to the end (sparse: nothing written)
    script = (
        "import json, resource, sys\n"
        "from capture import read_livelink_csv\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "take = read_livelink_csv(sys.argv[1])\n"
        "grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before\n"
        "print(json.dumps([take.time.size, [r['kind'] for r in take.meta.repairs], grown]))\n"
    )
    proc = run_python(script, str(path))
    assert proc.returncode == 0, proc.stderr
    frames, kinds, grown_kib = json.loads(proc.stdout)
    assert frames == 20 and kinds == ["truncated_row"]
    assert grown_kib < (run >> 10) // 2  # well under the run's size: the run was not read as text
