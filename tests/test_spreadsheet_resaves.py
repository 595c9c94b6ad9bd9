"""Live Link Face CSVs re-saved by spreadsheets and scripts (pandas, Excel, LibreOffice, Numbers): each is
read as the app's file with one note saying what was read otherwise, or refused with one line saying what
to do; never a take of NaN, nor silently lost rows or channels. Built from the real samples."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from capture import FrameStatus, InputError, read_livelink_csv, read_take
from tests.conftest import run_here

S07 = "livelinkface/alexdjulin_S07/S07-001.csv"
S88 = "livelinkface/alexdjulin_S88/S88-001.csv"
NS = "paired/neurosync-trainer-lite-testset"


def sample(samples: Path, name: str = S07) -> tuple[list[str], list[list[str]]]:
    """Header and rows of a real sample, as lists of fields."""
    lines = (samples / name).read_text().splitlines()
    return lines[0].split(","), [line.split(",") for line in lines[1:] if line]


def write(
    path: Path, header: list[str], rows: list[list[str]], encoding: str = "utf-8", sep: str = ","
) -> Path:
    path.write_text("".join(sep.join(r) + "\n" for r in [header, *rows]), encoding=encoding)
    return path


def kinds(take) -> list[str]:
    return [r["kind"] for r in take.meta.repairs]


def same_take(got, want) -> None:
    """The same frames, times, statuses and values (NaN where the other has NaN)."""
    assert got.meta.channels == want.meta.channels
    assert np.array_equal(got.frame_status, want.frame_status)
    assert np.allclose(got.time, want.time) and got.meta.start_timecode == want.meta.start_timecode
    assert np.allclose(got.values, want.values, equal_nan=True, atol=1e-9)


def cli_import(tmp_path: Path, *args) -> tuple[int, str, list[dict]]:
    proc = run_here("capture", "import", *args, "-o", tmp_path / "takes")
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, proc.stderr, proc.stdout


# 1. A user's column that is no channel never invalidates a frame.
def test_a_notes_column_is_left_out_and_every_frame_stays_valid(samples, tmp_path):
    header, rows = sample(samples)
    noted = [r + [""] for r in rows]
    noted[100][-1] = "blink here"
    take = read_livelink_csv(write(tmp_path / "t.csv", header + ["Notes"], noted))
    same_take(take, read_livelink_csv(samples / S07))
    assert kinds(take) == ["text_column"]
    assert "'Notes' holds no numbers ('blink here' on line 102): left out" in take.meta.repairs[0]["message"]
    # a column of numbers with some text keeps its numbers, NaN at the text; the channels stay valid
    extra = [r + [f"{i}"] for i, r in enumerate(rows)]
    extra[5][-1] = "n/a"
    take = read_livelink_csv(write(tmp_path / "u.csv", header + ["Marker"], extra), strict=True)
    assert take.count(FrameStatus.BAD_VALUE) == 0 and kinds(take) == ["text_column", "unknown_columns"]
    marker = take.channel("Marker")
    assert np.isnan(marker[5]) and marker[6] == 6


# 2. Number formats of a spreadsheet's locale.
def test_quoted_decimal_commas_are_read_with_one_note(samples, tmp_path):
    header, rows = sample(samples)
    german = [r if len(r) == 2 else r[:2] + [f'"{x.replace(".", ",")}"' for x in r[2:]] for r in rows]
    take = read_livelink_csv(write(tmp_path / "t.csv", header, german))
    same_take(take, read_livelink_csv(samples / S07))
    assert kinds(take) == ["number_format"]
    assert (
        "values written with a decimal comma ('0,0000000000' in EyeBlinkLeft on line 2)"
        in (take.meta.repairs[0]["message"])
    )
    with pytest.raises(InputError, match="decimal comma.*strict"):
        read_livelink_csv(tmp_path / "t.csv", strict=True)


def test_unicode_minus_signs_and_no_break_spaces_are_read(samples, tmp_path):
    header, rows = sample(samples, f"{NS}/testset.csv")
    numbers = [r[:2] + ["\u00a0" + x.replace("-", "\u2212") + "\u202f" for x in r[2:]] for r in rows]
    take = read_livelink_csv(write(tmp_path / "t.csv", header, numbers))
    same_take(take, read_livelink_csv(samples / NS / "testset.csv"))
    assert (take.values < 0).any()
    notes = [r["message"] for r in take.meta.repairs]
    assert kinds(take) == ["number_format", "number_format"]
    assert any("U+2212 minus sign" in m and "read as '-'" in m for m in notes)
    assert any("non-breaking or narrow spaces" in m for m in notes)


def test_a_take_whose_frames_mostly_lose_their_values_is_a_warning(samples, tmp_path):
    header, rows = sample(samples)
    percent = [r[:2] + [f"{float(x) * 100:.2f}%" for x in r[2:]] for r in rows]
    code, err, out = cli_import(tmp_path, write(tmp_path / "t.csv", header, percent))
    assert code == 0
    said = f"{len(rows)} of {len(rows)} frames have non-numeric values ('0.00%' in EyeBlinkLeft on line 2)"
    assert f"warning: {tmp_path / 't.csv'}: {said}" in err
    assert f": 0 valid, {len(rows)} bad-value, " in err  # the progress line says it too
    # a few damaged rows are repairs, not a warning
    rows[7][5] = "abc"
    code, err, _ = cli_import(tmp_path, write(tmp_path / "u.csv", header, rows))
    assert code == 0 and "warning" not in err and f": {len(rows) - 1} valid, 1 bad-value, " in err


# 3. Timecodes a script wrote without zero padding.
def test_timecodes_without_zero_padding_are_read_with_one_note(samples, tmp_path):
    header, rows = sample(samples)
    for r in rows:
        h, m, s, ff = r[0].split(":")
        r[0] = f"{int(h)}:{int(m)}:{int(s)}:{ff}"
    take = read_livelink_csv(write(tmp_path / "t.csv", header, rows))
    same_take(take, read_livelink_csv(samples / S07))
    assert (
        kinds(take) == ["timecode_format"]
        and "written without zero padding" in take.meta.repairs[0]["message"]
    )


def test_many_rows_dropped_for_their_timecodes_is_a_warning(samples, tmp_path):
    header, rows = sample(samples)
    for r in rows[::10]:  # a time of day without frames, as a spreadsheet shows it
        r[0] = r[0].rsplit(":", 1)[0]
    code, err, _ = cli_import(tmp_path, write(tmp_path / "t.csv", header, rows))
    assert code == 0
    assert f"{len(rows[::10])} of {len(rows)} rows dropped for timecodes that do not parse ('12:27:47'" in err


# 4. A typo in a channel's column name.
def test_a_misspelt_channel_column_is_a_warning_naming_both(samples, tmp_path):
    header, rows = sample(samples)
    header[header.index("JawOpen")] = "JawOpne"
    code, err, _ = cli_import(tmp_path, write(tmp_path / "t.csv", header, rows))
    assert code == 0 and "no JawOpen column; JawOpne is not a channel: did you mean JawOpen?" in err
    take = read_take(tmp_path / "takes" / "t")
    assert "jawOpen" not in take.meta.channels and "JawOpne" in take.meta.channels  # not renamed silently


# 5. Face-lost rows as pandas and spreadsheets re-save them.
@pytest.mark.parametrize("count", ["0", "0.0"])
@pytest.mark.parametrize("padded", [False, True])
def test_face_lost_rows_resaved_stay_face_lost(samples, tmp_path, count, padded):
    header, rows = sample(samples, S88)
    resaved = [r if len(r) > 2 else [r[0], count] + [""] * (61 if padded else 0) for r in rows]
    take = read_livelink_csv(write(tmp_path / "t.csv", header, resaved), strict=True)
    same_take(take, read_livelink_csv(samples / S88))
    assert take.count(FrameStatus.FACE_LOST) == 277 and kinds(take) == []


# 6. pandas' index column.
@pytest.mark.parametrize("name", ["", "Unnamed: 0"])
def test_a_pandas_index_column_is_dropped_with_one_note(samples, tmp_path, name):
    header, rows = sample(samples, S88)
    path = write(tmp_path / "t.csv", [name] + header, [[str(i)] + r for i, r in enumerate(rows)])
    take = read_livelink_csv(path)
    same_take(take, read_livelink_csv(samples / S88))
    assert (
        kinds(take) == ["index_column"]
        and "counting the rows from 0: dropped" in take.meta.repairs[0]["message"]
    )


def test_a_pandas_index_column_with_audio_is_read_as_the_apps_csv(samples, tmp_path):
    header, rows = sample(samples, f"{NS}/testset.csv")
    path = write(tmp_path / "t.csv", [""] + header, [[str(i + 1)] + r for i, r in enumerate(rows)])
    proc = run_here(
        "capture", "import", path, "--audio", samples / NS / "audio.wav", "-o", tmp_path / "o", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["source_kind"] == "livelink_csv" and summary["frames"] == len(rows)
    assert "counting the rows from 1" in read_take(summary["path"]).meta.repairs[0]["message"]


# 7. UTF-16 and tabs: one diagnosis, loose or in a take folder, whatever the file's suffix.
def test_utf16_and_tab_separated_files_get_the_same_diagnosis_everywhere(samples, tmp_path):
    header, rows = sample(samples)
    folder = tmp_path / "20240101_S07_1"
    folder.mkdir()
    (folder / "take.json").write_text("{}")
    loose = write(tmp_path / "loose.csv", header, rows, encoding="utf-16")
    inside = write(folder / "S07_1_iPhone.csv", header, rows, encoding="utf-16")
    for source in (loose, folder):
        code, err, _ = cli_import(tmp_path, source)
        assert code == 1 and "a Live Link Face CSV saved as UTF-16 text: save it as UTF-8" in err, err
    unicode_text = write(tmp_path / "sheet.txt", header, rows, encoding="utf-16", sep="\t")
    code, err, _ = cli_import(tmp_path, unicode_text)
    assert code == 1 and 'saved as UTF-16 text with tabs between the fields (Excel\'s "Unicode Text")' in err
    tsv = write(tmp_path / "sheet.tsv", header, rows, sep="\t")  # a UTF-8 TSV is read, its separator said
    same_take(read_livelink_csv(tsv), read_livelink_csv(samples / S07))
    assert "re-saved with tabs between the fields" in read_livelink_csv(tsv).meta.repairs[0]["message"]
    with pytest.raises(InputError, match="saved as UTF-16 text"):
        read_livelink_csv(inside)


# 8. Harmless artefacts of a re-save are no repairs.
def test_a_float_count_and_rows_of_separators_are_no_repairs(samples, tmp_path):
    header, rows = sample(samples)
    floated = [r[:1] + [r[1] + ".0"] + r[2:] for r in rows]
    path = write(tmp_path / "t.csv", header, floated)
    with path.open("a") as f:
        f.write(("," * 62 + "\n") * 3 + "\n,,,\n")
    take = read_livelink_csv(path, strict=True)
    same_take(take, read_livelink_csv(samples / S07))
    assert kinds(take) == []
    # a count that is wrong is still a repair, and says so without contradicting itself
    floated[3][1] = "60.0"
    take = read_livelink_csv(write(tmp_path / "u.csv", header, floated))
    assert (
        kinds(take) == ["bad_count"]
        and "is '60.0' but the row has 61 values" in take.meta.repairs[0]["message"]
    )


# 9. Values no face makes, and rows deleted from the middle.
def test_values_beyond_any_face_are_a_warning(samples, tmp_path):
    header, rows = sample(samples)
    rows[1234][header.index("JawOpen")] = "12"
    code, err, _ = cli_import(tmp_path, write(tmp_path / "t.csv", header, rows))
    assert code == 0 and "1 value beyond ±10 in JawOpen (the first: 12 in JawOpen at " in err
    assert "on line 1236" in err


def test_far_values_are_said_beside_a_channel_that_is_nan_throughout(samples, tmp_path):
    """A channel column of no numbers at all made the check's maximum NaN, and the check said nothing."""
    header, rows = sample(samples)
    for row in rows:
        row[header.index("EyeBlinkLeft")] = "x"
    rows[1234][header.index("JawOpen")] = "12"
    take = read_livelink_csv(write(tmp_path / "t.csv", header, rows))
    assert "value_range" in kinds(take)


def test_rows_deleted_from_the_middle_are_noted_once(samples, tmp_path):
    header, rows = sample(samples)
    take = read_livelink_csv(write(tmp_path / "t.csv", header, rows[:600] + rows[900:]))
    assert kinds(take) == ["gap"]
    message = take.meta.repairs[0]["message"]
    assert message.startswith("a gap of 10.0 s with no rows") and "on line 602" in message
    assert take.count(FrameStatus.DROPPED) >= 299
