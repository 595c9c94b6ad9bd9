"""Audio that misleads the pipeline: an isolated damaged float sample, NaN samples given to predict, a
take folder's ``.mov`` without audio or with a silent first track, silent audio given to predict, and
the same speech recorded at another level (speech-level normalisation of the features)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here
from dataset_helpers import SR, make_aligned_take, speech_like

from capture import Audio, InputError, read_audio, read_take_folder, write_reference_mov, write_take
from capture.take_folder import read_csv_with_audio
from dataset import BuildOptions, build_dataset, read_manifest
from dataset.features import FeatureSettings, compute_features
from dataset.shards import ShardReader, decode_flac
from dataset.splits import SplitRule
from train.config import resolve_config
from train.fit import fit
from train.predict import feature_settings, predict

QUIET = {"say": lambda _m: None}
CSV = "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"  # 30.8 s, 60 fps


def _voice(rate: int, seconds: float, seed: int = 0) -> np.ndarray:
    """Speech-like float audio at ``rate`` Hz (the dataset helper's syllables), peak 1."""
    x, _env = speech_like(seconds, np.random.default_rng(seed))
    if rate != SR:
        import soxr

        x = soxr.resample(x, SR, rate, quality="VHQ")
    return (x / np.abs(x).max()).astype(np.float32)


def _repairs(take, kind):
    return [r["message"] for r in take.meta.repairs if r["kind"] == kind]


# ------------------------------------------------------------------------------------ damaged samples


def test_an_isolated_damaged_float_sample_is_repaired_on_import_and_loud_float_is_not(tmp_path, samples):
    speech = 0.5 * _voice(48000, 31.0)  # -6 dBFS
    spiked = speech.copy()
    spiked[200_000] = 1500.0  # one damaged sample: 1500 times full scale
    sf.write(tmp_path / "spike.wav", spiked, 48000, subtype="FLOAT")
    take = read_csv_with_audio(samples / CSV, tmp_path / "spike.wav")
    [note] = _repairs(take, "bad_audio")
    assert note.startswith("spike.wav: 1 isolated sample(s) up to 1.5e+03") and "interpolation" in note
    x = take.audio.samples[:, 0]
    assert np.abs(x).max() <= 0.5 + 1e-6 and abs(x[200_000]) <= max(abs(x[199_999]), abs(x[200_001])) + 1e-6
    np.testing.assert_array_equal(np.delete(x, 200_000), np.delete(speech, 200_000))

    # a genuinely loud float take (peak 3 throughout) is not damaged: read as it is, no note
    sf.write(tmp_path / "loud.wav", 6.0 * speech, 48000, subtype="FLOAT")
    repairs: list = []
    loud = read_audio(tmp_path / "loud.wav", repairs)
    assert repairs == [] and np.array_equal(loud.samples[:, 0], 6.0 * speech)
    # NaN samples keep their repair, and both notes can come together
    both = spiked.copy()
    both[1000:1003] = np.nan
    sf.write(tmp_path / "both.wav", both, 48000, subtype="FLOAT")
    repairs = []
    read_audio(tmp_path / "both.wav", repairs)
    assert [r["message"].split(":")[1].split(" sample")[0].strip() for r in repairs] == [
        "3 NaN or infinite",
        "1 isolated",
    ]
    # the real samples (16-bit, and as float scaled to a peak of 3 or 100, with silence around) hold none
    from capture.audio_io import damaged_samples

    for wav in sorted(samples.rglob("*.wav")):
        repairs = []
        y = read_audio(wav, repairs).mono_float()
        assert repairs == [], wav
        for peak in (3.0, 100.0):
            z = np.concatenate(
                [np.zeros(SR, np.float32), y * (peak / np.abs(y).max()), np.zeros(SR, np.float32)]
            )
            assert damaged_samples(z).size == 0, (wav, peak)


def test_a_stray_sample_does_not_set_the_builds_audio_gain(tmp_path):
    """An aligned take written before the import repaired damage: one sample of 1500 at 48 kHz became a
    ringing burst peaking at ~400 in the 16 kHz audio. It used to scale the whole take by 1/400."""
    import soxr

    takes = tmp_path / "takes"
    for i in range(3):
        take = make_aligned_take(f"t{i}", 3.0, subject="a", seed=i)
        if i == 0:
            x48 = soxr.resample(take.audio.samples[:, 0], SR, 48000, quality="VHQ")
            x48[70_000] = 1500.0
            take.audio = None
            take.attach_audio(
                Audio(soxr.resample(x48, 48000, SR, quality="VHQ"), SR, "FLOAT"), 0.0, "aligned"
            )
            assert 100 < np.abs(take.audio.samples).max() < 1000
        write_take(take, takes)
    options = BuildOptions(split=SplitRule("take", 0.1, 0.1, 0, ("t1",), ("t2",)), max_sample_s=30.0)
    summary = build_dataset([takes], tmp_path / "ds", options, **QUIET)
    warnings = " | ".join(summary["warnings"])
    assert "take t0: a burst past full scale over 10 times the take's level" in warnings
    m = read_manifest(tmp_path / "ds")
    shard = next(s["shard"] for s in m["samples"] if s["take"] == "t0")
    [(_key, members)] = list(ShardReader(tmp_path / "ds" / shard))
    meta = json.loads(members["json"])
    audio, _ = decode_flac(members["flac"])
    assert meta["audio_gain"] == 1.0 and np.abs(audio).max() <= 1.0
    clean = make_aligned_take("t0", 3.0, subject="a", seed=0).audio.samples[:, 0]
    assert np.sqrt(np.mean(audio**2)) == pytest.approx(np.sqrt(np.mean(clean**2)), rel=0.05)


# ------------------------------------------------------------------------------------ take folder .mov


def _write_mov(path: Path, tracks: list[np.ndarray], rate: int) -> Path:
    """An app-like .mov (MJPEG video with a timecode) holding one 16-bit audio stream per track."""
    audio = [
        Audio((np.clip(np.rint(x * 32767), -32768, 32767)).astype(np.int16)[:, None], rate, "PCM_16")
        for x in tracks
    ]
    return write_reference_mov(path, 60.0, 10, audio, timecode="19:18:11:20", size=(64, 48))


def _folder(root: Path, samples: Path, name: str) -> Path:
    folder = root / name
    folder.mkdir(parents=True)
    shutil.copy(samples / CSV, folder / "MySlate_166_iPhone_cal.csv")
    return folder


def test_a_mov_without_audio_uses_the_wav_beside_it_or_imports_without_audio(tmp_path, samples):
    voice = 0.3 * _voice(48000, 31.0)
    with_wav = _folder(tmp_path, samples, "with_wav")
    write_reference_mov(with_wav / "MySlate_166_iPhone.mov", 60.0, 10, audio=None, timecode="19:18:11:20")
    sf.write(with_wav / "MySlate_166_iPhone.wav", voice, 48000, subtype="PCM_16")
    take = read_take_folder(with_wav)
    assert take.audio is not None and take.audio.sample_rate == 48000 and take.audio.frames == voice.size
    assert _repairs(take, "audio_track") == [
        "MySlate_166_iPhone.mov holds no audio track: the audio is MySlate_166_iPhone.wav beside it"
    ]
    assert take.meta.audio.start_source == "mov_timecode" and abs(take.meta.audio.start_s) < 0.05
    assert {s.role for s in take.meta.sources} >= {"reference_video", "audio"}

    bare = _folder(tmp_path, samples, "bare")
    write_reference_mov(bare / "MySlate_166_iPhone.mov", 60.0, 10, audio=None, timecode="19:18:11:20")
    proc = run_here("capture", "import", bare, "-o", tmp_path / "out", "--json")
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((tmp_path / "out" / "bare" / "meta.json").read_text())
    assert meta["audio"] is None
    assert [r["message"] for r in meta["repairs"] if r["kind"] == "no_audio"] == [
        "take folder has no .wav, and MySlate_166_iPhone.mov holds no audio track: imported without audio"
    ]


def test_a_mov_whose_first_audio_track_is_silent_uses_the_track_with_sound(tmp_path, samples):
    voice = 0.3 * _voice(48000, 31.0)
    folder = _folder(tmp_path, samples, "two_tracks")
    _write_mov(folder / "MySlate_166_iPhone.mov", [np.zeros_like(voice), voice], 48000)
    take = read_take_folder(folder)
    assert np.abs(take.audio.samples).max() > 0.25 * 32767
    [note] = _repairs(take, "audio_track")
    assert note.startswith("MySlate_166_iPhone.mov holds 2 audio tracks (1: silent (all zero), 2: peak -10.")
    assert note.endswith("track 2 is used (the first that is not silent)")
    assert take.meta.extra["mov_audio_track"]["track"] == 2
    assert take.meta.extra["mov_audio_track"]["tracks"] == 2
    # one track with sound first: it is used, and the other is still named
    folder = _folder(tmp_path, samples, "first_loud")
    _write_mov(folder / "MySlate_166_iPhone.mov", [voice, 0.5 * voice], 48000)
    take = read_take_folder(folder)
    [note] = _repairs(take, "audio_track")
    assert "2: peak -16." in note and note.endswith("track 1 is used (the first, which carries sound)")


# ------------------------------------------------------------------------------------ predict


@pytest.fixture(scope="module")
def ridge_run(tmp_path_factory):
    """A ridge run on a small dataset built with the default speech-level normalisation."""
    root = tmp_path_factory.mktemp("adversity")
    for i in range(4):
        write_take(make_aligned_take(f"take{i}", 3.0, subject=f"spk{i % 2}", seed=i), root / "takes")
    options = BuildOptions(split=SplitRule("take", 0.1, 0.1, 0, ("take2",), ("take3",)), max_sample_s=30.0)
    build_dataset([root / "takes"], root / "ds", options, **QUIET)
    fit(root / "ds", root / "run", resolve_config(sets=["model=ridge"]), **QUIET)
    return root


def test_predict_repairs_nan_samples_and_warns_about_silent_audio(ridge_run, tmp_path, capsys):
    voice = 0.3 * _voice(16000, 2.0)
    voice[5000:5011] = np.nan
    sf.write(tmp_path / "nan.wav", voice, 16000, subtype="FLOAT")
    sf.write(tmp_path / "silent.wav", np.zeros(32000, np.float32), 16000, subtype="FLOAT")
    sf.write(tmp_path / "dc.wav", np.full(32000, 0.5, np.float32), 16000, subtype="FLOAT")
    said: list[str] = []
    audio = [tmp_path / "nan.wav", tmp_path / "silent.wav", tmp_path / "dc.wav"]
    nan, silent, dc = predict(ridge_run / "run", audio, tmp_path / "o", say=said.append)
    assert "error" not in nan and nan["repairs"] == [
        {"kind": "bad_audio", "message": "nan.wav: 11 NaN or infinite samples set to 0"}
    ]
    assert not nan["silent"] and nan["speech_level_dbfs"] is not None
    assert silent["silent"] and silent["peak_dbfs"] is None and silent["repairs"] == []
    text = capsys.readouterr().err  # the warnings, on stderr
    assert "s2a: warning: " in text and "nan.wav: 11 NaN or infinite samples set to 0 (bad_audio" in text
    assert "silent.wav: the audio is silent (all zero): no speech to animate, the face stays still" in text
    # a constant offset is no sound either, but not "all zero"
    assert dc["silent"] and dc["peak_dbfs"] is None and dc["dc_offset_dbfs"] == -6.0
    assert "dc.wav: the audio is silent once its constant offset of -6.0 dBFS is removed: no speech" in text
    # the command line exits 0 with the repair in its JSON
    proc = run_here(
        "train", "predict", ridge_run / "run", tmp_path / "nan.wav", "-o", tmp_path / "x.csv", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["repairs"][0]["kind"] == "bad_audio" and "bad_audio" in proc.stderr


# ------------------------------------------------------------------------------------ speech level


def test_speech_level_normalisation_makes_features_and_predictions_independent_of_the_gain(
    ridge_run, tmp_path
):
    from dataset.features import parse_level, speech_level

    x, _env = speech_like(4.0, np.random.default_rng(7))
    level = speech_level(x, SR)
    assert speech_level(x * 10 ** (-30 / 20), SR) == pytest.approx(level - 30, abs=0.01)
    assert speech_level(np.zeros(SR), SR) is None
    on = FeatureSettings(level=parse_level("speech"))
    off = FeatureSettings()
    names = ("energy", "fbank")
    a, _ = compute_features(x, 240, 60.0, names, on)
    b, _ = compute_features(x * np.float32(0.02), 240, 60.0, names, on)
    c, _ = compute_features(x * np.float32(0.02), 240, 60.0, names, off)
    np.testing.assert_allclose(a["fbank"], b["fbank"], atol=1e-3)
    assert np.abs(a["energy"] - c["energy"]).mean() > 1.0  # without it the level is in every frame

    # the build records the setting; a manifest without it (older datasets) means none
    m = read_manifest(ridge_run / "ds")
    assert m["features"]["settings"]["level"] == "speech -26 dBFS"
    legacy = dict(m["features"])
    legacy["settings"] = {k: v for k, v in m["features"]["settings"].items() if k != "level"}
    assert feature_settings(legacy).level == "none"

    # predict applies it: the same speech 30 dB quieter animates the same
    speech = 0.5 * _voice(16000, 3.0, seed=5)
    sf.write(tmp_path / "loud.wav", speech, 16000, subtype="FLOAT")
    sf.write(tmp_path / "quiet.wav", speech * 10 ** (-30 / 20), 16000, subtype="FLOAT")
    predict(ridge_run / "run", [tmp_path / "loud.wav", tmp_path / "quiet.wav"], tmp_path / "p", **QUIET)
    loud, quiet = (
        np.loadtxt(tmp_path / "p" / f"{n}.csv", delimiter=",", skiprows=1, usecols=range(2, 63))
        for n in ("loud", "quiet")
    )
    assert np.abs(loud - quiet).max() < 1e-3 and np.abs(loud).max() > 0.01


def test_level_option_of_the_build(tmp_path):
    for i in range(3):
        write_take(make_aligned_take(f"t{i}", 2.0, subject="a", seed=i), tmp_path / "takes")
    common = ["dataset", "build", tmp_path / "takes", "--val", "t1", "--test", "t2", "--json"]
    proc = run_here(*common, "-o", tmp_path / "none", "--level", "none")
    assert proc.returncode == 0, proc.stderr
    assert read_manifest(tmp_path / "none")["features"]["settings"]["level"] == "none"
    proc = run_here(*common, "-o", tmp_path / "db", "--level", "-23")
    assert proc.returncode == 0, proc.stderr
    m = read_manifest(tmp_path / "db")
    assert m["features"]["settings"]["level"] == "speech -23 dBFS"
    [(_key, members)] = list(ShardReader(tmp_path / "db" / m["samples"][0]["shard"]))
    assert json.loads(members["json"])["level_gain"] > 0
    proc = run_here(*common, "-o", tmp_path / "bad", "--level", "loud")
    assert proc.returncode == 1 and "--level must be speech, none or a target in dBFS" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_flac_cut_short_keeps_the_samples_it_holds(tmp_path):
    """libsndfile stops a FLAC cut short with "lost sync" (it was one error: the recording lost); as a WAV
    cut short, the samples present are read, bit for bit (FLAC is lossless), the packet cut through as
    silence, and noted; without a repair list it is still an error."""
    rng = np.random.default_rng(0)
    speech = (rng.standard_normal((32000, 1)) * 3000).astype(np.int16)
    sf.write(tmp_path / "whole.flac", speech, 16000, subtype="PCM_16", format="FLAC")
    data = (tmp_path / "whole.flac").read_bytes()
    (tmp_path / "cut.flac").write_bytes(data[: len(data) // 2])
    repairs: list[dict] = []
    audio = read_audio(tmp_path / "cut.flac", repairs)
    assert audio.subtype == "PCM_16" and audio.sample_rate == 16000
    kept = int(np.flatnonzero(audio.samples[:, 0])[-1]) + 1  # the FLAC blocks wholly in the first half
    assert kept >= 8192 and np.array_equal(audio.samples[:kept], speech[:kept])
    assert kept < audio.frames <= 20000 and not audio.samples[kept:].any()  # the block cut through: silence
    (note,) = [r["message"] for r in repairs if r["kind"] == "truncated_audio"]
    assert "header declares 2.000 s" in note and "cut short" in note
    with pytest.raises(InputError, match="audio is unreadable"):
        read_audio(tmp_path / "cut.flac")
