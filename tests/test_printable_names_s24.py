"""A file name whose bytes are not UTF-8 shows them as ``\\xff`` in every command's error and warning
lines, as Python shows bytes, not as the surrogate escapes (``\\udcff``) Python holds them by."""

from __future__ import annotations

import os
from pathlib import Path

from conftest import run_cli

from capture.errors import InputError, printable

_ODD = b"caf\xe9 \xff"


def test_printable_shows_undecodable_bytes_and_leaves_other_text_alone():
    assert printable(os.fsdecode(_ODD + b".csv")) == "caf\\xe9 \\xff.csv"
    assert printable("café ✓ take.csv") == "café ✓ take.csv"
    assert str(InputError("no header", os.fsdecode(_ODD), 3)) == "caf\\xe9 \\xff:3: no header"


def test_an_error_naming_a_file_not_utf8_shows_its_bytes_escaped(tmp_path: Path):
    odd = Path(os.fsdecode(bytes(tmp_path) + b"/" + _ODD + b".csv"))
    odd.write_bytes(b"Timecode,BlendshapeCount\n")  # a header and no frame
    result = run_cli("capture", "import", str(odd), "-o", str(tmp_path / "out"))
    assert result.returncode == 1, result.stderr
    assert "caf\\xe9 \\xff.csv" in result.stderr, result.stderr
    assert "\\udc" not in result.stderr, result.stderr
