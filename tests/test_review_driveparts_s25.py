"""Review of the Google Drive parts import: a part's number is any run of digits, so a hostile or
mistaken name (``-99999.zip``) must not make the missing-parts warning list every number between."""

from __future__ import annotations

import resource
import subprocess
import sys
import zipfile
from pathlib import Path

from conftest import ROOT, run_cli

STEM = "Takes-20250301T101500Z"


def test_a_huge_part_number_says_the_missing_parts_as_one_run(samples: Path, tmp_path):
    csv = (samples / "livelinkface" / "alexdjulin_S07" / "S07-001.csv").read_text().splitlines(True)
    downloads = tmp_path / "Downloads"
    downloads.mkdir()
    with zipfile.ZipFile(downloads / f"{STEM}-001.zip", "w") as z:
        z.writestr("Takes/S07-001/S07-001.csv", "".join(csv[:121]))
    with zipfile.ZipFile(downloads / f"{STEM}-99999.zip", "w") as z:
        z.writestr("Takes/notes.txt", "the last part")
    out = tmp_path / "out"
    # one string per number missing: a line of 100000 numbers (of -999999999.zip: out of memory)
    proc = run_cli("capture", "import", downloads, "-o", out)
    assert proc.returncode == 0, proc.stderr
    (said,) = [line for line in proc.stderr.splitlines() if "Google Drive" in line]
    assert "parts 002-99998 of" in said and len(said) < 400, said[:300]
    assert (out / "S07-001" / "meta.json").is_file()


def test_a_download_of_hundreds_of_parts_imports_under_a_low_limit_of_open_files(samples: Path, tmp_path):
    csv = (samples / "livelinkface" / "alexdjulin_S07" / "S07-001.csv").read_text().splitlines(True)
    downloads = tmp_path / "Downloads"
    downloads.mkdir()
    for number in range(1, 301):  # a take's CSV in the first part, its notes in the last, files between
        with zipfile.ZipFile(downloads / f"{STEM}-{number:03d}.zip", "w") as z:
            if number == 1:
                z.writestr("Takes/S07-001/S07-001.csv", "".join(csv[:121]))
            else:
                z.writestr(f"Takes/S07-001/notes-{number}.txt", "notes")
    out = tmp_path / "out"

    def macos_limit() -> None:  # a Mac's default limit of open files: every part held open passed it
        resource.setrlimit(resource.RLIMIT_NOFILE, (256, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))

    proc = subprocess.run(
        [sys.executable, "-m", "capture", "import", str(downloads), "-o", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
        preexec_fn=macos_limit,
    )
    assert proc.returncode == 0, proc.stderr[-600:]
    assert (out / "S07-001" / "meta.json").is_file()
    # messages name the download by its first and last parts, not by 300 names on one line
    (unpacked,) = [line for line in proc.stderr.splitlines() if "unpacked" in line]
    assert unpacked == f"{downloads / STEM}-001.zip + ... + {STEM}-300.zip (300 parts): 1 source unpacked"


def test_info_of_a_part_alone_holding_no_take_says_it_is_one_part(tmp_path):
    part = tmp_path / f"{STEM}-002.zip"
    with zipfile.ZipFile(part, "w") as z:  # the part holding the .mov files only
        z.writestr("Takes/S07-001/S07-001.mov", b"\0\0\0\x18ftypqt  ")
    for command in (["info", part], ["import", part, "-o", tmp_path / "out"]):
        proc = run_cli("capture", *command)
        assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
        assert "one part of a Google Drive download: give it with its other parts" in proc.stderr
