"""Import problems a probe found with inputs the other tests had not seen: CSVs whose timecode frames
count at the take's own rate, takes of one id from different sources, NTSC rates, and external audio
of the wrong length. Real files in tmp_path, real command lines."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from test_import_robustness import one_line_error, repairs_of

from capture import FrameStatus, Timecode, read_livelink_csv, read_paired, read_take
from capture.channels import CSV_ORDER
from tests.conftest import run_here

HEADER = "Timecode,BlendshapeCount," + ",".join(CSV_ORDER)
START_S = 10 * 3600.0  # 10:00:00:00


def livelink_csv(path: Path, timecodes: list[str]) -> Path:
    """A Live Link Face CSV with one tracked row per timecode (values that vary from row to row)."""
    rows = [HEADER]
    for i, tc in enumerate(timecodes):
        rows.append(f"{tc},61," + ",".join([f"{(i % 50) / 100:.10f}"] * 61))
    path.write_text("\n".join(rows) + "\n")
    return path


def counted_at(rate: int, frames: int, keep=None) -> list[str]:
    """Timecodes of ``frames`` rows from 10:00:00:00 with FF counted at ``rate`` (as other writers of the
    format do), leaving out the rows where ``keep`` is False."""
    return [f"10:00:{i // rate:02d}:{i % rate:02d}.000" for i in range(frames) if keep is None or keep[i]]


def wav(path: Path, seconds: float, rate: int = 16000) -> Path:
    t = np.arange(int(seconds * rate)) / rate
    sf.write(path, (0.1 * np.sin(2 * np.pi * 220 * t)).astype(np.float32), rate, subtype="PCM_16")
    return path


def imported(proc) -> dict:
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    return json.loads(proc.stdout)


# 1: timecode frames counted at the take's own rate, not the app's 60


@pytest.mark.parametrize("rate", [24, 25, 30, 50])
def test_timecode_frames_counted_at_the_takes_rate_are_read_at_it(tmp_path, rate):
    csv = livelink_csv(tmp_path / f"tc{rate}.csv", counted_at(rate, 4 * rate))
    proc = run_here("capture", "import", csv, "-o", tmp_path / "out", "--json")
    summary = imported(proc)
    assert summary["fps"] == rate and summary["frames"] == 4 * rate and summary["dropped_frames"] == 0
    assert summary["duration_s"] == pytest.approx(4.0)
    take = read_take(summary["path"])
    np.testing.assert_allclose(take.time, np.arange(4 * rate) / rate, atol=1e-9)
    (message,) = repairs_of(take, "timecode_rate")
    assert f"count at {rate} fps, not the app's 60" in message and take.meta.csv["timecode_rate"] == rate
    assert "warning:" in proc.stderr and f"count at {rate} fps" in proc.stderr


def test_three_seconds_at_30_are_90_frames_not_150_with_60_dropped(tmp_path):
    """The probe's example: FF 0..29 at 30 rows/s used to become 150 frames at 60 fps, 60 dropped."""
    take = read_livelink_csv(livelink_csv(tmp_path / "tc30.csv", counted_at(30, 90)))
    assert take.meta.fps == 30 and take.time.size == 90 and take.duration_s == pytest.approx(3.0)
    assert len(repairs_of(take, "timecode_rate")) == 1


def test_rows_missing_from_a_30_fps_timecode_become_dropped_frames(tmp_path):
    keep = np.random.default_rng(1).random(300) > 0.15
    keep[29::30][::2] = False  # the last row of every other second too
    keep[[0, -1]] = True
    take = read_livelink_csv(livelink_csv(tmp_path / "gaps.csv", counted_at(30, 300, keep)))
    assert take.meta.fps == 30 and take.time.size == 300
    assert take.count(FrameStatus.DROPPED) == int((~keep).sum())
    np.testing.assert_allclose(take.time, np.arange(300) / 30, atol=1e-9)


def test_timecode_rate_can_be_given(tmp_path):
    csv = livelink_csv(tmp_path / "tc30.csv", counted_at(30, 300))
    as_app = imported(
        run_here("capture", "import", csv, "-o", tmp_path / "a", "--json", "--timecode-rate", 60)
    )
    assert as_app["fps"] == 60 and as_app["repairs"] == 0  # the app's reading, as asked
    # --strict makes no guess: the detected rate is refused, a given one is read
    one_line_error(
        run_here("capture", "import", csv, "-o", tmp_path / "s", "--strict"),
        "count at 30 fps, not the app's 60",
    )
    strict = run_here(
        "capture", "import", csv, "-o", tmp_path / "t", "--json", "--strict", "--timecode-rate", 30
    )
    assert imported(strict)["fps"] == 30
    one_line_error(
        run_here("capture", "import", csv, "-o", tmp_path / "b", "--timecode-rate", 25),
        "timecode frames (FF) reach 29.000: they do not count at 25 fps",
    )
    # under two whole seconds FF cannot tell its rate: auto keeps the app's 60, the option reads it at 30
    short = livelink_csv(tmp_path / "short.csv", counted_at(30, 45))
    assert imported(run_here("capture", "import", short, "-o", tmp_path / "c", "--json"))["fps"] == 60
    given = imported(
        run_here("capture", "import", short, "-o", tmp_path / "d", "--json", "--timecode-rate", 30)
    )
    assert given["fps"] == 30 and given["frames"] == 45
    one_line_error(
        run_here(
            "capture",
            "import",
            "--matrix",
            csv,
            "--audio",
            wav(tmp_path / "a.wav", 1),
            "-o",
            tmp_path / "e",
            "--timecode-rate",
            30,
        ),  # fmt: skip
        "--timecode-rate applies to Live Link Face CSVs",
    )


def test_real_samples_keep_the_apps_60_fps_timecode(samples):
    """Every real CSV (30 and 60 rows/s, drops, face-lost rows) reads as before: FF at 60."""
    csvs = []
    for p in sorted(samples.rglob("*.csv")):
        with p.open() as f:  # closed: no file left to the collector
            if p.name != "frame_log.csv" and "Timecode" in f.readline():
                csvs.append(p)
    assert len(csvs) >= 4
    for path in csvs:
        auto, app = read_livelink_csv(path), read_livelink_csv(path, timecode_rate=60)
        assert not repairs_of(auto, "timecode_rate") and auto.meta.csv["timecode_rate"] == 60
        assert np.array_equal(auto.time, app.time) and auto.meta.fps == app.meta.fps in (30, 60)
        assert np.array_equal(auto.values, app.values, equal_nan=True)


# 2: take ids that meet in the output folder


def test_matrix_imports_are_named_after_the_matrix_and_never_replace_another_source(tmp_path):
    audio = wav(tmp_path / "audio.wav", 2)
    names = tmp_path / "names.txt"
    names.write_text("jawOpen\nmouthClose\n")
    out = tmp_path / "t2"

    def matrix_import(stem: str, fps: int, *extra) -> dict:
        np.save(tmp_path / f"{stem}.npy", np.random.default_rng(fps).random((2 * fps, 2)))
        return imported(
            run_here(
                "capture",
                "import",
                "--matrix",
                tmp_path / f"{stem}.npy",
                "--names",
                names,
                "--fps",
                fps,
                "--audio",
                audio,
                "-o",
                out,
                "--json",
                *extra,
            )  # fmt: skip
        )

    assert matrix_import("m24", 24)["id"] == "m24" and matrix_import("m120", 120)["id"] == "m120"
    assert read_take(out / "m24").meta.fps == 24 and read_take(out / "m120").meta.fps == 120
    # one --id for two sources: the second is renamed, as within one run; re-importing replaces
    assert matrix_import("m24", 24, "--id", "same")["path"] == str(out / "same")
    second = matrix_import("m120", 120, "--id", "same")
    assert second["path"] == str(out / "same-2")
    assert "taken in" in repairs_of(read_take(out / "same-2"), "renamed_id")[0]
    assert matrix_import("m24", 24, "--id", "same")["path"] == str(out / "same")
    assert matrix_import("m120", 120, "--id", "same")["path"] == str(out / "same-2")
    assert sorted(p.name for p in out.iterdir()) == ["m120", "m24", "same", "same-2"]
    assert read_take(out / "same").meta.fps == 24 and read_take(out / "same-2").meta.fps == 120


def test_an_earlier_import_of_another_csv_or_a_folder_of_the_user_is_not_replaced(tmp_path):
    out = tmp_path / "out"
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
    a = livelink_csv(tmp_path / "a/take.csv", counted_at(60, 60))
    b = livelink_csv(tmp_path / "b/take.csv", counted_at(60, 90))
    for src, path in ((a, "take"), (b, "take-2"), (a, "take"), (b, "take-2")):
        proc = run_here("capture", "import", src, "-o", out, "--json")
        assert imported(proc)["path"] == str(out / path)
    assert read_take(out / "take").time.size == 60 and read_take(out / "take-2").time.size == 90
    mine = out / "notes"
    mine.mkdir()
    (mine / "todo.txt").write_text("keep me")
    proc = run_here("capture", "import", a, "-o", out, "--json", "--id", "notes")
    assert imported(proc)["path"] == str(out / "notes-2") and "is not a take" in proc.stderr
    assert (mine / "todo.txt").read_text() == "keep me"


# 3: NTSC rates


@pytest.mark.parametrize("nominal", [24, 30, 60])
def test_a_time_column_at_an_ntsc_rate_keeps_it(tmp_path, nominal):
    rate = nominal * 1000 / 1001
    matrix = tmp_path / "m.csv"
    rows = [f"{i / rate:.6f},{(i % 7) / 10}" for i in range(20 * nominal)]
    matrix.write_text("time,jawOpen\n" + "\n".join(rows) + "\n")
    take = read_paired(wav(tmp_path / "a.wav", 20.1), matrix, None)
    assert take.meta.fps == pytest.approx(rate, rel=1e-9)
    matrix.write_text("time,jawOpen\n" + "\n".join(f"{i / nominal:.6f},0.1" for i in range(20 * nominal)))
    assert read_paired(tmp_path / "a.wav", matrix, None).meta.fps == nominal


def test_a_livelink_csv_at_59_94_rows_per_second_is_a_60_fps_take(tmp_path):
    """The phone's rates are 30 and 60 (never NTSC): rows at 59.94/s are a "60" take, as the app's own
    59.90/s are, so that takes from one session never end up at two rates."""
    tcs = [Timecode.from_seconds(START_S + i * 1001 / 60000).format() for i in range(600)]
    take = read_livelink_csv(livelink_csv(tmp_path / "ntsc.csv", tcs))
    assert take.meta.fps == 60.0 and take.count(FrameStatus.DROPPED) == 0


# 4: external audio of the wrong length


@pytest.mark.parametrize("pairing", ["first-row", "frame-index"])
def test_csv_with_audio_of_the_wrong_length_is_noted_as_for_a_matrix(tmp_path, pairing):
    csv = livelink_csv(tmp_path / "take.csv", counted_at(60, 300))  # 5 s
    short = wav(tmp_path / "short.wav", 0.1)
    proc = run_here(
        "capture", "import", csv, "--audio", short, "--audio-pairing", pairing, "-o", tmp_path / "o", "--json"
    )
    (note,) = repairs_of(read_take(imported(proc)["path"]), "length_mismatch")
    np.save(tmp_path / "m.npy", np.zeros((300, 1)))
    (tmp_path / "n.txt").write_text("jawOpen\n")
    (same,) = repairs_of(read_paired(short, tmp_path / "m.npy", 60, tmp_path / "n.txt"), "length_mismatch")
    pattern = r"audio is 4\.900 s shorter than the frames: "
    assert re.match(pattern, note) and re.match(pattern, same), (note, same)
    fits = run_here(
        "capture", "import", csv, "--audio", wav(tmp_path / "fits.wav", 5.5), "-o", tmp_path / "p", "--json"
    )
    assert not repairs_of(read_take(imported(fits)["path"]), "length_mismatch")
