"""Review of the --pair-audio mends (capture/importer.py ``audio_beside``): an audio file named for a
Face Cap text export beside a CSV is the export's, not the CSV's (the export became a source of the same
import), in a folder and in an archive the viewer unpacks part of; the folder's names read once per
listing, not once per CSV beside them."""

from __future__ import annotations

import os
import time
import zipfile

from conftest import run_cli, run_here
from test_generators_s29 import face_cap_txt, silence
from test_mends_s29 import _folder_of_csvs

from capture.importer import audio_beside
from capture.take_folder import listed_once
from viewer.inputs import archives_unpacked, unpacked_input


def test_audio_named_for_a_face_cap_export_is_not_a_csvs_only_audio(samples, tmp_path):
    """a.csv beside fc.txt (Face Cap) and fc.wav: a.csv took fc.wav as "the only audio file beside it"
    while fc.txt was imported with it too: two takes of one speech."""
    src = _folder_of_csvs(samples, tmp_path, ["a.csv"], [])
    face_cap_txt(src / "fc.txt", 1)
    silence(src / "fc.wav", 1)
    proc = run_here("capture", "import", src, "-o", tmp_path / "out", "--pair-audio")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert {p.parent.name for p in (tmp_path / "out").glob("*/audio.wav")} == {"fc"}, proc.stderr
    assert "a.csv: the only audio file beside it, fc.wav, is named for fc.txt: imported without audio" in (
        proc.stderr
    )


def test_a_csv_read_alone_in_an_archive_has_the_face_cap_export_its_audio_is_named_for(tmp_path):
    """The viewer unpacks of an archive what ``audio_beside`` looks at for a CSV read alone (a neutral
    pose): fc.txt was left packed, and the CSV was shown with fc.wav, the Face Cap export's speech."""
    face_cap_txt(tmp_path / "fc.txt", 1)
    archive = tmp_path / "day.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("S/T_neutral.csv", "Timecode,BlendShapeCount\n")
        zf.write(tmp_path / "fc.txt", "S/fc.txt")
        zf.write(silence(tmp_path / "fc.wav", 1), "S/fc.wav")
    with archives_unpacked():
        target, _ = unpacked_input(archive / "S" / "T_neutral.csv")
        assert (target.parent / "fc.txt").is_file()
        assert audio_beside(target) == (None, "the only audio file beside it, fc.wav, is named for fc.txt")


def test_many_csvs_beside_their_audio_are_paired_in_time_linear_in_their_number(tmp_path):
    """Each CSV looked at every file beside it again (its stem in NFC, the other CSVs): 1,000 CSVs
    beside their audio took 2.3 s of CPU, 3,000 took 45 s; now 0.06 s. The bound is CPU time
    (not the wall clock of a busy machine), far above it."""
    for i in range(3000):
        (tmp_path / f"take{i:04d}.csv").write_text("x")
        (tmp_path / f"TAKE{i:04d}.wav").write_bytes(b"RIFF")
    csvs = sorted(tmp_path.glob("*.csv"))
    start = time.process_time()
    with listed_once():
        paired = [audio_beside(c) for c in csvs]
    assert time.process_time() - start < 4.0
    assert all(audio == c.with_name(c.stem.upper() + ".wav") for (audio, _why), c in zip(paired, csvs))


def test_a_named_pipe_named_txt_in_a_folder_is_not_read(samples, tmp_path):
    """A .txt is read to see whether it is a Face Cap export: a named pipe ``notes.txt`` beside the CSVs
    held the import for ever (it waited for a writer); the take beside it was never imported."""
    src = _folder_of_csvs(samples, tmp_path, ["x.csv"], ["x.wav"])
    os.mkfifo(src / "notes.txt")
    proc = run_cli("capture", "import", src, "-o", tmp_path / "out", "--pair-audio")  # 300 s at most
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert (tmp_path / "out" / "x" / "audio.wav").is_file()
