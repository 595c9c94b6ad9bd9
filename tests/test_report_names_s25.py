"""``s2a-view report`` of a folder of takes whose name is not UTF-8 (another system's encoding): the page
names it, and writing it as UTF-8 was a traceback (UnicodeEncodeError), the page lost. It names it as
messages do (``caf\\xe9\\xff``)."""

from __future__ import annotations

import os
from pathlib import Path

from conftest import run_cli


def test_a_report_of_a_folder_named_not_utf8_is_written(tmp_path):
    folder = Path(os.fsdecode(bytes(tmp_path) + b"/caf\xe9\xff"))
    run_cli("capture", "simulate", "-o", folder / "sim", "--seconds", 2, check=True)
    run_cli("capture", "import", folder / "sim", "-o", folder / "takes", check=True)
    proc = run_cli("viewer", "report", folder / "takes", "-o", tmp_path / "report.html")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "caf\\xe9\\xff" in (tmp_path / "report.html").read_text(encoding="utf-8")
