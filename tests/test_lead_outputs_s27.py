"""Outputs in the way: ``export-csv -o`` a file of the take being exported (its audio was replaced by the
CSV, exit 0), and an output folder that is a dangling symbolic link (said "File exists")."""

from __future__ import annotations

import os

from conftest import run_here


def test_export_csv_never_writes_over_a_file_of_its_take(sim_take, tmp_path):
    run_here("capture", "import", sim_take, "-o", tmp_path, check=True)
    (take,) = [p for p in tmp_path.iterdir() if (p / "meta.json").is_file()]
    audio = take / "audio.wav"
    before = audio.read_bytes()
    proc = run_here("capture", "export-csv", take, "-o", audio)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "is a file of the take" in proc.stderr and "give -o outside any take" in proc.stderr, proc.stderr
    assert audio.read_bytes() == before
    run_here("capture", "import", sim_take, "-o", tmp_path / "other", check=True)
    (other,) = [p for p in (tmp_path / "other").iterdir() if (p / "meta.json").is_file()]
    proc = run_here("capture", "export-csv", other, "-o", audio)  # another take's file
    assert proc.returncode == 1 and "give -o outside any take" in proc.stderr, proc.stderr
    assert audio.read_bytes() == before


def test_an_output_folder_that_is_a_dangling_link_is_said_so(sim_take, tmp_path):
    out = tmp_path / "takes"
    os.symlink(tmp_path / "gone", out)
    proc = run_here("capture", "import", sim_take, "-o", out)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    said = proc.stderr.strip().splitlines()[-1]
    assert "a symbolic link to" in said and "which does not exist, is in the way" in said, said
    assert os.path.islink(out) and not (tmp_path / "gone").exists()
