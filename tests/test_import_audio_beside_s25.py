"""A Live Link Face CSV imported on its own with its recording beside it (``S07-001.wav``) was imported
without audio and nothing said so: the take then failed in align ("has no audio"). The import names the
file and the option that pairs it."""

from __future__ import annotations

import shutil

import numpy as np
import soundfile as sf
from conftest import run_cli


def _csv_with_audio_beside(samples, tmp_path, audio_name: str):
    src = tmp_path / "src"
    src.mkdir()
    shutil.copy(samples / "livelinkface" / "alexdjulin_S07" / "S07-001.csv", src / "S07-001.csv")
    sf.write(src / audio_name, np.zeros(16000, np.int16), 16000)
    return src / "S07-001.csv"


def test_a_csv_imported_without_the_audio_beside_it_says_so(samples, tmp_path):
    csv = _csv_with_audio_beside(samples, tmp_path, "S07-001.wav")
    proc = run_cli("capture", "import", csv, "-o", tmp_path / "out", check=True)
    assert "S07-001.wav beside it is not used: add --pair-audio to import it with its audio" in proc.stderr
    paired = run_cli("capture", "import", csv, "-o", tmp_path / "paired", "--pair-audio", check=True)
    assert "beside it is not used" not in paired.stderr
    assert (tmp_path / "paired" / "S07-001" / "audio.wav").is_file()


def test_audio_named_for_another_csv_is_not_offered(samples, tmp_path):
    csv = _csv_with_audio_beside(samples, tmp_path, "S07-001.wav")
    (csv.parent / "other.csv").write_text("x")
    (csv.parent / "S07-001.wav").rename(csv.parent / "other.wav")
    proc = run_cli("capture", "import", csv, "-o", tmp_path / "out", check=True)
    assert "beside it is not used" not in proc.stderr
