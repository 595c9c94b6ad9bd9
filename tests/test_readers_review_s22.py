"""Fresh-eyes review of the capture readers on inputs built from the documented formats (formats doc §2,
§3): a short take's CSV cut by a power loss, a take folder whose names a copy upper-cased, another tool's
CSV in the app's layout with plain-number times."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_here

from capture import Audio, InputError, read_livelink_csv, read_take_folder, write_reference_mov
from capture.channels import CSV_ORDER
from capture.timecode import Timecode

HEADER = "Timecode,BlendshapeCount," + ",".join(CSV_ORDER)
T0 = 14 * 3600 + 58 * 60 + 2.0  # 14:58:02:00.000


def rows(n: int, fps: float = 60.0, t0: float = T0, times=None) -> list[str]:
    """``n`` tracked rows as the app writes them (FF at 60 fps, 10 decimals), or with ``times`` cells."""
    cells = [Timecode.from_seconds(t0 + i / fps).format() for i in range(n)] if times is None else times
    values = ",".join(f"{0.1:.10f}" for _ in CSV_ORDER)
    return [f"{tc},{len(CSV_ORDER)},{values}" for tc in cells]


def rows_at(seconds, tracked: bool = True) -> list[str]:
    """Rows at these times of day: tracked (as ``rows`` writes them) or face lost (count 0, no values)."""
    cells = [Timecode.from_seconds(t).format() for t in seconds]
    return rows(len(cells), times=cells) if tracked else [f"{tc},0" for tc in cells]


def write_csv(path: Path, lines: list[str]) -> Path:
    path.write_text("".join(line + "\n" for line in [HEADER, *lines]))
    return path


# 1. A phone losing power leaves the file's length written and its last blocks NUL: a take short enough
# that the NUL run starts in the first 64 KiB was refused whole as "binary data".
@pytest.mark.parametrize("cut", [0, 300], ids=["after_a_row", "inside_a_row"])
def test_a_short_take_ending_in_nul_bytes_keeps_its_rows(tmp_path, cut):
    path = write_csv(tmp_path / "MySlate_3_iPhone.csv", rows(40))
    text = path.read_bytes()
    path.write_bytes(text[: len(text) - cut] + b"\0" * 70_000)  # the NUL run reaches past 64 KiB too
    take = read_livelink_csv(path)
    assert take.time.size == (40 if cut == 0 else 39)
    assert take.valid.all()
    assert [r["kind"] for r in take.meta.repairs] == ["truncated_row"]


def test_nul_bytes_with_text_after_them_or_alone_are_still_binary(tmp_path):
    path = write_csv(tmp_path / "a.csv", rows(10))
    path.write_bytes(path.read_bytes() + b"\0" * 100 + b"12:00:00:00.000,0\n")
    with pytest.raises(InputError, match="binary data"):
        read_livelink_csv(path)
    path.write_bytes(b"\0" * 5000)
    with pytest.raises(InputError, match="binary data"):
        read_livelink_csv(path)


# 2. A take folder whose app files a copy upper-cased (TAKE.JSON, FRAME_LOG.CSV, as an old FAT tool or a
# zip from Windows leaves them): their .CSV and .MOV were found, take.json and frame_log.csv were not, so
# the audio was placed by the .mov's timecode instead of frame_log's audio row, in silence.
def test_app_files_named_in_upper_case_are_read(tmp_path):
    folder = tmp_path / "20250101_MySlate_7"
    folder.mkdir()
    write_csv(folder / "MYSLATE_7_IPHONE.CSV", rows(60))
    log = [Timecode.from_seconds(T0 + dt).format() for dt in (0.0, 0.1)]
    (folder / "FRAME_LOG.CSV").write_text(f"V,0,0,60,{log[0]},0\nA,0,0,48000,{log[1]},0\n")
    take_json = {"identifier": "20250101_MySlate_7", "slate": "MySlate", "take": 7, "subject": "iPhone"}
    (folder / "TAKE.JSON").write_text(json.dumps(take_json))
    (folder / "Video_Metadata.json").write_text(json.dumps({"FrameRate": 60}))
    (folder / "Thumbs.db").write_bytes(b"\xd0\xcf\x11\xe0")
    (folder / "desktop.ini").write_text("[.ShellClassInfo]\n")
    audio = Audio(np.zeros((4800, 1), np.int16), 48000, "PCM_16")
    write_reference_mov(folder / "MYSLATE_7_IPHONE.MOV", 60, 6, audio)
    take = read_take_folder(folder)
    assert take.meta.audio.start_source == "frame_log_audio"
    assert take.meta.audio.start_s == pytest.approx(0.100, abs=1e-3)
    assert (take.meta.slate, take.meta.take_number) == ("MySlate", 7)
    roles = {s.role for s in take.meta.sources}
    assert {"take.json", "frame_log.csv", "video_metadata.json"} <= roles


def test_the_apps_own_spelling_wins_over_another_case(tmp_path):
    folder = tmp_path / "take"
    folder.mkdir()
    write_csv(folder / "S_1_iPhone.csv", rows(30))
    (folder / "take.json").write_text(json.dumps({"slate": "Own", "take": 1}))
    (folder / "TAKE.JSON").write_text(json.dumps({"slate": "Other", "take": 2}))
    take = read_take_folder(folder)
    assert take.meta.slate == "Own"


# 3. Another tool's CSV in the app's layout whose Timecode column holds seconds or frame numbers: the
# error said only that '0.0000' is no HH:MM:SS:FF.fff timecode; it now says how to import such a file.
@pytest.mark.parametrize("times", [[f"{i / 30:.4f}" for i in range(90)], [str(i) for i in range(90)]])
def test_plain_number_times_in_the_apps_layout_say_how_to_import_them(tmp_path, times):
    path = write_csv(tmp_path / "take.csv", rows(90, times=times))
    proc = run_here("capture", "import", path, "-o", tmp_path / "out")
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    assert "plain numbers" in proc.stderr and "--matrix" in proc.stderr and "--fps" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


# 4. UTF-16 text without its byte-order mark (Python's "utf-16-le", .NET's UnicodeEncoding without a
# preamble): the reader said "binary data", import that its header does not start with Timecode.
@pytest.mark.parametrize("codec", ["utf-16-le", "utf-16-be"])
def test_utf16_without_its_mark_says_to_save_it_as_utf8(tmp_path, codec):
    path = tmp_path / "MySlate_3_iPhone.csv"
    path.write_bytes("".join(line + "\r\n" for line in [HEADER, *rows(20)]).encode(codec))
    with pytest.raises(InputError, match="UTF-16 text: save it as UTF-8"):
        read_livelink_csv(path)
    proc = run_here("capture", "import", path, "-o", tmp_path / "out")
    assert proc.returncode != 0 and "UTF-16 text: save it as UTF-8" in proc.stderr


# 5. Another writer of the app's layout putting a clock time HH:MM:SS.fff (seconds and their fraction,
# no frames) in the Timecode column: every row was dropped ("no usable data rows"); now read as seconds,
# across midnight too, with one note.
def test_clock_times_in_the_timecode_column_are_read_as_seconds(tmp_path):
    def clock(t: float) -> str:
        t %= 86400
        return f"{int(t) // 3600:02d}:{int(t) // 60 % 60:02d}:{t % 60:06.3f}"

    times = [clock(86400 - 1 + i / 30) for i in range(90)]  # 23:59:59.000 on, 30 rows/s
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", rows(90, times=times)))
    assert take.time.size == 90 and take.valid.all() and take.meta.fps == 30.0
    assert np.allclose(np.diff(take.time), 1 / 30, atol=1e-3)  # 3 decimals of a second
    (note,) = take.meta.repairs
    assert note["kind"] == "timecode_format" and "clock time" in note["message"]


# 6. A writer of the app's layout leaving the head and eye angle cells empty on every row (it tracks the
# 52 shapes only): every frame was BAD_VALUE, the whole take unusable; now those 9 channels, which hold
# nothing, are left out with one note, and the frames keep their 52 values.
def test_channels_empty_on_every_row_are_left_out_not_every_frame(tmp_path):
    lines = [row.rsplit(",", 9)[0] + "," * 9 for row in rows(120)]
    lines[30:40] = [row.split(",")[0] + ",0" for row in lines[30:40]]  # face lost a while
    lines[50] = lines[50].replace("0.1000000000", "abc", 1)  # one damaged cell of a kept channel
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", lines))
    assert sorted(c.lower() for c in take.meta.channels) == sorted(c.lower() for c in CSV_ORDER[:52])
    assert int(take.valid.sum()) == 120 - 10 - 1
    assert sorted(r["kind"] for r in take.meta.repairs) == ["bad_value", "empty_channel"]
    assert [r["line"] for r in take.meta.repairs if r["kind"] == "bad_value"] == [52]
    assert np.allclose(take.values[take.valid], 0.1)


# 7. The app's JSON and log files as a Windows editor re-saves them: take.json with a UTF-8 byte-order mark
# (or as Notepad's "Unicode") was ignored whole (id, slate, take lost); frame_log.csv's first row, behind
# the mark, was skipped: without audio rows the audio was placed at video frame 1, a frame late.
@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16"])
def test_app_files_with_a_byte_order_mark_are_read(tmp_path, encoding):
    folder = tmp_path / "copied"
    folder.mkdir()
    write_csv(folder / "MySlate_7_iPhone.csv", rows(60))
    log = [Timecode.from_seconds(T0 + i / 60).format() for i in range(2)]
    (folder / "frame_log.csv").write_bytes(f"V,0,0,60,{log[0]},0\r\nV,1,1,60,{log[1]},0\r\n".encode(encoding))
    take_json = {"identifier": "20250101_MySlate_7", "slate": "MySlate", "take": 7}
    (folder / "take.json").write_bytes(json.dumps(take_json).encode(encoding))
    write_reference_mov(folder / "MySlate_7_iPhone.mov", 60, 6, Audio(np.zeros((4800, 1), np.int16), 48000))
    take = read_take_folder(folder)
    assert (take.meta.id, take.meta.take_number) == ("20250101_MySlate_7", 7)
    assert take.meta.audio.start_source == "frame_log_video"
    assert take.meta.audio.start_s == pytest.approx(0.0, abs=1e-6)
    assert take.meta.repairs == []


def drop_frame_label(n: int) -> str:
    """SMPTE drop-frame timecode (29.97 fps) of frame ``n`` counted from midnight."""
    tens, rest = divmod(n, 17982)
    n += 18 * tens + (2 * ((rest - 2) // 1798) if rest >= 2 else 0)
    return f"{n // 108000:02d}:{n // 1800 % 60:02d}:{n // 30 % 60:02d};{n % 30:02d}"


# 8. Drop-frame timecodes (HH:MM:SS;FF, another writer's 29.97 fps timeline): the labels ;00 and ;01 each
# minute skips became 2 dropped frames a minute that never were, and times drifted by the labels.
def test_drop_frame_timecodes_are_counted_frames_not_gaps(tmp_path):
    first = 50 * 30  # 00:00:50;00, 20 s before the first minute's skipped labels
    labels = [drop_frame_label(first + i) for i in range(1200)]  # 40 s, past 00:01:00;02
    assert "00:01:00;02" in labels and "00:01:00;00" not in labels
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", rows(1200, times=labels)))
    assert take.time.size == 1200 and take.valid.all()
    assert np.allclose(np.diff(take.time), 1001 / 30000, atol=1e-9)
    assert any("drop-frame" in r["message"] for r in take.meta.repairs)


def test_semicolons_on_labels_a_drop_frame_count_skips_are_read_as_written(tmp_path):
    seconds = ["00:00:58", "00:00:59", "00:01:00"]  # 00:01:00;00 and ;01: labels drop-frame never writes
    labels = [f"{second};{ff:02d}" for second in seconds for ff in range(30)]
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", rows(90, times=labels)))
    assert take.time.size == 90 and np.allclose(np.diff(take.time), 1 / 30, atol=1e-9)
    assert not any("drop-frame" in r["message"] for r in take.meta.repairs)
