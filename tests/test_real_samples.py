"""Every real sample in ../shared/samples imports with the right frames, rate, drops and face-lost rows."""

import json

import numpy as np
import pytest

from capture import FrameStatus, read_livelink_csv, read_paired, read_take, write_livelink_csv, write_take
from capture.take_folder import read_csv_with_audio
from tests.conftest import run_cli

LLF = {
    # file: (rows in file, nominal fps, dropped rows, face-lost rows)
    "livelinkface/alexdjulin_S07/S07-001.csv": (2028, 30.0, 2, 0),
    "livelinkface/alexdjulin_S88/S88-001.csv": (1939, 30.0, 3, 277),
    "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv": (1848, 60.0, 0, 0),
    "paired/neurosync-trainer-lite-testset/testset.csv": (1218, 60.0, 0, 0),
}

FACEGOOD = {
    "1114_2_01": 3295,
    "1114_2_02": 3360,
    "1114_2_03": 3356,
    "1114_2_04": 3377,
    "1114_2_05": 3384,
    "1114_3_15": 1472,
    "1114_3_16": 1429,
}


@pytest.mark.parametrize("name", sorted(LLF))
def test_livelink_csv_sample(samples, name):
    rows, fps, dropped, lost = LLF[name]
    take = read_livelink_csv(samples / name)
    s = take.summary()
    assert s["fps"] == fps
    assert s["frames"] == rows + dropped  # dropped rows become placeholder frames
    assert s["dropped_frames"] == dropped
    assert s["face_lost_frames"] == lost
    assert s["valid_frames"] == rows - lost
    assert s["channels"] == 61 and s["repairs"] == 0
    assert np.all(np.diff(take.time) > 0)
    assert np.isnan(take.values[~take.valid]).all()
    assert np.isfinite(take.values[take.valid]).all()
    # Times come from the timecode: the measured row rate is the app's 29.97 / 59.90, not 30 / 60.
    tracked = take.time[take.frame_status != FrameStatus.DROPPED]
    rate = (tracked.size - 1) / (tracked[-1] - tracked[0])
    assert rate == pytest.approx(fps * 0.9984, rel=2e-3)
    assert take.meta.sources[0].sha256 and take.meta.sources[0].bytes == (samples / name).stat().st_size


@pytest.mark.parametrize("name", sorted(LLF))
def test_csv_round_trips_byte_for_byte(samples, tmp_path, name):
    take = read_livelink_csv(samples / name)
    folder = write_take(take, tmp_path / "takes")
    out = write_livelink_csv(read_take(folder), tmp_path / "out.csv")
    assert out.read_bytes() == (samples / name).read_bytes()


def test_values_are_never_clamped(samples):
    take = read_livelink_csv(samples / "paired/neurosync-trainer-lite-testset/testset.csv")
    assert take.channel("headRoll")[take.valid].min() < 0  # signed angles stay signed
    assert take.channel("leftEyeYaw")[take.valid].min() < -0.5


def test_header_spellings_and_calibrated_variant(samples):
    old = read_livelink_csv(samples / "livelinkface/alexdjulin_S07/S07-001.csv")
    new = read_livelink_csv(samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv")
    assert old.meta.csv["count_name"] == "BlendShapeCount"
    assert new.meta.csv["count_name"] == "BlendshapeCount"
    assert new.meta.csv["variant"] == "cal"
    assert (new.meta.slate, new.meta.take_number, new.meta.subject) == ("MySlate", 166, "iPhone")


def test_neurosync_pairs_a_44k_wav_with_1218_frames(samples):
    d = samples / "paired/neurosync-trainer-lite-testset"
    take = read_csv_with_audio(d / "testset.csv", d / "audio.wav")
    assert take.time.size == 1218
    assert take.audio.sample_rate == 44100 and take.audio.frames == 898560
    assert take.audio.samples.dtype == np.int16
    assert take.meta.audio.start_s == 0.0


@pytest.mark.parametrize("take_name", sorted(FACEGOOD))
def test_facegood_takes_import(samples, tmp_path, take_name):
    d = samples / "paired/facegood-audio2face"
    take = read_paired(
        d / "wav" / f"{take_name}.wav",
        d / "bs_value" / f"bs_value_{take_name}.npy",
        30,
        d / "bs_names.txt",
    )
    assert take.values.shape == (FACEGOOD[take_name], 116)
    assert take.meta.channels[0] == "brow_lower_l"
    assert take.audio.sample_rate == 16000
    assert abs(take.audio.duration_s - FACEGOOD[take_name] / 30) < 1 / 30 + 0.03
    back = read_take(write_take(take, tmp_path))
    assert np.array_equal(back.values, take.values)
    assert np.array_equal(back.audio.samples, take.audio.samples)


def test_facegood_names_from_npy(samples):
    d = samples / "paired/facegood-audio2face"
    a = read_paired(d / "wav/1114_3_16.wav", d / "bs_value/bs_value_1114_3_16.npy", 30, d / "bs_names.txt")
    b = read_paired(
        d / "wav/1114_3_16.wav", d / "bs_value/bs_value_1114_3_16.npy", 30, d / "shirley_1015_bs_name.npy"
    )
    assert a.meta.channels == b.meta.channels


def test_cli_imports_every_sample_and_reports_info(samples, tmp_path):
    out = tmp_path / "takes"
    proc = run_cli("capture", "import", samples / "livelinkface", "-o", out, "--json", check=True)
    lines = [json.loads(x) for x in proc.stdout.splitlines()]
    assert sorted(x["id"] for x in lines) == ["MySlate_166_iPhone_cal", "S07-001", "S88-001"]
    d = samples / "paired/neurosync-trainer-lite-testset"
    run_cli("capture", "import", d / "testset.csv", "--audio", d / "audio.wav", "-o", out, check=True)
    fg = samples / "paired/facegood-audio2face"
    run_cli(
        "capture",
        "import",
        "--matrix",
        fg / "bs_value/bs_value_1114_3_16.npy",
        "--audio",
        fg / "wav/1114_3_16.wav",
        "--names",
        fg / "bs_names.txt",
        "--fps",
        "30",
        "-o",
        out,
        check=True,
    )
    info = run_cli("capture", "info", out, "--json", check=True)
    by_id = {x["id"]: x for x in map(json.loads, info.stdout.splitlines())}
    for key in ("id", "frames", "fps", "duration_s", "dropped_frames", "face_lost_frames", "channels"):
        assert key in by_id["S88-001"]
    assert by_id["S88-001"]["face_lost_frames"] == 277
    assert by_id["S07-001"]["dropped_frames"] == 2
    assert by_id["testset"]["audio_sample_rate"] == 44100 and by_id["testset"]["frames"] == 1218
    facegood = by_id["bs_value_1114_3_16"]  # a --matrix take is named after its matrix file
    assert facegood["frames"] == 1429 and facegood["channels"] == 116
    exported = tmp_path / "S07.csv"
    run_cli("capture", "export-csv", out / "S07-001", "-o", exported, check=True)
    assert exported.read_bytes() == (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_bytes()


def test_interpolated_frames_are_written_with_their_values(samples, tmp_path):
    """Frames s2a-align filled across short gaps are usable: the CSV keeps their values (Epic's importer
    would stop at a face-lost row), while face-lost frames stay ``<timecode>,0`` rows."""
    take = read_livelink_csv(samples / "paired/neurosync-trainer-lite-testset/testset.csv")
    filled = np.arange(100, 110)
    take.frame_status[filled] = FrameStatus.INTERPOLATED
    take.frame_status[200] = FrameStatus.FACE_LOST
    back = read_livelink_csv(write_livelink_csv(take, tmp_path / "out.csv"))
    assert (back.frame_status[filled] == FrameStatus.TRACKED).all()
    assert np.allclose(back.values[filled], take.values[filled], atol=1e-9)
    assert back.frame_status[200] == FrameStatus.FACE_LOST and np.isnan(back.values[200]).all()
