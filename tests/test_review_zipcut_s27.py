"""Zips damaged in ways zipfile refuses with other exceptions than ``BadZipFile`` (a version in the directory
no zip has, flag bit 5 "patched data", LZMA bytes that do not decode): one error line naming the member or
the archive, or, when only the directory is damaged, the members read from their own headers; never a
traceback."""

from __future__ import annotations

import zipfile
from pathlib import Path

from conftest import run_here
from test_driveparts_s25 import _imported
from test_take_archives import zip_folder


def _directory_patched(archive: Path, at: int, value: int) -> Path:
    """``archive`` with the 2-byte field ``at`` of its directory's first entry (APPNOTE 4.3.12: 6, the
    version needed to extract; 8, the flags) set to ``value``."""
    with zipfile.ZipFile(archive) as z:
        start = z.start_dir
    data = bytearray(archive.read_bytes())
    data[start + at : start + at + 2] = value.to_bytes(2, "little")
    archive.write_bytes(bytes(data))
    return archive


def _errors(proc) -> list[str]:
    assert proc.returncode == 1, proc.stderr
    return [line for line in proc.stderr.splitlines() if "error" in line]


def test_a_damaged_lzma_member_is_named_damaged(sim_take, tmp_path):
    archive = tmp_path / "take.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_LZMA) as z:
        mov = next(sim_take.glob("*.mov"))
        z.write(mov, f"{sim_take.name}/{mov.name}")
        info = z.getinfo(f"{sim_take.name}/{mov.name}")
    data = bytearray(archive.read_bytes())
    middle = info.header_offset + 30 + len(info.filename) + info.compress_size // 2
    data[middle : middle + 64] = bytes(64)  # in its compressed bytes
    archive.write_bytes(bytes(data))
    (error,) = _errors(run_here("capture", "import", archive, "-o", tmp_path / "out"))  # was: LZMAError
    assert f"member {sim_take.name}/{mov.name} is damaged" in error and "copy the archive again" in error


def test_a_member_flagged_as_patched_data_is_named_damaged(sim_take, tmp_path):
    archive = _directory_patched(zip_folder(sim_take, tmp_path / "take.zip"), 8, 0x20)
    (error,) = _errors(run_here("capture", "import", archive, "-o", tmp_path / "out"))  # NotImplementedError
    assert "is damaged (compressed patched data (flag bit 5))" in error, error


def test_a_directory_claiming_a_version_no_zip_has(sim_take, tmp_path):
    """zipfile refuses the whole directory: the members are read from their own headers, as of a
    directory cut; an archive not starting with a member (a self-extracting one) is not a readable zip."""
    archive = _directory_patched(zip_folder(sim_take, tmp_path / "take.zip"), 6, 105)
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out")  # was: NotImplementedError
    assert proc.returncode == 0, proc.stderr
    assert "read from its members' own headers" in proc.stderr, proc.stderr
    assert list(_imported(tmp_path / "out")) == [sim_take.name]
    prefixed = tmp_path / "sfx.zip"
    prefixed.write_bytes(b"#!/bin/sh\nexit 0\n" + archive.read_bytes())
    (error,) = _errors(run_here("capture", "import", prefixed, "-o", tmp_path / "out2"))
    assert "not a readable zip archive (zip file version 10.5)" in error, error
