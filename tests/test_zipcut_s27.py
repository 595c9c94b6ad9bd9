"""Zips whose directory (the list of files at their end) is cut or damaged, every member whole: read from
their members' own headers (each member's CRC checked), as one archive or a part of a Google Drive
download, with a warning; a cut part ending in a zip stored in it is not read as that zip; a cut part's
zip64 headers name all the files it shows."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import pytest
import test_driveparts_s25
from conftest import run_here
from test_driveparts_s25 import STEM, TAKES, _download, _imported, _part, _unpacked_left
from test_review_csvdrive_s26 import _Stream
from test_take_archives import zip_folder

from capture import read_take
from capture.errors import InputError
from capture.take_archive import drive_downloads, unpacked
from viewer.inputs import read_input

takes = test_driveparts_s25.takes  # the fixture: the folder uploaded to Drive, two take folders


def _cut_in_directory(archive: Path, into: int = 10) -> Path:
    """``archive`` cut ``into`` bytes into its directory, as a download that stopped near its end."""
    with zipfile.ZipFile(archive) as z:
        start = z.start_dir
    archive.write_bytes(archive.read_bytes()[: start + into])
    return archive


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_a_zip_cut_in_its_directory_imports_every_member_from_their_headers(sim_take, tmp_path):
    whole = zip_folder(sim_take, tmp_path / "whole.zip")
    run_here("capture", "import", whole, "-o", tmp_path / "whole", check=True)
    cut = _cut_in_directory(zip_folder(sim_take, tmp_path / "take.zip"))
    proc = run_here("capture", "import", cut, "-o", tmp_path / "out")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr  # was: not a readable zip
    (said,) = [line for line in proc.stderr.splitlines() if "directory" in line]
    assert "warning" in said and str(cut) in said and "read from its members' own headers" in said, said
    (expected,) = _imported(tmp_path / "whole").values()
    got = read_take(_imported(tmp_path / "out")[sim_take.name])
    assert got.audio is not None and len(got.time) == len(read_take(expected).time)
    assert all(s.path.startswith(f"{cut.resolve()}/{sim_take.name}/") for s in got.meta.sources)


def test_streamed_and_zip64_zips_cut_in_their_directory_unpack_as_whole(sim_take, tmp_path):
    """Sizes after the bytes (a zip written as a stream), zip64 headers, stored or compressed: what is
    unpacked is what the whole zip unpacks; a member's damaged bytes are said by its CRC."""
    files = sorted(p for p in sim_take.rglob("*") if p.is_file())
    for n, (stream, zip64, method) in enumerate(
        [
            (s, z, m)
            for s in (False, True)
            for z in (False, True)
            for m in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED)
        ]
    ):
        archive = tmp_path / f"t{n}.zip"
        with open(archive, "wb") as f, zipfile.ZipFile(_Stream(f) if stream else f, "w", method) as z:
            for p in files:
                with z.open(p.relative_to(sim_take.parent).as_posix(), "w", force_zip64=zip64) as member:
                    member.write(p.read_bytes())
        with unpacked(archive, tmp_path) as box:
            expected = _files(box.folder)
        _cut_in_directory(archive, 30)
        with unpacked(archive, tmp_path) as box:
            assert _files(box.folder) == expected, (stream, zip64, method)
    data = bytearray(archive.read_bytes())
    data[200] ^= 0xFF  # in the first member's bytes
    archive.write_bytes(bytes(data))
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    (error,) = [line for line in proc.stderr.splitlines() if "error" in line]
    assert "is damaged" in error and "copy the archive again" in error, error


def test_a_drive_part_cut_in_its_directory_keeps_its_files(takes, tmp_path):
    downloads = tmp_path / "Downloads"
    parts = _download(downloads, takes)
    _cut_in_directory(parts[1])  # 002: S07-001's .mov, whole
    out = tmp_path / "out"
    proc = run_here("capture", "import", downloads, "-o", out)
    assert proc.returncode == 0 and "part missing" not in proc.stderr, proc.stderr  # was: read as missing
    (said,) = [line for line in proc.stderr.splitlines() if "directory" in line]
    assert str(parts[1]) in said, said
    found = _imported(out)
    assert sorted(found) == sorted(TAKES)
    take = read_take(found["S07-001"])
    assert take.audio is not None
    assert f"{parts[1].resolve()}/Takes/S07-001/S07-001.mov" in [s.path for s in take.meta.sources]
    assert _unpacked_left(out) == []


def _with_stored_zip(archive: Path, folder: Path, then: bytes = b"") -> Path:
    """``archive`` of ``folder``'s files under its name, a zip holding a take's CSV stored after them (an
    earlier download kept in the folder) and, with ``then``, a file after that."""
    inner = io.BytesIO()
    with zipfile.ZipFile(inner, "w") as z:
        z.writestr("S99-001.csv", (folder / f"{folder.name}.csv").read_bytes())
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.iterdir()):
            z.write(p, f"{folder.name}/{p.name}")
        z.writestr(zipfile.ZipInfo("old.zip"), inner.getvalue())  # stored: its end as it is
        if then:
            z.writestr("notes.txt", then)
    return archive


def test_a_cut_zip_ending_in_a_zip_stored_in_it_is_not_read_as_that_zip(takes, tmp_path):
    """zipfile finds the stored zip's end among a cut zip's last bytes and reads that zip: its take was
    imported as the archive's, the archive's own files silently left out."""
    archive = _with_stored_zip(tmp_path / "take.zip", takes / "S07-001", bytes(range(256)) * 40)
    with zipfile.ZipFile(archive) as z:
        cut = z.getinfo("notes.txt").header_offset + 100  # in the last member's bytes
    archive.write_bytes(archive.read_bytes()[:cut])
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and "not a readable zip archive" in proc.stderr, proc.stderr
    assert _imported(tmp_path / "out") == {}
    # cut in its directory: its members read, the zip in it one level down
    archive = _cut_in_directory(_with_stored_zip(tmp_path / "take2.zip", takes / "S07-001"))
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out2")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    found = _imported(tmp_path / "out2")
    assert sorted(found) == ["S07-001", "S99-001"]
    assert read_take(found["S07-001"]).audio is not None
    source = read_take(found["S99-001"]).meta.sources[0].path
    assert source == f"{archive.resolve()}/old.zip/S99-001.csv"


def test_a_cut_zip64_part_names_every_file_its_headers_show(takes, tmp_path):
    """Zip64 headers give their sizes in an extra field: the list of files stopped at the first."""
    downloads = tmp_path / "Downloads"
    _download(downloads, takes, (1,))
    part = downloads / f"{STEM}-002.zip"
    with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
        for name in ("S07-001/S07-001.mov", "S88-001/S88-001.mov"):
            with z.open(f"Takes/{name}", "w", force_zip64=True) as member:
                member.write((takes / name).read_bytes())
    part.write_bytes(part.read_bytes()[: part.stat().st_size * 3 // 4])  # cut in the second .mov
    _part(downloads, 3, takes, [])
    proc = run_here("capture", "import", downloads, "-o", tmp_path / "out")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    (said,) = [line for line in proc.stderr.splitlines() if "cut short" in line]
    assert "Takes/S07-001/S07-001.mov, Takes/S88-001/S88-001.mov and what followed" in said, said


def test_strict_refuses_a_download_read_short_or_repaired(takes, tmp_path):
    """``--strict`` refuses files that need any repair: an import passes it to ``unpacked``, where a part
    read as missing or a zip read from its headers is an error instead of a warning."""
    parts = _download(tmp_path / "a", takes)
    parts[1].write_bytes(parts[1].read_bytes()[:100])  # cut in S07-001's .mov
    _cut_in_directory(zip_folder(takes / "S07-001", tmp_path / "take.zip"))
    for archive, said in (
        (drive_downloads(parts)[0], "read as a part missing"),
        (tmp_path / "take.zip", "directory"),
    ):
        with unpacked(archive, tmp_path) as box:  # as before: read, with a warning
            assert box.folder.is_dir()
        with pytest.raises(InputError, match=f"{said}.*--strict refuses an archive read short or repaired"):
            with unpacked(archive, tmp_path, strict=True):
                pass
    assert not list(tmp_path.glob(".unzip-*"))


def test_the_viewer_reads_a_take_of_a_zip_cut_in_its_directory(takes, tmp_path, unpack_tmp):
    archive = tmp_path / "takes.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(takes.rglob("*")):
            z.write(p, p.relative_to(takes).as_posix())
    _cut_in_directory(archive)
    take, _, speech = read_input(archive / "S07-001", "one")  # was: not a readable zip archive
    assert take.audio is not None and len(take.time) > 100
    assert speech == archive / "S07-001/S07-001.mov"
    assert list(unpack_tmp.iterdir()) == []
