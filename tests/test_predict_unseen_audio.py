"""``s2a-train predict`` on audio it has not seen: rates, channel counts, sample formats and damage in
one batch (each file its own CSV in the Live Link Face format, with the frame count of its length; a bad
file reported and the others written), an output CSV that is the audio file itself (refused, the audio
kept), and silence made of a sub-audible constant offset (said as quiet, not as an offset to remove).
The command line runs in-process (``train.cli.main``) on a tiny ridge run."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import SAMPLES
from dataset_helpers import build_five_take_dataset
from test_train_pipeline import TINY

from train.cli import main
from train.config import resolve_config
from train.fit import fit

# the header the app writes (a take recorded with it)
APP_CSV = SAMPLES / "livelinkface" / "alexdjulin_S07" / "S07-001.csv"


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A ridge run (solved in closed form: seconds) on five 2 s takes."""
    root = tmp_path_factory.mktemp("unseen")
    ds = build_five_take_dataset(root)
    fit(ds, root / "run", resolve_config(sets=TINY + ["model='ridge'"]), say=lambda _m: None)
    return root / "run"


def _cli(capsys, *args) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in args])
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def _voice(rate: int, seconds: float) -> np.ndarray:
    t = np.arange(int(round(rate * seconds))) / rate
    return 0.3 * np.sin(2 * np.pi * 180 * t) * (0.5 + 0.5 * np.sin(2 * np.pi * 4 * t))


def _frames(path: Path) -> tuple[list[str], int]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], len(rows) - 1


def test_a_batch_of_unseen_audio_kinds_writes_each_csv_and_reports_the_bad_one(run, tmp_path, capsys):
    audio = tmp_path / "audio"
    audio.mkdir()
    sf.write(audio / "phone.wav", _voice(8000, 0.5), 8000)  # narrowband, 8 kHz
    sf.write(audio / "studio.wav", np.tile(_voice(96000, 0.3)[:, None], (1, 2)), 96000, subtype="PCM_24")
    sf.write(audio / "surround.flac", np.tile(_voice(44100, 1.0)[:, None], (1, 6)), 44100)
    nan = _voice(22050, 0.5).astype(np.float32)
    nan[100:200] = np.nan  # repaired to 0, as s2a-capture import repairs it
    sf.write(audio / "nan.wav", nan, 22050, subtype="FLOAT")
    whole = audio / "short.wav"
    sf.write(whole, _voice(16000, 1.0), 16000)
    (audio / "cut.wav").write_bytes(whole.read_bytes()[:30])  # a truncated header
    whole.write_bytes(whole.read_bytes()[: 44 + 2 * 4800])  # header says 1 s, 0.3 s present
    app_header = _frames(APP_CSV)[0]
    expected = {"phone": 30, "studio": 18, "surround": 60, "nan": 30, "short": 18}

    code, out, err = _cli(capsys, "predict", run, *sorted(audio.iterdir()), "-o", tmp_path / "csv")
    assert code != 0 and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("s2a-train: error: 1 of 6 audio files failed")
    assert "cut.wav" in err and "truncated_audio" in err and "bad_audio" in err
    for stem, frames in expected.items():
        header, rows = _frames(tmp_path / "csv" / f"{stem}.csv")
        assert header == app_header and rows == frames, stem
    assert not (tmp_path / "csv" / "cut.csv").exists()


def test_an_output_csv_that_is_the_audio_itself_is_refused_and_the_audio_kept(run, tmp_path, capsys):
    voice = tmp_path / "voice.csv"  # an audio file whatever its name says
    sf.write(voice, _voice(16000, 0.3), 16000, format="WAV")
    kept = voice.read_bytes()
    for out in (voice, tmp_path):  # the CSV itself, or the folder that would receive voice.csv
        code, _out, err = _cli(capsys, "predict", run, voice, "-o", out)
        assert code != 0 and "Traceback" not in err and len(err.strip().splitlines()) == 1
        assert "is the audio file" in err
        assert voice.read_bytes() == kept


def test_silence_of_a_sub_audible_offset_is_said_as_quiet(run, tmp_path, capsys):
    sf.write(tmp_path / "tiny.wav", np.full(4800, 1e-30, np.float32), 16000, subtype="FLOAT")
    code, _out, err = _cli(capsys, "predict", run, tmp_path / "tiny.wav", "-o", tmp_path / "tiny.csv")
    assert code == 0
    assert "the audio is silent (peak" in err and "offset" not in err
    assert _frames(tmp_path / "tiny.csv")[1] == 18
