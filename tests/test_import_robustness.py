"""Bad input found by testing the importer and s2a-align end to end: every case gets a documented repair
or a one-line error, never a traceback or silently wrong data."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from capture import FrameStatus, InputError, read_livelink_csv, read_take, read_take_folder, write_take
from capture.audio_io import read_audio
from tests.conftest import run_here

T_ID = "20250106_SimSpk01_1"


@pytest.fixture(scope="module")
def sim_take(tmp_path_factory) -> Path:
    """A simulated Live Link Face take folder with .mov, .wav and the app's JSON files."""
    root = tmp_path_factory.mktemp("sim")
    run_here("capture", "simulate", "-o", root, "--seconds", 3, "--mov", "--sample-rate", 44100, check=True)
    (folder,) = [p for p in root.iterdir() if p.is_dir()]
    return folder


@pytest.fixture
def take_dir(sim_take, tmp_path) -> Path:
    return Path(shutil.copytree(sim_take, tmp_path / "T"))


def one_line_error(proc, fragment: str) -> None:
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "error:" in proc.stderr
    assert fragment in proc.stderr, proc.stderr


def repairs_of(take, kind: str) -> list[str]:
    return [r["message"] for r in take.meta.repairs if r["kind"] == kind]


def float_wav(folder: Path, bad: dict[int, float]) -> Path:
    """Replace the take's .mov by its WAV as float samples, with ``bad`` samples set."""
    for mov in folder.glob("*.mov"):
        mov.unlink()
    (wav,) = folder.glob("*.wav")
    data, rate = sf.read(wav, dtype="float32")
    for i, v in bad.items():
        data[i] = v
    sf.write(wav, data, rate, subtype="FLOAT")
    return wav


# 1, 2: the app's JSON files


@pytest.mark.parametrize(
    "name, text, field",
    [
        ("audio_metadata.json", '{"BitsPerChannel": "16", "SampleRate": "fast"}', "SampleRate"),
        ("audio_metadata.json", '{"SampleRate": [44100]}', "SampleRate"),
        ("audio_metadata.json", '{"SampleRate": true}', "SampleRate"),
        ("video_metadata.json", '{"FrameRate": "sixty"}', "FrameRate"),
        ("video_metadata.json", '{"FrameRate": {"num": 60}}', "FrameRate"),
        ("video_metadata.json", '{"FrameRate": -60}', "FrameRate"),
        ("take.json", '{"subject": ["a"], "identifier": 7, "take": true}', "subject"),
    ],
)
def test_bad_fields_in_app_json_are_ignored_with_a_repair(take_dir, tmp_path, name, text, field):
    (take_dir / name).write_text(text)
    take = read_take_folder(take_dir)
    messages = repairs_of(take, "bad_json")
    assert any(m.startswith(f"{name}: {field} ") for m in messages), messages
    assert take.audio.sample_rate == 44100 and take.meta.audio.start_source == "frame_log_audio"
    assert type(take.meta.take_number) is int  # a JSON true is not a take number (the file name's is used)
    proc = run_here("capture", "info", take_dir)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    "name, text, where",
    [
        ("take.json", '{"frames": NaN, "identifier": "x"}', "frames"),
        ("video_metadata.json", '{"FrameRate": Infinity}', "FrameRate"),
        ("audio_metadata.json", '{"SampleRate": 1e999, "x": [1, -Infinity]}', "SampleRate, x[1]"),
    ],
)
def test_non_finite_numbers_in_app_json_never_reach_the_writer(take_dir, tmp_path, name, text, where):
    (take_dir / name).write_text(text)
    proc = run_here("capture", "import", take_dir, "-o", tmp_path / "out")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    (out,) = (tmp_path / "out").iterdir()
    take = read_take(out)
    assert f"{name}: NaN or infinite number in {where}: set to null" in repairs_of(take, "bad_json")


# 3: non-finite audio samples


def test_non_finite_audio_samples_are_repaired_and_align_never_crashes(take_dir, tmp_path):
    float_wav(take_dir, {100: np.nan, 200: np.inf, 300: -np.inf})
    take = read_take_folder(take_dir)
    assert repairs_of(take, "bad_audio") == ["SimSpk01_1_spk01.wav: 3 NaN or infinite samples set to 0"]
    assert np.isfinite(take.audio.samples).all() and take.audio.samples[100, 0] == 0
    # A take written before this repair existed: s2a-align reports it in one line.
    folder = write_take(take, tmp_path / "raw")
    data, rate = sf.read(folder / "audio.wav", dtype="float32")
    data[5] = np.nan
    sf.write(folder / "audio.wav", data, rate, subtype="FLOAT")
    with pytest.raises(InputError, match="1 NaN or infinite sample"):
        read_take(folder)
    proc = run_here("align", tmp_path / "raw", "-o", tmp_path / "aligned", "--vad", "none")
    one_line_error(proc, "NaN or infinite sample")


# 4, 10: CSV cells


def test_csv_values_beyond_float32_and_underscores_are_bad_values(tmp_path, samples):
    lines = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_text().splitlines()
    for row, cell in ((3, "1e39"), (4, "-1e308"), (5, "1_0")):
        fields = lines[row].split(",")
        fields[20] = cell
        lines[row] = ",".join(fields)
    path = tmp_path / "big.csv"
    path.write_text("\n".join(lines) + "\n")
    proc = run_here("capture", "import", path, "-o", tmp_path / "out")
    assert proc.returncode == 0 and "RuntimeWarning" not in proc.stderr, proc.stderr
    take = read_take(tmp_path / "out" / "big")
    assert {r["line"]: r["kind"] for r in take.meta.repairs} == {
        4: "bad_value",
        5: "bad_value",
        6: "bad_value",
    }
    assert np.all(take.frame_status[2:5] == FrameStatus.BAD_VALUE)
    assert np.isfinite(take.values[take.valid]).all()


def test_all_rows_rejected_names_the_first_rejected_row(tmp_path, samples):
    header = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_text().splitlines()[0]
    path = tmp_path / "bad.csv"
    path.write_text(header + "\n1,2,3\n4,5\n")
    with pytest.raises(InputError, match="no usable data rows; the first: row has 3 fields") as exc:
        read_livelink_csv(path)
    assert exc.value.line == 2


# 5: forward clock jumps


def test_implausible_forward_gap_is_an_error_naming_the_line(tmp_path, samples):
    s07 = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_text()
    s88 = (samples / "livelinkface/alexdjulin_S88/S88-001.csv").read_text()
    joined = tmp_path / "joined.csv"
    joined.write_text(s07 + s88)  # `cat a.csv b.csv`: the second header names the line
    proc = run_here("capture", "import", joined, "-o", tmp_path / "out")
    one_line_error(proc, f"{joined}:2030: the header repeats here")
    assert not (tmp_path / "out" / "joined").exists()
    # without the second header, the 6-hour jump itself is refused
    joined.write_text(s07 + s88.split("\n", 1)[1])
    proc = run_here("capture", "import", joined, "-o", tmp_path / "out")
    one_line_error(proc, f"{joined}:2030: timecode ")
    assert "forward" in proc.stderr and not (tmp_path / "out" / "joined").exists()
    # the same take twice (no jump forward, the clock goes back): the header is what tells
    joined.write_text(s07 + s07)
    with pytest.raises(InputError, match="header repeats") as exc:
        read_livelink_csv(joined)
    assert exc.value.line == 2030
    # Rows shifted later by 13 minutes, on the fast path's kind of file (no other repair).
    lines = s07.splitlines()
    shifted = lines[:50] + [f"{ln[:3]}{int(ln[3:5]) + 13:02d}{ln[5:]}" for ln in lines[50:]]
    path = tmp_path / "shifted.csv"
    path.write_text("\n".join(shifted) + "\n")
    with pytest.raises(InputError, match="jumps 780 s forward") as exc:
        read_livelink_csv(path)
    assert exc.value.line == 51
    # Ordinary drops keep working: 10 missing seconds become dropped frames.
    gap = lines[:50] + [f"{ln[:6]}{(int(ln[6:8]) + 10) % 60:02d}{ln[8:]}" for ln in lines[50:60]]
    path.write_text("\n".join(gap) + "\n")
    take = read_livelink_csv(path)
    assert take.count(FrameStatus.DROPPED) == pytest.approx(10 * 30, abs=3)


# 6: take ids


def test_same_take_id_from_two_sources_is_never_overwritten(tmp_path, samples):
    src = samples / "livelinkface/alexdjulin_S07/S07-001.csv"
    for sub in ("a", "b", "c"):
        (tmp_path / "coll" / sub).mkdir(parents=True)
        shutil.copy(src, tmp_path / "coll" / sub / ("Take.csv" if sub == "c" else "take.csv"))
    proc = run_here("capture", "import", tmp_path / "coll", "-o", tmp_path / "out")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["Take-3", "take", "take-2"]
    assert proc.stderr.count("warning:") == 2
    assert repairs_of(read_take(tmp_path / "out" / "take-2"), "renamed_id")


def test_align_refuses_two_takes_with_one_id(take_dir, tmp_path):
    for sub in ("run1", "run2"):
        run_here("capture", "import", take_dir, "-o", tmp_path / "raw" / sub, check=True)
    proc = run_here("align", tmp_path / "raw", "-o", tmp_path / "aligned", "--vad", "none")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.count("error:") == 1 and "would overwrite each other" in proc.stderr
    out = read_take(tmp_path / "aligned" / T_ID)
    assert out.meta.extra["align"]["parent"]["path"] == str((tmp_path / "raw" / "run1" / T_ID).resolve())


# 7, 8: where a take folder's audio is


def test_upper_case_mov_is_found_and_a_take_without_audio_is_noted(take_dir):
    (take_dir / "SimSpk01_1_spk01.wav").unlink()
    (take_dir / "SimSpk01_1_spk01.mov").rename(take_dir / "X.MOV")
    take = read_take_folder(take_dir)
    assert take.audio is not None and take.meta.extra["reference_video"] == "X.MOV"
    (take_dir / "X.MOV").unlink()
    take = read_take_folder(take_dir)
    assert take.audio is None and repairs_of(take, "no_audio")


def test_truncated_wav_is_noted_with_both_durations(take_dir):
    wav = float_wav(take_dir, {})
    data = wav.read_bytes()
    wav.write_bytes(data[: len(data) // 2])
    take = read_take_folder(take_dir)
    (message,) = repairs_of(take, "truncated_audio")
    full = (len(data) - 100) / 4 / 44100
    assert f"header declares {full:.1f}" in message and f"holds {full / 2:.1f}" in message


def test_unfinished_wav_is_read_to_its_end(take_dir, tmp_path):
    """A recorder that crashed before it wrote the sizes leaves RIFF and data sizes at 0: libsndfile
    reads no samples; the samples after the header are used, with a repair that says so, and the
    strict reader (no repair list) names what it found."""
    wav = float_wav(take_dir, {})
    data, rate = sf.read(wav, dtype="float32")
    raw = bytearray(wav.read_bytes())
    at = raw.index(b"data")
    raw[4:8] = raw[at + 4 : at + 8] = bytes(4)
    wav.write_bytes(raw)
    take = read_take_folder(take_dir)
    (message,) = repairs_of(take, "unfinished_audio")
    assert f"the {data.shape[0] / rate:.3f} s of samples after it are used" in message
    np.testing.assert_array_equal(take.audio.samples[:, 0], data)
    with pytest.raises(InputError, match="declares no samples, but .* bytes follow it"):
        read_audio(wav)
    proc = run_here("capture", "import", take_dir, "-o", tmp_path / "out")
    assert proc.returncode == 0 and "unfinished_audio" not in proc.stderr and "did not finish" in proc.stderr


# 9: output paths


def test_output_path_errors_are_one_line(take_dir, tmp_path):
    csv = next(take_dir.glob("*.csv"))
    proc = run_here("capture", "import", take_dir, "-o", tmp_path / "out")
    take = tmp_path / "out" / T_ID
    proc = run_here("capture", "export-csv", take, "-o", tmp_path / "new" / "x" / "y.csv")
    assert proc.returncode == 0 and (tmp_path / "new" / "x" / "y.csv").is_file()
    one_line_error(run_here("capture", "export-csv", take, "-o", tmp_path), "is a folder")
    one_line_error(run_here("capture", "export-csv", csv, "-o", tmp_path / "x.csv"), "not a take folder")
    afile = tmp_path / "afile"
    afile.write_text("")
    one_line_error(run_here("capture", "export-csv", take, "-o", afile / "y.csv"), "output folder is a file")
    one_line_error(run_here("capture", "import", csv, "-o", afile), "output folder is a file")
    one_line_error(
        run_here("align", tmp_path / "out", "-o", afile, "--vad", "none"), "output folder is a file"
    )


# 10: the rest


def test_generic_import_refuses_a_non_finite_fps(tmp_path, sim_take):
    matrix = tmp_path / "m.npy"
    np.save(matrix, np.zeros((10, 2), np.float32))
    (tmp_path / "names.txt").write_text("a\nb\n")
    for fps in ("nan", "inf"):
        proc = run_here(
            "capture", "import", "--matrix", matrix, "--names", tmp_path / "names.txt", "--fps", fps,
            "--audio", next(sim_take.glob("*.wav")), "-o", tmp_path / "out",
        )  # fmt: skip
        one_line_error(proc, "--fps must be a positive frame rate")


def test_unknown_frame_status_in_a_take_is_refused(take_dir, tmp_path):
    folder = write_take(read_take_folder(take_dir), tmp_path / "out")
    with np.load(folder / "frames.npz") as z:
        arrays = dict(z)
    arrays["frame_status"][3] = 9
    np.savez(folder / "frames.npz", **arrays)
    with pytest.raises(InputError, match=r"unknown value\(s\) \[9\]"):
        read_take(folder)
    one_line_error(run_here("capture", "info", folder), "frame_status")


def test_meta_json_with_nan_is_a_one_line_error_not_a_traceback(take_dir, tmp_path):
    take = read_take_folder(take_dir)
    take.meta.extra["oops"] = float("nan")
    with pytest.raises(InputError, match="metadata cannot be written"):
        write_take(take, tmp_path / "out")
    assert not list((tmp_path / "out").iterdir())


def test_json_sidecar_keeps_meaning(take_dir):
    """The bad_json repair leaves the good fields of the same file in place."""
    (take_dir / "video_metadata.json").write_text(json.dumps({"FrameRate": "x", "Quality": "high"}))
    take = read_take_folder(take_dir)
    assert take.meta.extra["video_metadata"]["Quality"] == "high"


def test_header_only_csv_never_aborts_the_process(tmp_path, samples):
    """pyarrow reading a CSV with no rows could abort at exit (SIGABRT, apache/arrow#38676)."""
    header = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_text().splitlines()[0]
    path = tmp_path / "h.csv"
    path.write_text(header + "\n")
    for _ in range(6):
        one_line_error(run_here("capture", "import", path, "-o", tmp_path / "out"), "no data rows")


# align: options and hand-edited takes


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--max-offset-ms", "nan"),
        ("--min-segment-s", "inf"),
        ("--min-segment-s", "1e308"),
        ("--max-gap-ms", "nan"),
        ("--max-disagreement-ms", "inf"),
        ("--max-gap-ms", "-1"),
    ],
)
def test_align_option_out_of_range_names_the_option(take_dir, tmp_path, option, value):
    run_here("capture", "import", take_dir, "-o", tmp_path / "takes", check=True)
    proc = run_here("align", tmp_path / "takes", "-o", tmp_path / "al", option, value)
    # a usage error (exit 2): argparse's usage line, then the option named
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert (
        proc.stderr.strip()
        .splitlines()[-1]
        .startswith(f"s2a-align: error: argument {option}: must be between")
    )


@pytest.mark.parametrize("fps", [0, "NaN", None, "sixty", 1e9, -60])
def test_a_take_with_a_bad_fps_in_meta_json_fails_alone(take_dir, tmp_path, fps):
    takes = tmp_path / "takes"
    run_here("capture", "import", take_dir, "-o", takes, check=True)
    (good,) = list(takes.iterdir())
    bad = shutil.copytree(good, takes / "0000_bad")
    meta = json.loads((bad / "meta.json").read_text())
    meta["id"] = "0000_bad"
    meta["fps"] = float("nan") if fps == "NaN" else fps
    (bad / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="fps must be a frame rate"):
        read_take(bad)
    proc = run_here("align", takes, "-o", tmp_path / "al", "--vad", "none", "--json")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    reports = {r["id"]: r for r in map(json.loads, proc.stdout.splitlines())}
    assert "fps must be a frame rate" in reports["0000_bad"]["error"]
    assert "error" not in reports[good.name]  # the good take beside it is still aligned


def test_frame_times_that_are_not_float_seconds_are_refused(take_dir, tmp_path):
    run_here("capture", "import", take_dir, "-o", tmp_path / "takes", check=True)
    (folder,) = list((tmp_path / "takes").iterdir())
    with np.load(folder / "frames.npz") as z:
        arrays = dict(z)
    arrays["time"] = np.round(arrays["time"] * 1000).astype(np.int64)  # milliseconds
    np.savez(folder / "frames.npz", **arrays)
    with pytest.raises(InputError, match="not float seconds"):
        read_take(folder)


def test_content_confidence_rests_on_the_overlap_not_the_audio(tmp_path):
    """A face cut to its first 1.5 s against 20 s of audio: the content evidence rests on 1.5 s."""
    run_here("capture", "simulate", "-o", tmp_path / "sim", "--seconds", 20, "--seed", 2, check=True)
    run_here("capture", "import", tmp_path / "sim", "-o", tmp_path / "takes", check=True)
    (folder,) = list((tmp_path / "takes").iterdir())
    with np.load(folder / "frames.npz") as z:
        arrays = dict(z)
    keep = arrays["time"] - arrays["time"][0] <= 1.5
    np.savez(
        folder / "frames.npz", **{k: v[keep] if v.shape[:1] == keep.shape else v for k, v in arrays.items()}
    )
    proc = run_here("align", tmp_path / "takes", "-o", tmp_path / "al", "--vad", "none", "--json")
    (report,) = map(json.loads, proc.stdout.splitlines())
    # too weak to move the placement (below the minimum confidence): listed among the alternatives
    content = [a for a in report["alternatives"] if a["source"] == "content"]
    assert len(content) == 1 and content[0]["detail"]["seconds"] == pytest.approx(1.5, abs=0.1)
    assert content[0]["confidence"] < 0.3
    assert report["offset_confidence"] < 0.3 and "low_confidence" in report["flags"]


def test_align_output_into_an_input_folder_or_a_take_is_refused(take_dir, tmp_path):
    takes = tmp_path / "takes"
    run_here("capture", "import", take_dir, "-o", takes, check=True)
    (take,) = list(takes.iterdir())
    for out in (takes, take, take / "aligned"):
        proc = run_here("align", takes, "-o", out, "--vad", "none")
        one_line_error(proc, "the output folder is an input folder or inside a take")
    assert not (take / "aligned").exists()
    proc = run_here("align", takes, "-o", tmp_path / "al", "--vad", "none")
    assert proc.returncode == 0, proc.stderr


# 10: batches of paired data (--pair-audio)


def test_pair_audio_imports_a_batch_of_paired_data(samples, tmp_path):
    """NeuroSync's layout (a folder per take: audio.wav + CSV), Audio2Face exports beside their audio,
    a CSV without audio and one with ambiguous audio, and a Live Link Face take folder, in one run."""
    ns = samples / "paired" / "neurosync-trainer-lite-testset"
    root = tmp_path / "batch"
    for name in ("take_a", "take_b"):
        (root / "data" / name).mkdir(parents=True)
        shutil.copy(ns / "audio.wav", root / "data" / name / "audio.wav")
        shutil.copy(ns / "testset.csv", root / "data" / name / f"{name}.csv")
    a2f = root / "a2f"
    a2f.mkdir()
    sf.write(a2f / "line1.wav", np.zeros(16000, np.float32), 16000)
    names = ["jawOpen", "mouthClose", "mouthFunnel"]
    (a2f / "line1.json").write_text(
        json.dumps(
            {
                "exportFps": 30,
                "numFrames": 30,
                "numPoses": 3,
                "facsNames": names,
                "weightMat": [[0.1, 0.2, 0.3]] * 30,
            }
        )
    )
    (a2f / "notes.json").write_text('{"comment": "not an export"}')
    lone = root / "lone"
    lone.mkdir()
    shutil.copy(ns / "testset.csv", lone / "alone.csv")
    two = root / "two"
    two.mkdir()
    shutil.copy(ns / "testset.csv", two / "x.csv")
    for n in ("a.wav", "b.wav"):
        shutil.copy(ns / "audio.wav", two / n)
    proc = run_here(
        "capture",
        "import",
        root,
        "-o",
        tmp_path / "out",
        "--pair-audio",
        "--audio-pairing",
        "frame-index",
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    got = {Path(x["path"]).name: x for x in map(json.loads, proc.stdout.splitlines())}
    assert sorted(got) == ["alone", "line1", "take_a", "take_b", "x"]
    assert "two/x.csv: 2 audio files beside it and none named x.*: imported without audio" in proc.stderr
    for name in ("take_a", "take_b"):
        take = read_take(tmp_path / "out" / name)
        assert take.audio is not None and take.meta.audio.start_source == "paired_frame_convention"
    a2f_take = read_take(tmp_path / "out" / "line1")
    assert a2f_take.meta.fps == 30 and a2f_take.meta.channels == names and a2f_take.audio is not None
    assert (
        read_take(tmp_path / "out" / "alone").audio is None
        and read_take(tmp_path / "out" / "x").audio is None
    )


def test_a_batch_failing_alike_ends_with_one_line_that_says_so(tmp_path):
    """A batch whose files all fail for one reason (Audio2Face exports without their rate, imported without
    --fps) said it once per file and nothing more: 200 lines to read for one mistake. The errors stay, one
    per file, and a last line counts them with the reason most of them share."""
    for name in ("line1", "line2", "line3"):
        sf.write(tmp_path / f"{name}.wav", np.zeros(16000, np.float32), 16000)
        export = {"exportFps": None, "facsNames": ["jawOpen"], "weightMat": [[0.1]] * 30}
        (tmp_path / f"{name}.json").write_text(json.dumps(export))
    (tmp_path / "line4.json").write_text(json.dumps(export | {"exportFps": 30, "weightMat": [[0.1, 0.2]]}))
    sf.write(tmp_path / "line4.wav", np.zeros(16000, np.float32), 16000)
    proc = run_here("capture", "import", tmp_path, "-o", tmp_path / "out", "--pair-audio")
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and sum("error:" in line for line in lines) == 4, proc.stderr
    assert lines[-1] == "s2a-capture: 4 sources failed; 3 of them: no frame rate: give --fps", lines[-1]


def test_pair_audio_option_errors(tmp_path):
    (tmp_path / "a.csv").write_text("x")
    one_line_error(
        run_here(
            "capture", "import", tmp_path, "-o", tmp_path / "o", "--pair-audio", "--audio", tmp_path / "a.wav"
        ),
        "--pair-audio finds each source's audio",
    )
    a2f = tmp_path / "solo.json"
    a2f.write_text('{"exportFps": 30, "facsNames": ["jawOpen"], "weightMat": [[0.1]]}')
    proc = run_here("capture", "import", a2f, "-o", tmp_path / "o")
    one_line_error(proc, "blendshape weights in JSON need their audio")


def test_pair_audio_takes_generic_csvs_from_other_generators(samples, tmp_path):
    """A generator's own CSV (time column, its names) beside its audio, in the same batch as an app CSV."""
    ns = samples / "paired" / "neurosync-trainer-lite-testset"
    root = tmp_path / "gen"
    (root / "a").mkdir(parents=True)
    (root / "b").mkdir()
    shutil.copy(ns / "audio.wav", root / "a" / "audio.wav")
    rows = "".join(f"{i / 60:.6f},{0.5 + 0.4 * np.sin(i / 9):.4f},0.1\n" for i in range(1200))
    (root / "a" / "gen.csv").write_text("time,blendShapes.JawOpen,mouthClose\n" + rows)
    shutil.copy(ns / "audio.wav", root / "b" / "audio.wav")
    (root / "b" / "frames.csv").write_text("frame,jawOpen\n" + "".join(f"{i},0.2\n" for i in range(600)))
    proc = run_here("capture", "import", root, "-o", tmp_path / "out", "--pair-audio", "--json")
    assert proc.returncode == 1  # the frame-index CSV needs a rate; the other is imported
    assert "frames.csv: no frame rate: give --fps" in proc.stderr
    take = read_take(tmp_path / "out" / "gen")
    assert take.meta.fps == 60 and take.meta.channels == ["jawOpen", "mouthClose"] and take.audio is not None
    proc = run_here("capture", "import", root / "b", "-o", tmp_path / "out2", "--pair-audio", "--fps", "30")
    assert proc.returncode == 0, proc.stderr
    assert read_take(tmp_path / "out2" / "frames").meta.fps == 30
    one_line_error(
        run_here("capture", "import", root, "-o", tmp_path / "o3", "--fps", "30"), "--fps only applies"
    )
    app = tmp_path / "app"
    app.mkdir()
    shutil.copy(ns / "testset.csv", app / "t.csv")
    shutil.copy(ns / "audio.wav", app / "t.wav")
    proc = run_here("capture", "import", app, "-o", tmp_path / "o4", "--pair-audio", "--fps", "45")
    assert proc.returncode == 0, proc.stderr
    assert "t.csv: --fps ignored: a Live Link Face take has its own timecodes" in proc.stderr


def test_pair_audio_never_borrows_another_takes_audio_and_survives_link_loops(samples, tmp_path):
    ns = samples / "paired" / "neurosync-trainer-lite-testset"
    root = tmp_path / "n"
    (root / "sub").mkdir(parents=True)
    for name in ("take1", "take2"):
        shutil.copy(ns / "testset.csv", root / f"{name}.csv")
    shutil.copy(ns / "audio.wav", root / "take1.wav")
    (root / "sub" / "loop").symlink_to(root, target_is_directory=True)  # a folder that contains itself
    proc = run_here("capture", "import", root, "-o", tmp_path / "out", "--pair-audio", "--json")
    assert proc.returncode == 0, proc.stderr
    names = sorted(Path(json.loads(x)["path"]).name for x in proc.stdout.splitlines())
    assert names == ["take1", "take2"]  # each once, though the loop reaches them again and again
    assert "take2.csv: the only audio file beside it, take1.wav, is named for take1.csv" in proc.stderr
    assert read_take(tmp_path / "out" / "take1").audio is not None
    assert read_take(tmp_path / "out" / "take2").audio is None


def test_a_generic_csv_without_audio_says_what_it_needs(tmp_path):
    path = tmp_path / "gen.csv"
    path.write_text("time,jawOpen\n0,0.1\n0.0333,0.2\n")
    one_line_error(
        run_here("capture", "import", path, "-o", tmp_path / "o"),
        "as generic paired data it needs its audio (--audio, or --pair-audio)",
    )


def test_an_app_csv_with_a_leading_blank_line_is_judged_as_the_apps(samples, tmp_path):
    ns = samples / "paired" / "neurosync-trainer-lite-testset"
    csv = tmp_path / "blank.csv"
    csv.write_text("\n" + (ns / "testset.csv").read_text())
    proc = run_here("capture", "import", csv, "--audio", ns / "audio.wav", "-o", tmp_path / "o")
    one_line_error(proc, "not a Live Link Face CSV: the header must start with Timecode,BlendShapeCount")


def test_an_empty_csv_is_named_empty_with_or_without_audio(samples, tmp_path):
    empty = tmp_path / "take.csv"
    empty.write_text("\n \n")
    wav = next((samples / "speech").rglob("*.wav"))
    one_line_error(run_here("capture", "import", empty, "-o", tmp_path / "a"), "file is empty")
    one_line_error(
        run_here("capture", "import", empty, "--audio", wav, "-o", tmp_path / "b"), "file is empty"
    )
