"""Face Cap's text export named directly and found by --pair-audio (capture/importer.py dispatch)."""

from __future__ import annotations

import json

import numpy as np
from conftest import run_cli
from test_generators_s29 import face_cap_txt, imported, refused, silence

from capture import read_take


def test_face_cap_text_named_directly_is_read_with_its_audio(tmp_path):
    """Was "not a Live Link Face CSV or take folder"."""
    weights = face_cap_txt(tmp_path / "fc.txt", 2)
    take = imported(tmp_path / "takes", tmp_path / "fc.txt", "--audio", silence(tmp_path / "a.wav", 2))
    assert take.meta.fps == 60 and take.values.shape == (120, 52)
    assert np.allclose(take.values, weights, atol=1e-6)


def test_face_cap_text_without_audio_says_it_needs_it(tmp_path):
    face_cap_txt(tmp_path / "fc.txt", 1)
    assert "a Face Cap text export needs its audio" in refused(tmp_path, tmp_path / "fc.txt")


def test_face_cap_text_in_a_folder_is_paired_with_its_audio(tmp_path):
    """Was: "no takes found" (the .txt was not looked at)."""
    src = tmp_path / "src"
    src.mkdir()
    face_cap_txt(src / "line01.txt", 1)
    silence(src / "line01.wav", 1)
    (src / "notes.txt").write_text("a note of the session, no Face Cap export\n")
    proc = run_cli("capture", "import", src, "--pair-audio", "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    paths = [json.loads(line)["path"] for line in proc.stdout.splitlines() if line.startswith("{")]
    assert len(paths) == 1 and read_take(paths[0]).values.shape == (60, 52)


def test_a_note_starting_with_bs_is_no_face_cap_export(tmp_path):
    """A notes file whose second line starts with ``bs,`` (and a list of names starting so) beside a take:
    passed over as before (was: read as a Face Cap export, and the run failed)."""
    src = tmp_path / "src"
    src.mkdir()
    face_cap_txt(src / "line01.txt", 1)
    silence(src / "line01.wav", 1)
    (src / "notes.txt").write_text("session notes\nbs, not really\n")
    (src / "names.txt").write_text("bs,eyeBlinkLeft,jawOpen\n")
    proc = run_cli("capture", "import", src, "--pair-audio", "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    paths = [json.loads(line)["path"] for line in proc.stdout.splitlines() if line.startswith("{")]
    assert len(paths) == 1
