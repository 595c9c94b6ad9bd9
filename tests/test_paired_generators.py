"""Paired data as other generators and tools write it (pandas, R, spreadsheets, Audio2Face, names files),
built from the real samples: the NeuroSync take (52 ARKit channels at 60 fps with its audio) and FACEGOOD's
rig takes (116 controls, names as text and as a .npy)."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from capture import FrameStatus, InputError, Timecode, read_paired, read_take
from capture.channels import ARKIT52
from capture.paired import load_npy
from tests.conftest import run_cli

NS = "paired/neurosync-trainer-lite-testset"
FG = "paired/facegood-audio2face"


@pytest.fixture(scope="module")
def ns(samples):
    """The NeuroSync take: its 52 ARKit names, their values (frames x 52, 60 fps), the seconds of its
    Live Link timecodes from the first row (a real capture's frame times), its audio."""
    with open(samples / NS / "testset.csv", newline="") as f:
        header, *rows = csv.reader(f)
    names = [n[0].lower() + n[1:] for n in header[2:54]]
    assert names[:2] == ["eyeBlinkLeft", "eyeLookDownLeft"] and len(rows) == 1218
    seconds = np.array([Timecode.parse(r[0]).seconds_of_day for r in rows])
    values = np.array([r[2:54] for r in rows], dtype=np.float64)
    return names, values, seconds - seconds[0], samples / NS / "audio.wav"


def write_csv(path: Path, header, values, first=None, sep=",", decimal=".", encoding="utf-8") -> Path:
    """A CSV as a generator writes it: ``header`` (None: no header row), a ``first`` column of cells
    (time, frame or index) before the values, written with 6 decimals."""
    lines = [] if header is None else [sep.join(header)]
    for i, row in enumerate(values):
        cells = [f"{x:.6f}".replace(".", decimal) for x in row]
        lines.append(sep.join(([first[i]] if first is not None else []) + cells))
    path.write_text("\n".join(lines) + "\n", encoding=encoding)
    return path


def cli_import(tmp_path: Path, *args) -> tuple[object, list[dict]]:
    proc = run_cli("capture", "import", *args, "-o", tmp_path / "takes", "--json")
    return proc, [json.loads(line) for line in proc.stdout.splitlines()]


def imported(tmp_path: Path, *args):
    proc, out = cli_import(tmp_path, *args)
    assert proc.returncode == 0, proc.stderr
    return read_take(out[-1]["path"])


def one_line_error(tmp_path: Path, *args) -> str:
    proc, _ = cli_import(tmp_path, *args)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    return proc.stderr


# a time column in seconds places the frames, and align keeps them there


def test_a_seconds_time_column_keeps_its_times_and_says_so_to_align(ns, tmp_path):
    names, values, seconds, audio = ns
    timed = write_csv(tmp_path / "timed.csv", ["time", *names], values, [f"{t:.6f}" for t in seconds])
    take = imported(tmp_path, "--matrix", timed, "--audio", audio)
    assert take.meta.audio.start_source == "paired_time_column"
    assert take.meta.fps == 60 and np.allclose(take.time, seconds, atol=1e-6)
    framed = write_csv(
        tmp_path / "framed.csv", ["frame", *names], values, [str(i) for i in range(len(values))]
    )
    plain = write_csv(tmp_path / "plain.csv", names, values)
    for path in (framed, plain):
        take = imported(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
        assert take.meta.audio.start_source == "paired_frame_convention"


# a time column rounded to 2 decimals


@pytest.mark.parametrize("fps", [30, 60])
def test_a_time_column_rounded_to_two_decimals_gives_its_rate(ns, tmp_path, fps):
    """30 fps written to 2 decimals steps by 0.03 and 0.04 s (median: 33.3 fps), 60 fps by 0.01 and
    0.02 s (median: 50 fps): the rate is the slope over the whole column."""
    names, values, _, audio = ns
    values = values[:: 60 // fps]
    times = [f"{i / fps:.2f}" for i in range(len(values))]
    path = write_csv(tmp_path / f"r{fps}.csv", ["time", *names], values, times)
    assert imported(tmp_path, "--matrix", path, "--audio", audio).meta.fps == fps
    take = imported(tmp_path, "--matrix", path, "--audio", audio, "--fps", str(fps))
    assert take.meta.fps == fps and take.count(FrameStatus.DROPPED) == 0
    assert np.allclose(take.time, np.array(times, dtype=float))
    other = {30: 25, 60: 50}[fps]  # a truly different rate is still refused
    assert "does not match" in one_line_error(tmp_path, "--matrix", path, "--audio", audio, "--fps", other)


# a `time` column of frame numbers


def test_a_time_column_of_frame_numbers_is_not_a_one_fps_take(ns, tmp_path):
    names, values, _, audio = ns
    path = write_csv(tmp_path / "t.csv", ["time", *names], values, [str(i) for i in range(len(values))])
    err = one_line_error(tmp_path, "--matrix", path, "--audio", audio)
    assert "frame numbers, not seconds?" in err and "`frame`" in err and "--fps" in err
    take = imported(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
    assert take.meta.fps == 60 and take.time[600] == pytest.approx(10.0)
    assert take.meta.audio.start_source == "paired_frame_convention"
    assert [r["kind"] for r in take.meta.repairs] == ["frame_numbers"]
    slow = write_csv(
        tmp_path / "s.csv", ["time", *names], values, [f"{i / 5:.6f}" for i in range(len(values))]
    )
    with pytest.raises(InputError, match=r"gives 5 frames per second, slower than any face capture"):
        read_paired(audio, slow, None)


# quoted header cells (R's write.csv, with its row names)


def test_quoted_header_and_r_row_names_are_read_as_a_csv(ns, tmp_path):
    names, values, _, audio = ns
    header = ['""', '"time"', *(f'"{n}"' for n in names)]
    first = [f'"{i + 1}",{i / 60:.6f}' for i in range(len(values))]  # R: quoted row names 1..N, then time
    path = write_csv(tmp_path / "r.csv", header, values, first)
    take = imported(tmp_path, "--matrix", path, "--audio", audio)
    assert take.meta.channels == names and take.meta.fps == 60
    assert np.allclose(take.values, values, atol=1e-6)


# time columns in seconds and milliseconds under other names


@pytest.mark.parametrize(
    "name, scale",
    [("time_ms", 1000), ("Time (s)", 1), ("time (ms)", 1000), ("timestamp_ms", 1000), ("milliseconds", 1000)]
    + [("ms", 1000), ("Time [sec]", 1), ("Timestamp [ms]", 1000)],
)
def test_time_columns_named_in_seconds_or_milliseconds(ns, tmp_path, name, scale):
    names, values, seconds, audio = ns
    path = write_csv(tmp_path / "m.csv", [name, *names], values, [f"{t * scale:.6f}" for t in seconds])
    take = read_paired(audio, path, None)
    assert take.meta.channels == names and take.meta.fps == 60
    assert np.allclose(take.time, seconds, atol=1e-6)


def test_a_milliseconds_column_through_the_cli(ns, tmp_path):
    names, values, seconds, audio = ns
    path = write_csv(tmp_path / "ms.csv", ["time_ms", *names], values, [f"{t * 1000:.3f}" for t in seconds])
    take = imported(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
    assert "time_ms" not in take.meta.channels and np.allclose(take.time, seconds, atol=1e-6)


# pandas' default header of column numbers


@pytest.mark.parametrize("index", [False, True])
def test_a_header_of_column_numbers_is_not_frame_zero(ns, tmp_path, index):
    """``pd.DataFrame(weights).to_csv(path, index=index)``: a header 0..51 (after an empty cell over the
    index column with ``index=True``)."""
    names, values, _, audio = ns
    header = [""] * index + [str(i) for i in range(52)]
    path = write_csv(
        tmp_path / "p.csv", header, values, [str(i) for i in range(len(values))] if index else None
    )
    err = one_line_error(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
    assert "numbers the columns 0..51" in err and "--names" in err
    (tmp_path / "names.txt").write_text("\n".join(names) + "\n")
    take = imported(
        tmp_path, "--matrix", path, "--audio", audio, "--fps", "60", "--names", tmp_path / "names.txt"
    )
    assert take.values.shape == values.shape and np.allclose(take.values, values, atol=1e-6)


# names in a .npy: bytes in another encoding, an empty name


def test_names_npy_of_gbk_bytes_or_with_an_empty_name_is_a_clear_error(samples, tmp_path):
    fg = samples / FG
    names = load_npy(fg / "shirley_1015_bs_name.npy")  # a Python 2 era .npy
    args = ["--matrix", fg / "bs_value/bs_value_1114_3_16.npy", "--audio", fg / "wav/1114_3_16.wav"]
    gbk = names.astype("S40")
    gbk[0] = "嘴巴张开".encode("gbk")  # a Chinese rig's tool writing its own code page
    np.save(tmp_path / "gbk.npy", gbk)
    err = one_line_error(tmp_path, *args, "--fps", "30", "--names", tmp_path / "gbk.npy")
    assert "gbk.npy: name 0" in err and "not UTF-8" in err
    utf8 = names.astype("S40")
    np.save(tmp_path / "utf8.npy", utf8)
    take = imported(tmp_path, *args, "--fps", "30", "--names", tmp_path / "utf8.npy")
    assert take.meta.channels[0] == "brow_lower_l"
    empty = names.copy()
    empty[5] = ""
    np.save(tmp_path / "empty.npy", empty)
    assert "empty.npy: name 5 of the array is empty" in one_line_error(
        tmp_path, *args, "--fps", "30", "--names", tmp_path / "empty.npy"
    )
    (tmp_path / "gap.txt").write_text(",".join(names[:5]) + ",," + ",".join(names[5:]) + "\n")
    with pytest.raises(InputError, match="gap.txt:1: an empty channel name"):
        read_paired(
            fg / "wav/1114_3_16.wav", fg / "bs_value/bs_value_1114_3_16.npy", 30, tmp_path / "gap.txt"
        )


# Audio2Face at NTSC rates


@pytest.mark.parametrize(
    "written, exact", [(29.97, 30000 / 1001), (59.94, 60000 / 1001), (23.976, 24000 / 1001)]
)
def test_audio2face_ntsc_export_rate_is_the_exact_ntsc_rate(ns, tmp_path, written, exact):
    names, values, _, audio = ns
    export = {"exportFps": written, "numPoses": 52, "numFrames": 300, "facsNames": list(ARKIT52)}
    export["weightMat"] = values[:300].round(6).tolist()
    (tmp_path / "a2f.json").write_text(json.dumps(export))
    assert imported(tmp_path, "--matrix", tmp_path / "a2f.json", "--audio", audio).meta.fps == exact
    assert read_paired(audio, tmp_path / "a2f.json", written).meta.fps == exact  # --fps as written agrees


# semicolons, tabs, decimal commas, UTF-16, empty cells, SMPTE timecode


@pytest.mark.parametrize(
    "sep, decimal, encoding",
    [
        (";", ",", "utf-8"),
        (";", ".", "utf-8"),
        ("\t", ".", "utf-8"),
        ("\t", ",", "utf-8"),
        (",", ".", "utf-16"),
    ],
)
def test_spreadsheet_csvs_are_read(ns, tmp_path, sep, decimal, encoding):
    names, values, _, audio = ns
    path = write_csv(tmp_path / "x.csv", names, values, sep=sep, decimal=decimal, encoding=encoding)
    take = imported(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
    assert take.meta.channels == names and np.allclose(take.values, values, atol=1e-6)


def test_empty_cells_are_bad_value_frames_and_a_timecode_column_is_named(ns, tmp_path):
    names, values, _, audio = ns
    path = write_csv(tmp_path / "nan.csv", names, values)
    lines = path.read_text().splitlines()
    for row in (11, 12):  # pandas writes NaN as an empty cell
        cells = lines[row].split(",")
        cells[17] = ""
        lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    take = imported(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
    assert np.flatnonzero(take.frame_status == FrameStatus.BAD_VALUE).tolist() == [10, 11]
    assert np.isnan(take.values[10, 17]) and take.values[10, 16] == pytest.approx(values[10, 16])
    smpte = [f"00:00:{i // 60:02d}:{i % 60:02d}" for i in range(len(values))]
    path = write_csv(tmp_path / "tc.csv", ["Timecode", *names], values, smpte)
    err = one_line_error(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
    assert "tc.csv:2: non-numeric value in the matrix: '00:00:00:00' in column 'Timecode'" in err
    assert "SMPTE timecode" in err


# --pair-audio: Audio2Face exports wherever their keys are, headerless CSVs


def test_pair_audio_finds_an_export_whose_names_come_last_and_says_what_it_skips(ns, tmp_path):
    names, values, _, audio = ns
    folder = tmp_path / "in"
    folder.mkdir()
    export = {"exportFps": 60, "numFrames": len(values), "weightMat": values.round(6).tolist()}
    export |= {"numPoses": 52, "facsNames": list(ARKIT52)}  # after a weightMat of more than 64 KiB
    (folder / "late.json").write_text(json.dumps(export))
    assert (folder / "late.json").read_bytes().find(b'"facsNames"') > 1 << 16
    shutil.copy(audio, folder / "late.wav")
    (folder / "settings.json").write_text('{"solver": "default"}')
    proc, out = cli_import(tmp_path, folder, "--pair-audio")
    assert proc.returncode == 0, proc.stderr
    assert [Path(x["path"]).name for x in out] == ["late"] and out[0]["audio_duration_s"] > 20
    assert "settings.json: not an Audio2Face blendshape export" in proc.stderr and "skipped" in proc.stderr


def test_a_headerless_csv_under_pair_audio_says_what_works_there(ns, tmp_path):
    names, values, _, audio = ns
    folder = tmp_path / "in"
    folder.mkdir()
    write_csv(folder / "take.csv", None, values)
    shutil.copy(audio, folder / "take.wav")
    err = one_line_error(tmp_path, folder, "--pair-audio")
    assert "no channel names: write a header row of channel names in the CSV" in err
    assert "--matrix, --names and --audio" in err
    (tmp_path / "names.txt").write_text("\n".join(names))
    args = ["--audio", folder / "take.wav", "--fps", "60", "--names", tmp_path / "names.txt"]
    take = imported(tmp_path, "--matrix", folder / "take.csv", *args)
    assert take.meta.channels == names  # the way it names: imported alone with --names


# problems in the names file are the names file's


def test_names_file_problems_name_the_names_file(samples, tmp_path):
    fg = samples / FG
    args = [
        "--matrix",
        fg / "bs_value/bs_value_1114_3_16.npy",
        "--audio",
        fg / "wav/1114_3_16.wav",
        "--fps",
        "30",
    ]
    text = (fg / "bs_names.txt").read_text()
    (tmp_path / "utf16.txt").write_text(text, encoding="utf-16")  # Windows' "Unicode" text
    take = imported(tmp_path, *args, "--names", tmp_path / "utf16.txt")
    assert take.meta.channels[:2] == ["brow_lower_l", "tongue_Scale_X"] and len(take.meta.channels) == 116
    (tmp_path / "header.txt").write_text("name\n" + text)
    err = one_line_error(tmp_path, *args, "--names", tmp_path / "header.txt")
    assert "header.txt: 117 channel names for a matrix of 116 columns (bs_value_1114_3_16.npy)" in err
    assert "'name', a header? remove it" in err
    (tmp_path / "latin1.txt").write_bytes(text.replace("brow_lower_l", "brow_lower_é").encode("latin-1"))
    assert "latin1.txt:1: not UTF-8 text" in one_line_error(
        tmp_path, *args, "--names", tmp_path / "latin1.txt"
    )


def test_a_livelink_csv_saved_as_utf16_is_named_as_such(samples, tmp_path):
    """Not "not a Live Link Face CSV", nor an SMPTE timecode in a generic CSV: the app's CSV re-saved as
    Windows' "Unicode" text."""
    text = (samples / NS / "testset.csv").read_text()
    (tmp_path / "take.csv").write_text(text, encoding="utf-16")
    for audio in ([], ["--audio", samples / NS / "audio.wav"]):
        err = one_line_error(tmp_path, tmp_path / "take.csv", *audio)
        assert "a Live Link Face CSV saved as UTF-16 text: save it as UTF-8" in err
