"""A Google Drive download whose part was cut short (a download that stopped: the zip's start, no
directory at its end) is read as a part missing: the other parts import, a warning names the cut part
and the files it shows it held, and the take with files in it imports without those (said, never
silently). ``s2a-view`` given a member of a download's part reads the download as import does."""

from __future__ import annotations

from pathlib import Path

import test_driveparts_s25
from conftest import run_cli
from test_driveparts_s25 import TAKES, _download, _imported, _unpacked_left

from capture import read_take
from viewer.inputs import read_input

takes = test_driveparts_s25.takes  # the fixture: the folder uploaded to Drive, two take folders


def _cut(part: Path) -> Path:
    """``part`` as a download that stopped half way leaves it."""
    data = part.read_bytes()
    part.write_bytes(data[: len(data) // 2])
    return part


def test_a_part_cut_short_is_read_as_missing_and_said_with_its_files(takes, tmp_path):
    parts = _download(tmp_path / "Downloads", takes)
    _cut(parts[1])  # 002: S07-001's .mov
    out = tmp_path / "out"
    proc = run_cli("capture", "import", tmp_path / "Downloads", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    (said,) = [line for line in proc.stderr.splitlines() if "cut short" in line]
    assert "warning" in said and str(parts[1]) in said and "Takes/S07-001/S07-001.mov" in said, said
    found = _imported(out)
    assert sorted(found) == sorted(TAKES)
    assert read_take(found["S88-001"]).audio is not None  # its files are in 001 and 003
    assert read_take(found["S07-001"]).audio is None  # its .mov was in the cut part
    assert _unpacked_left(out) == []


def test_a_download_of_cut_parts_only_is_one_error(takes, tmp_path):
    parts = [_cut(p) for p in _download(tmp_path / "Downloads", takes, (1, 2))]
    out = tmp_path / "out"
    proc = run_cli("capture", "import", *parts, "-o", out)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and "not a readable zip archive" in proc.stderr, proc.stderr
    assert _imported(out) == {} and _unpacked_left(out) == []


def test_the_viewer_reads_a_member_of_a_part_as_the_download(takes, tmp_path):
    parts = _download(tmp_path / "Downloads", takes)
    take, _, speech = read_input(parts[0] / "Takes/S07-001", "one")
    assert take.audio is not None and len(take.time) > 100
    assert speech == parts[1] / "Takes/S07-001/S07-001.mov"
    csv_take, _, _ = read_input(parts[0] / "Takes/S88-001/S88-001.csv", "one")
    assert csv_take.audio is not None
