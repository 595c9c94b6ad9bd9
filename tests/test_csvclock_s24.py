"""NeuroSync Player's CSVs (its utils/csv/save_csv.py): 60 rows/s whose timecode's part after the dot is the
milliseconds of the second, not the app's sub-frame (formats doc §2), with FF the frame those fall in (one
less now and then, from floating error). Read as the app's, a 20 s file became 1,538 frames, 320 of them
DROPPED, and align interpolated over half of it; its times are read as seconds and milliseconds now, which
no real take of the app's ever is. A ``row_rate_change`` note no longer says "60/s, not 60/s"."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_cli
from test_readers_review_s22 import rows_at, write_csv

from capture import channels as ch
from capture import read_livelink_csv
from capture.csv_take import read_csv_rows
from capture.take import FrameStatus, read_take
from capture.timecode import MIN_MILLISECOND_ROWS, Timecode, millisecond_seconds

EMOTIONS = ["Angry", "Disgusted", "Fearful", "Happy", "Neutral", "Sad", "Surprised"]


def neurosync_timecode(frame: int) -> str:
    """Frame ``frame``'s timecode as NeuroSync Player builds it (from its logic, described): the time in
    seconds split into hours, minutes and seconds, the milliseconds of the second after the dot, FF the
    whole 60 fps frames in those milliseconds."""
    hours, rest = divmod(frame * (1 / 60), 3600)
    minutes, seconds = divmod(rest, 60)
    milliseconds = (seconds - int(seconds)) * 1000
    ff = int(milliseconds / (1000 / 60))
    return f"{int(hours):02}:{int(minutes):02}:{int(seconds):02}:{ff:02}.{int(milliseconds):03}"


def neurosync_csv(path: Path, frames: int, emotions: bool) -> tuple[Path, np.ndarray]:
    """A NeuroSync Player CSV of ``frames`` rows: the 61 columns (``BlendshapeCount`` 61), or 68 with its
    emotion columns (count 68); float32 values as numpy prints them (``0.1234567``, ``1e-05``). The file
    and its values (rows x columns)."""
    columns = list(ch.CSV_ORDER) + (EMOTIONS if emotions else [])
    values = np.random.default_rng(frames).random((frames, len(columns))).astype(np.float32)
    values[::7, 3] = np.float32(1e-05)  # numpy writes it in exponent form
    lines = [
        f"{neurosync_timecode(i)},{len(columns)}," + ",".join(str(v) for v in row)
        for i, row in enumerate(values)
    ]
    path.write_text("Timecode,BlendshapeCount," + ",".join(columns) + "\n" + "\n".join(lines) + "\n")
    return path, values


def test_the_generator_writes_what_neurosync_player_does() -> None:
    # FF one less than the milliseconds say now and then (58 at 983 ms, 0 at 16 ms), from floating error
    assert [neurosync_timecode(i) for i in (0, 1, 59, 60, 3599, 3600, 3601)] == [
        "00:00:00:00.000",
        "00:00:00:01.016",
        "00:00:00:58.983",
        "00:00:01:00.000",
        "00:00:59:59.983",
        "00:01:00:00.000",
        "00:01:00:00.016",
    ]


@pytest.mark.parametrize("emotions", [False, True], ids=["61_columns", "68_columns"])
@pytest.mark.parametrize("seconds", [0.5, 20, 70])
def test_a_neurosync_player_csv_imports_and_aligns_frame_for_row(
    tmp_path: Path, seconds: float, emotions: bool
) -> None:
    frames = round(seconds * 60)
    csv, values = neurosync_csv(tmp_path / "generated.csv", frames, emotions)
    rate = 16000
    t = np.arange(int((seconds + 0.05) * rate)) / rate
    sf.write(tmp_path / "generated.wav", 0.2 * np.sin(2 * np.pi * 220 * t), rate)
    run_cli(
        "capture", "import", csv, "--audio", tmp_path / "generated.wav", "-o", tmp_path / "takes", check=True
    )
    take = read_take(tmp_path / "takes" / "generated")
    assert take.time.size == frames and take.valid.all()  # 20 s: was 1,538 frames, 320 of them DROPPED
    assert np.abs(take.time - np.arange(frames) / 60).max() <= 1.001e-3  # the milliseconds, truncated
    assert take.meta.fps == 60 and take.meta.extra["dropped_frames_inserted"] == 0
    kinds = [r["kind"] for r in take.meta.repairs]
    assert "timecode_format" in kinds and "row_rate_change" not in kinds  # was row_rate_change, twice
    assert ("unknown_columns" in kinds) == emotions
    assert "milliseconds" in take.meta.repairs[0]["message"]
    # the emotion columns are kept under their own names, as written
    assert take.meta.channels[61:] == (EMOTIONS if emotions else [])
    assert np.array_equal(take.values[:, 61:], values[:, 61:])
    jaw = take.meta.channels.index("jawOpen")
    assert np.array_equal(take.values[:, jaw], values[:, list(ch.CSV_ORDER).index("JawOpen")])
    proc = run_cli(
        "align",
        tmp_path / "takes",
        "-o",
        tmp_path / "aligned",
        "--vad",
        "none",
        "--min-segment-s",
        0.2,
        "--json",
    )
    if seconds < 1:  # align's limit: a face tracked for under 1 s is refused, in one line
        assert proc.returncode != 0 and "shorter than 1 s" in proc.stderr and "Traceback" not in proc.stderr
        return
    assert proc.returncode == 0, proc.stderr
    (report,) = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert report["interpolated_share"] == 0 and "mostly_interpolated" not in report["flags"]  # was 0.53
    assert abs(report["frame_clock"]["timecode_vs_nominal_ppm"]) < 2000  # was -208,664
    assert report["frames"] >= frames - 2


# Strict mode reads times only as they are written: the milliseconds' reading is refused, in one line.
def test_strict_mode_refuses_the_milliseconds_reading(tmp_path: Path) -> None:
    csv, _ = neurosync_csv(tmp_path / "generated.csv", 120, False)
    proc = run_cli("capture", "import", csv, "-o", tmp_path / "takes", "--strict")
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "milliseconds of the second" in proc.stderr and "strict mode" in proc.stderr


# The real takes of the app never read so: about 3 % of their rows have a sub-frame that agrees with FF as
# milliseconds, never more than 3 in a row, so not a take of 10 rows or more cut anywhere from them (a short
# take, 1-2 s, of the 30 or 60 rows/s builds), nor any whole file.
def test_no_real_take_of_the_app_reads_as_milliseconds(samples: Path) -> None:
    real = sorted((samples / "livelinkface").glob("*/*.csv"))
    real.append(samples / "paired" / "neurosync-trainer-lite-testset" / "testset.csv")
    assert len(real) == 4
    for path in real:
        assert "timecode_format" not in [r["kind"] for r in read_livelink_csv(path).meta.repairs]
        t = read_csv_rows(path).seconds_of_day
        for length in (MIN_MILLISECOND_ROWS, 60, 120):
            cuts = [t[i : i + length] for i in range(0, t.size - length + 1)]
            assert all(millisecond_seconds(cut) is None for cut in cuts), (path.name, length)


# The app's sub-frame creeps (0.0016 a row in newer builds) or stays put while FF runs through the second:
# whatever it starts at, 10 rows in a row at 30 or 60 rows/s never all agree with FF as milliseconds.
@pytest.mark.parametrize("ff_step", [1, 2])
@pytest.mark.parametrize("creep", [0.0, 0.0016, -0.0016])
def test_no_app_like_run_of_ten_rows_reads_as_milliseconds(ff_step: int, creep: float) -> None:
    t0 = 12 * 3600 + 28 * 60
    k = np.arange(MIN_MILLISECOND_ROWS)
    for sub_frame in np.arange(0, 1, 0.001):
        for first in range(60):
            frames = first + ff_step * k + (sub_frame + creep * k) % 1
            times = [
                Timecode.parse(Timecode.from_seconds(t0 + f / 60).format()).seconds_of_day for f in frames
            ]
            assert millisecond_seconds(np.array(times)) is None, (sub_frame, first)


# Fewer rows than MIN_MILLISECOND_ROWS (a NeuroSync file of 9 rows) are read as the app's: too few to tell.
def test_a_take_of_fewer_rows_is_read_as_the_apps(tmp_path: Path) -> None:
    csv, _ = neurosync_csv(tmp_path / "short.csv", MIN_MILLISECOND_ROWS - 1, False)
    assert not [r for r in read_livelink_csv(csv).meta.repairs if r["kind"] == "timecode_format"]
    csv, _ = neurosync_csv(tmp_path / "ten.csv", MIN_MILLISECOND_ROWS, False)
    assert [r["kind"] for r in read_livelink_csv(csv).meta.repairs] == ["timecode_format"]


# Rows at the take's rate but uneven (steps of 0.4, 1 and 1.6 frames): the note said "rows come at 60/s,
# not 60/s"; it says they come unevenly now.
def test_uneven_rows_at_the_takes_rate_are_not_said_to_come_at_another(tmp_path: Path) -> None:
    t, lines = 14 * 3600 + 58 * 60 + 1.2 / 60, []
    row = ",".join(f"{0.1:.10f}" for _ in range(61))
    for i in range(600):
        lines.append(f"{Timecode.from_seconds(t).format()},61,{row}")
        t += (0.4, 1.0, 1.6)[i % 3] / 60
    take = read_livelink_csv(write_csv(tmp_path / "uneven.csv", lines))
    (note,) = [r["message"] for r in take.meta.repairs if r["kind"] == "row_rate_change"]
    assert "not 60/s" not in note and note.startswith("rows come unevenly") and "60 rows/s in all" in note
    assert take.meta.fps == 60 and int((take.frame_status == FrameStatus.DROPPED).sum()) == 199


# Review of d33a2a8 (rate from the steps beside rows with values): the mirror of its case, a 60 fps take
# whose tracked rows were dropped every other one for 10 s (30 a second) before 20 s of face-lost rows and
# 2 s of tracked rows at 60 a second, was read as 30 fps: its last 2 s of tracked rows shared frames, 1/60 s
# apart in a 30 fps take, without a note. Dropped rows only lengthen steps: the shorter rate is the take's.
def test_tracked_rows_dropped_at_half_the_cadence_do_not_set_the_rate(tmp_path: Path) -> None:
    t0 = 14 * 3600 + 58 * 60
    tracked = [t0 + i / 30 for i in range(300)]
    lost = [tracked[-1] + (i + 1) / 60 for i in range(1200)]
    after = [lost[-1] + (i + 1) / 60 for i in range(120)]
    lines = rows_at(tracked) + rows_at(lost, tracked=False) + rows_at(after)
    take = read_livelink_csv(write_csv(tmp_path / "MySlate_8_iPhone.csv", lines))
    assert take.meta.fps == 60.0  # was 30
    assert np.allclose(np.diff(take.time), 1 / 60, atol=2e-3)  # one frame per 1/60 s, none shared
    assert int(take.valid.sum()) == 420 and take.meta.extra["dropped_frames_inserted"] == 299
    (note,) = [r["message"] for r in take.meta.repairs if r["kind"] == "row_rate_change"]
    assert note.startswith("rows come at 30/s, not 60/s, from about 0.0 s")
