"""A list of names in a JSON line (align's ``outputs``) keeps the bytes of a name that is not UTF-8, as a
single name does under ``<key>_b64``: ``strict_names`` wrote it as ``caf\\xe9\\xff`` only, its bytes lost
(a consumer could not find the aligned take folder)."""

from __future__ import annotations

import base64
import os
from pathlib import Path

from test_jsonstrict_s25 import SHOWN, _lines, _odd

from capture.command import named
from capture.errors import strict_names


def test_a_list_of_names_keeps_the_bytes_of_one_not_utf8_beside_it():
    odd = os.fsdecode(b"/tmp/caf\xe9\xff")
    record = strict_names({"outputs": ["/tmp/plain", odd], "counts": [1, 2], "notes": ["a\\xff", "b"]})
    assert record["outputs"] == ["/tmp/plain", f"/tmp/{SHOWN}"]
    assert record["outputs_b64"] == [None, base64.b64encode(b"/tmp/caf\xe9\xff").decode("ascii")]
    assert "counts_b64" not in record and "notes_b64" not in record  # UTF-8 text (a backslash) as it is
    assert named(record, "outputs") == ["/tmp/plain", odd] and named(record, "notes") == ["a\\xff", "b"]


def test_align_names_its_output_folders_not_utf8_with_their_bytes(tmp_path):
    folder = _odd(tmp_path)
    folder.mkdir()
    _lines("capture", "simulate", "-o", folder / "sim", "--seconds", 2)
    _lines("capture", "import", folder / "sim", "-o", folder / "takes")
    (record,) = _lines("align", folder / "takes", "-o", folder / "aligned", "--vad", "none")
    (shown,) = record["outputs"]
    assert shown.startswith(f"{tmp_path}/{SHOWN}/aligned/")
    (raw,) = record["outputs_b64"]
    aligned = Path(os.fsdecode(base64.b64decode(raw)))
    assert aligned.parent == folder / "aligned" and (aligned / "meta.json").is_file()
