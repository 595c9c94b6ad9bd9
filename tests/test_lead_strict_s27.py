"""``s2a-capture import --strict`` refuses a Google Drive download with a part missing or cut, and a zip read
from its members' headers; without it they are imported with a warning."""

from __future__ import annotations

import test_driveparts_s25
from conftest import run_here
from test_driveparts_s25 import _download, _imported
from test_take_archives import zip_folder
from test_zipcut_s27 import _cut_in_directory

takes = test_driveparts_s25.takes  # the fixture: the folder uploaded to Drive, two take folders


def test_strict_import_refuses_a_download_with_a_part_missing(takes, tmp_path):
    parts = _download(tmp_path / "a", takes, numbers=(1, 3))  # 002 (S07-001's .mov) not downloaded
    proc = run_here("capture", "import", *parts, "-o", tmp_path / "lenient")
    assert proc.returncode == 0 and "002" in proc.stderr and "warning" in proc.stderr, proc.stderr
    assert sorted(_imported(tmp_path / "lenient")) == ["S07-001", "S88-001"]
    proc = run_here("capture", "import", "--strict", *parts, "-o", tmp_path / "strict")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    (error,) = [line for line in proc.stderr.splitlines() if "error" in line]
    assert "002" in error and "--strict refuses" in error, error
    assert _imported(tmp_path / "strict") == {}


def test_strict_import_refuses_a_zip_read_from_its_headers(sim_take, tmp_path):
    cut = _cut_in_directory(zip_folder(sim_take, tmp_path / "take.zip"))
    proc = run_here("capture", "import", "--strict", cut, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "--strict refuses" in proc.stderr and _imported(tmp_path / "out") == {}, proc.stderr
