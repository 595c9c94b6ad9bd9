"""Leftovers mended: a figure printed beside the bound it passed reads on its side of it (predict's dBFS
levels next to -70 dBFS, the build's damaged audio peak next to 1000 times full scale); the importer's
pairing of a CSV with the audio beside it on edge inputs."""

from __future__ import annotations

import json
import shutil

import numpy as np
import soundfile as sf
from conftest import run_here
from dataset_helpers import make_aligned_take
from test_audio_adversity import ridge_run  # noqa: F401 (a fixture)

from align.resample import to_16k_mono
from capture import Audio, write_take
from train.predict import predict

# -- a figure beside its bound ---------------------------------------------------------------------

JUST_UNDER_SILENCE = 10 ** (-70.04 / 20)  # -70.04 dBFS: .1f read -70.0, "under -70 dBFS"


def test_predict_names_a_peak_just_under_silence_as_under_it(ridge_run, tmp_path, capsys):  # noqa: F811
    """A peak of -70.04 dBFS was said as "peak -70.0 dBFS, under -70 dBFS", and its JSON peak_dbfs
    was -70.0 beside ``silent: true``."""
    tone = np.sin(2 * np.pi * 500 * np.arange(32000) / 16000)
    # scaled so that its peak once predict has high-passed it (as to_16k_mono does) is -70.04 dBFS
    peak = np.abs(to_16k_mono(Audio(tone.astype(np.float32)[:, None], 16000, "FLOAT"))).max()
    quiet = (tone * (JUST_UNDER_SILENCE / peak)).astype(np.float32)
    sf.write(tmp_path / "quiet.wav", quiet, 16000, subtype="FLOAT")
    (result,) = predict(ridge_run / "run", [tmp_path / "quiet.wav"], tmp_path / "o", say=lambda _m: None)
    assert result["silent"] and result["peak_dbfs"] == -70.04
    assert "quiet.wav: the audio is silent (peak -70.04 dBFS, under -70 dBFS)" in capsys.readouterr().err


def test_predict_names_an_offset_just_under_silence_as_the_peak(ridge_run, tmp_path, capsys):  # noqa: F811
    """A constant offset of -70.04 dBFS and nothing else: the offset is under -70 dBFS, said as the
    peak; it was rounded to -70.0 first, found not under -70, and said as an offset "of -70.0 dBFS"
    removed."""
    sf.write(tmp_path / "dc.wav", np.full(32000, JUST_UNDER_SILENCE, np.float32), 16000, subtype="FLOAT")
    proc = run_here(
        "train", "predict", ridge_run / "run", tmp_path / "dc.wav", "-o", tmp_path / "o", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.splitlines()[-1])
    assert result["silent"] and result["peak_dbfs"] is None and result["dc_offset_dbfs"] == -70.04
    assert "dc.wav: the audio is silent (peak -70.04 dBFS, under -70 dBFS)" in proc.stderr, proc.stderr


def test_predict_levels_away_from_the_bound_keep_one_decimal(ridge_run, tmp_path, capsys):  # noqa: F811
    sf.write(tmp_path / "dc.wav", np.full(32000, 0.5, np.float32), 16000, subtype="FLOAT")
    (result,) = predict(ridge_run / "run", [tmp_path / "dc.wav"], tmp_path / "o", say=lambda _m: None)
    assert result["dc_offset_dbfs"] == -6.0
    assert "dc.wav: the audio is silent once its constant offset of -6.0 dBFS is removed" in (
        capsys.readouterr().err
    )


def test_build_names_a_damaged_peak_just_past_its_bound_as_past_it(tmp_path):
    """A sample of 1000.5 (over the 1000 times full scale refused) was said as "a sample of 1e+03"."""
    take = make_aligned_take("spike", 2.0, subject="a", seed=1)
    take.audio.samples[1000, 0] = 1000.5
    write_take(take, tmp_path / "takes")
    proc = run_here("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds")
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "audio holds a sample of 1000.5 at 0.062 s, over 1000 times full scale" in proc.stderr, proc.stderr


def test_build_names_a_peak_far_past_its_bound_in_three_figures(tmp_path):
    take = make_aligned_take("spike", 2.0, subject="a", seed=1)
    take.audio.samples[1000, 0] = 1e30
    write_take(take, tmp_path / "takes")
    proc = run_here("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds")
    assert "audio holds a sample of 1e+30 at 0.062 s, over 1000 times full scale" in proc.stderr, proc.stderr


# -- the audio beside a CSV (s2a-capture import --pair-audio) -------------------------------------


def _folder_of_csvs(samples, tmp_path, csvs: list[str], audio: list[str]):
    """A folder of copies of a real Live Link Face CSV named ``csvs`` and 1 s WAVs named ``audio``."""
    src = tmp_path / "src"
    src.mkdir()
    for name in csvs:
        shutil.copy(samples / "livelinkface" / "alexdjulin_S07" / "S07-001.csv", src / name)
    for name in audio:
        sf.write(src / name, np.zeros(16000, np.int16), 16000)
    return src


def _imported(src, tmp_path):
    """``s2a-capture import SRC --pair-audio``: (its stderr, the take ids written with audio)."""
    proc = run_here("capture", "import", src, "-o", tmp_path / "out", "--pair-audio")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    with_audio = {p.parent.name for p in (tmp_path / "out").glob("*/audio.wav")}
    return proc.stderr, with_audio


def test_audio_named_for_a_csv_in_another_case_is_not_another_csvs(samples, tmp_path):
    """b.wav is B.csv's (a copy changed the case of one name): a.csv took it as "the only audio file
    beside it", and the take a was imported with B's speech."""
    src = _folder_of_csvs(samples, tmp_path, ["a.csv", "B.csv"], ["b.wav"])
    err, with_audio = _imported(src, tmp_path)
    assert with_audio == {"B"}, err
    assert "a.csv: the only audio file beside it, b.wav, is named for B.csv: imported without audio" in err


def test_audio_of_the_same_stem_in_another_case_is_the_csvs(samples, tmp_path):
    """Take1.csv beside take1.wav and other.wav: none was taken ("2 audio files beside it and none
    named Take1.*"), as the take folder reader takes a CSV named after its take in another case."""
    src = _folder_of_csvs(samples, tmp_path, ["Take1.csv"], ["take1.wav", "other.wav"])
    err, with_audio = _imported(src, tmp_path)
    assert with_audio == {"Take1"} and "without audio" not in err, err


def test_audio_of_the_same_stem_that_is_a_link_to_nothing_is_no_licence_for_another(samples, tmp_path):
    """x.wav, a symbolic link to a file not there (a drive not mounted), was passed over, and y.wav, the
    only audio file left, was imported as x's speech."""
    src = _folder_of_csvs(samples, tmp_path, ["x.csv"], ["y.wav"])
    (src / "x.wav").symlink_to(tmp_path / "elsewhere" / "x.wav")
    err, with_audio = _imported(src, tmp_path)
    assert with_audio == set(), err
    assert "x.csv: x.wav beside it is no file (a symbolic link to nothing, or a folder)" in err


def test_a_hidden_audio_file_is_not_the_only_audio_beside_a_csv(samples, tmp_path):
    """.y.wav (a program's temporary file) was taken as the only audio file beside x.csv."""
    src = _folder_of_csvs(samples, tmp_path, ["x.csv"], [".y.wav"])
    err, with_audio = _imported(src, tmp_path)
    assert with_audio == set(), err
    assert "x.csv: the only audio file beside it, .y.wav, is hidden (a program's temporary file?)" in err
