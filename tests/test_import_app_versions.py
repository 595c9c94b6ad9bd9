"""Live Link Face takes as other app versions, devices and spreadsheets write them: the same take must
come through the importer with its frames, timing and metadata, and anything unusual said once."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_here

from capture import (
    Audio,
    FrameStatus,
    InputError,
    csv_take,
    read_livelink_csv,
    read_take_folder,
    write_reference_mov,
)
from capture.timecode import Timecode

ZEROS = ",".join(["0.0000000000"] * 61)


def sample_lines(samples: Path, rows: int = 240) -> tuple[str, list[str]]:
    """Header and the first ``rows`` rows (60 rows/s) of the real NeuroSync take."""
    lines = (samples / "paired/neurosync-trainer-lite-testset/testset.csv").read_text().splitlines()
    return lines[0], lines[1 : rows + 1]


def write_csv(path: Path, header: str, rows: list[str], end: str = "") -> Path:
    path.write_text("".join(line + end + "\n" for line in [header, *rows]))
    return path


def quoted(line: str) -> str:
    """A line as a spreadsheet re-saves it with every field quoted."""
    return ",".join(f'"{cell}"' for cell in line.split(","))


def kinds(take) -> list[str]:
    return [r["kind"] for r in take.meta.repairs]


# 1. A take folder without video_metadata.json: frame_log.csv counts at the .mov's rate.
def test_frame_log_without_video_metadata_is_read_at_the_mov_rate(tmp_path, samples):
    header, rows = sample_lines(samples, 60)
    folder = tmp_path / "20250101_MySlate_7"
    folder.mkdir()
    write_csv(folder / "MySlate_7_iPhone.csv", header, rows)
    csv_t0 = Timecode.parse(rows[0].split(",")[0]).seconds_of_day
    at_30 = [Timecode.from_seconds(csv_t0 + dt, rate=30).format() for dt in (0.0, 0.1)]
    (folder / "frame_log.csv").write_text(f"V,0,0,30,{at_30[0]},0\nA,0,0,48000,{at_30[1]},0\n")
    audio = Audio(np.zeros((4800, 1), np.int16), 48000, "PCM_16")
    write_reference_mov(folder / "MySlate_7_iPhone.mov", 30, 3, audio)
    take = read_take_folder(folder)
    assert take.meta.audio.start_source == "frame_log_audio"
    assert take.meta.audio.start_s == pytest.approx(0.100, abs=1e-3)


# 2. A count-0 row with all 61 values zero is the app's face-lost marker, as a short ``<tc>,0`` row is.
def _no_careful_reader(*_args, **_kw):
    raise AssertionError("the careful reader was used")


def test_a_zero_filled_count_0_row_is_face_lost(tmp_path, samples, monkeypatch):
    header, rows = sample_lines(samples, 10)
    rows[3] = rows[3].split(",")[0] + ",0," + ZEROS
    rows[4] = rows[4].split(",")[0] + ",0"
    tracked = rows[6]
    rows[6] = tracked.replace(",61,", ",0,", 1)  # values, so not face lost: a wrong count
    take = read_livelink_csv(write_csv(tmp_path / "t.csv", header, rows))
    assert take.frame_status.tolist() == [0, 0, 0, 1, 1, 0, 0, 0, 0, 0]
    assert np.isnan(take.values[3]).all()
    assert [(r["kind"], r["line"]) for r in take.meta.repairs] == [("bad_count", 8)]
    # without that row, the file takes the fast reader (the careful one refused here): the same frames
    rows[6] = tracked
    monkeypatch.setattr(csv_take, "_read_careful", _no_careful_reader)
    take = read_livelink_csv(write_csv(tmp_path / "u.csv", header, rows), strict=True)
    assert take.frame_status.tolist() == [0, 0, 0, 1, 1, 0, 0, 0, 0, 0] and kinds(take) == []
    assert np.isnan(take.values[3]).all() and not np.isnan(take.values[5]).any()


# 3. A comma ending every line (a spreadsheet's re-save) is no column.
def test_a_comma_ending_every_line_is_no_column(tmp_path, samples):
    header, rows = sample_lines(samples)
    rows[5] = rows[5].split(",")[0] + ",0"  # a face-lost row, comma-ended too
    clean = read_livelink_csv(write_csv(tmp_path / "clean.csv", header, rows))
    take = read_livelink_csv(write_csv(tmp_path / "t.csv", header, rows, end=","), strict=True)
    assert take.meta.channels == clean.meta.channels
    assert np.array_equal(take.values, clean.values, equal_nan=True)
    assert np.array_equal(take.frame_status, clean.frame_status)
    assert kinds(take) == ["trailing_comma"] and "every line ends" in take.meta.repairs[0]["message"]
    # only the header ending with a comma: said as it is
    take = read_livelink_csv(write_csv(tmp_path / "h.csv", header + ",", rows), strict=True)
    assert np.array_equal(take.values, clean.values, equal_nan=True)
    assert [r["message"] for r in take.meta.repairs] == ["the header ends with a comma: no column, ignored"]


def test_an_empty_header_column_says_how_to_fix_it(tmp_path, samples):
    header, rows = sample_lines(samples, 3)
    names = header.split(",")
    names[5] = ""
    with pytest.raises(InputError, match=r"column 6 empty.*name it"):
        read_livelink_csv(write_csv(tmp_path / "t.csv", ",".join(names), rows))
    # the last column empty in the header but holding values in a row is not a trailing comma
    rows[1] += ",0.5"
    with pytest.raises(InputError, match=r"last column.*name it"):
        read_livelink_csv(write_csv(tmp_path / "u.csv", header + ",", [r + "," for r in rows[:1]] + rows[1:]))


# 4. Spreadsheet re-saves: every field quoted is read; ';' between fields is read.
def test_a_csv_with_every_field_quoted_is_read(tmp_path, samples):
    header, rows = sample_lines(samples)
    clean = read_livelink_csv(write_csv(tmp_path / "clean.csv", header, rows))

    for name, quoted_rows in (("head.csv", rows), ("all.csv", [quoted(r) for r in rows])):
        take = read_livelink_csv(write_csv(tmp_path / name, quoted(header), quoted_rows), strict=True)
        assert take.meta.channels == clean.meta.channels and kinds(take) == []
        assert np.array_equal(take.values, clean.values) and np.array_equal(take.time, clean.time)


def test_a_semicolon_separated_resave_is_read(tmp_path, samples):
    header, rows = sample_lines(samples, 3)
    clean = read_livelink_csv(write_csv(tmp_path / "c.csv", header, rows))
    rows = [r.replace(",", ";").replace(".", ",") for r in rows]  # a decimal-comma locale
    take = read_livelink_csv(write_csv(tmp_path / "t.csv", header.replace(",", ";"), rows))
    assert kinds(take) == ["separator"]
    assert np.array_equal(take.values, clean.values) and np.array_equal(take.time, clean.time)


def test_import_recognises_a_spreadsheets_resave_of_a_loose_csv(tmp_path, samples):
    """``s2a-capture import`` decides by a loose CSV's first line whether it is the app's: quoted, it
    is imported as the app's CSV; separated by ';', it is read as the app's CSV too (repair
    ``separator``), not by the generic paired-data reader, which complained about its timecodes."""
    header, rows = sample_lines(samples)

    write_csv(tmp_path / "q.csv", quoted(header), [quoted(r) for r in rows])
    proc = run_here("capture", "import", tmp_path / "q.csv", "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["frames"] == len(rows)
    semi = write_csv(tmp_path / "s.csv", header.replace(",", ";"), [r.replace(",", ";") for r in rows])
    audio = samples / "paired/neurosync-trainer-lite-testset/audio.wav"
    proc = run_here("capture", "import", semi, "--audio", audio, "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["frames"] == len(rows)


# 5. Columns past the 61 channels, named in the header: BlendshapeCount counts the channels.
def test_extra_named_columns_keep_the_blendshape_count(tmp_path, samples):
    header, rows = sample_lines(samples)
    path = write_csv(tmp_path / "t.csv", header + ",HeadX,HeadY,HeadZ", [r + ",0.1,0.2,0.3" for r in rows])
    for strict in (False, True):
        take = read_livelink_csv(path, strict=strict)
        assert kinds(take) == ["unknown_columns"]
        assert take.meta.channels[-3:] == ["HeadX", "HeadY", "HeadZ"]
        assert (take.frame_status == FrameStatus.TRACKED).all()
        assert take.values[0, -1] == pytest.approx(0.3)
    # a count that is neither the channels' nor the values' number is still a wrong count
    rows[2] = rows[2].replace(",61,", ",60,", 1)
    path = write_csv(tmp_path / "u.csv", header + ",HeadX", [r + ",0.1" for r in rows])
    assert kinds(read_livelink_csv(path)) == ["bad_count", "unknown_columns"]


# 6. Rows at 60/s that go on at 30/s: the frames stay as they are, and the change is said once.
def test_a_row_rate_change_mid_take_is_noted(tmp_path, samples):
    header, rows = sample_lines(samples, 1218)
    changed = rows[:600] + rows[600::2]
    take = read_livelink_csv(write_csv(tmp_path / "t.csv", header, changed))
    notes = [r for r in take.meta.repairs if r["kind"] == "row_rate_change"]
    assert len(notes) == 1 and take.meta.fps == 60
    assert "30/s, not 60/s, from about 10.0 s" in notes[0]["message"]
    assert take.meta.extra["dropped_frames_inserted"] == 308
    # a few dropped rows here and there are no change of rate
    dropped = [r for i, r in enumerate(rows) if i % 97 != 50]
    assert "row_rate_change" not in kinds(read_livelink_csv(write_csv(tmp_path / "d.csv", header, dropped)))


# 7. take.json of another app version: keys in any case; one the app never writes is said.
def take_folder_with(tmp_path: Path, samples: Path, take_json: dict) -> Path:
    header, rows = sample_lines(samples, 30)
    folder = tmp_path / "20250101_MySlate_7"
    folder.mkdir()
    write_csv(folder / "MySlate_7_iPhone.csv", header, rows)
    (folder / "take.json").write_text(json.dumps(take_json))
    return folder


def test_take_json_keys_are_read_in_any_case(tmp_path, samples):
    renamed = {"Identifier": "x", "Slate": "S", "Take": "7", "Subject": "Bob", "DeviceModel": "iPhone15,2"}
    take = read_take_folder(take_folder_with(tmp_path, samples, dict(renamed, frames="1218")))
    m = take.meta
    assert (m.id, m.slate, m.take_number, m.subject, m.device) == ("x", "S", 7, "Bob", "iPhone15,2")
    assert "bad_json" not in kinds(take)


def test_a_take_json_without_any_known_key_is_noted(tmp_path, samples):
    take = read_take_folder(take_folder_with(tmp_path, samples, {"name": "Bob", "shot": 7}))
    notes = [r["message"] for r in take.meta.repairs if r["kind"] == "bad_json"]
    assert len(notes) == 1 and "take.json" in notes[0] and "name" in notes[0]
    assert take.meta.subject == "iPhone"  # from the file name, as the note says


# Messages a probe of s2a-view met, which come from the take and audio readers.
def test_a_take_folder_with_times_out_of_order_names_its_frames_file(tmp_path, samples):
    from capture import read_take, write_take

    header, rows = sample_lines(samples, 10)
    folder = write_take(read_livelink_csv(write_csv(tmp_path / "t.csv", header, rows)), tmp_path / "takes")
    with np.load(folder / "frames.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["time"] = arrays["time"][::-1].copy()
    np.savez(folder / "frames.npz", **arrays)
    with pytest.raises(InputError, match=r"frames\.npz: take t: frame times are not strictly increasing"):
        read_take(folder)


def test_audio_that_is_not_audio_says_why_without_ffmpegs_error_number(tmp_path):
    from capture import read_audio

    garbage = tmp_path / "noise.wav"
    garbage.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(InputError, match="could not be decoded") as err:
        read_audio(garbage)
    assert "Errno" not in str(err.value) and str(garbage) in str(err.value)


def test_audio_given_as_a_folder_or_a_device_says_so(tmp_path):
    from capture import read_audio

    for path, needle in ((tmp_path, "is a folder"), (Path("/dev/null"), "not a regular file")):
        with pytest.raises(InputError, match=needle):
            read_audio(path)
    with pytest.raises(InputError, match="audio file not found"):
        read_audio(tmp_path / "none.wav")


# A frame log whose timecodes count at 30 beside a .mov that says 60 (and no video_metadata.json): the
# log's own video rows tell its rate, so its audio start is read at 30 and noted.
@pytest.mark.parametrize("log_rate, mov_rate", [(30, 60), (60, 30), (60, 60)])
def test_frame_log_counting_at_another_rate_than_the_mov(tmp_path, samples, log_rate, mov_rate):
    header, rows = sample_lines(samples, 60)
    folder = tmp_path / "20250101_MySlate_8"
    folder.mkdir()
    write_csv(folder / "MySlate_8_iPhone.csv", header, rows)
    csv_t0 = Timecode.parse(rows[0].split(",")[0]).seconds_of_day

    # two seconds of video rows (media time from 5 s on the phone's clock), the audio's first row 0.1 s in
    def tc(dt: float) -> str:
        return Timecode.from_seconds(csv_t0 + dt, log_rate).format()

    lines = [f"V,{i},{5 * log_rate + i},{log_rate},{tc(i / log_rate)},0" for i in range(2 * log_rate)]
    audio_row = f"A,0,{5 * 48000 + 4800},48000,{tc(0.1)},0"
    (folder / "frame_log.csv").write_text("\n".join([lines[0], audio_row, *lines[1:]]) + "\n")
    write_reference_mov(
        folder / "MySlate_8_iPhone.mov", mov_rate, 3, Audio(np.zeros((4800, 1), np.int16), 48000)
    )
    take = read_take_folder(folder)
    assert take.meta.audio.start_source == "frame_log_audio"
    assert take.meta.audio.start_s == pytest.approx(0.100, abs=1e-3)
    noted = [r["message"] for r in take.meta.repairs if r["kind"] == "frame_log_rate"]
    assert noted == ([] if log_rate == mov_rate else [noted[0]])
    if noted:
        assert f"count at {log_rate} fps, not at the video's {mov_rate}" in noted[0]


# From the guide walkthrough: --variant raw on a folder holding only a take's _cal CSV imported the _cal.
def test_variant_leaves_out_loose_csvs_of_another_variant(tmp_path, samples):
    header, rows = sample_lines(samples, 30)
    loose = tmp_path / "loose"
    loose.mkdir()
    write_csv(loose / "MySlate_9_iPhone_cal.csv", header, rows)
    proc = run_here("capture", "import", loose, "-o", tmp_path / "takes", "--variant", "raw")
    assert proc.returncode == 1 and not (tmp_path / "takes" / "MySlate_9_iPhone_cal").exists()
    assert "the cal CSV of its take, not --variant raw: skipped" in proc.stderr
    assert "no raw CSV among the sources" in proc.stderr
    write_csv(loose / "MySlate_9_iPhone_raw.csv", header, rows)
    proc = run_here("capture", "import", loose, "-o", tmp_path / "takes", "--variant", "raw", "--json")
    assert proc.returncode == 0 and [json.loads(x)["id"] for x in proc.stdout.splitlines()] == [
        "MySlate_9_iPhone_raw"
    ]
