"""A file holding another whole zip after a zip's members (two zips joined with ``cat``, a download resumed
over a copy cut short) is read as zipfile and unzip read it, as the last zip: only a zip inside a stored
member of the file's own first zip is one it holds, not its directory."""

from __future__ import annotations

import zipfile

import test_driveparts_s25
from test_take_archives import zip_folder
from test_zipcut_s27 import _files

from capture.take_archive import unpacked

takes = test_driveparts_s25.takes  # the fixture: two take folders


def test_two_zips_joined_read_as_the_last(takes, tmp_path):
    first = zip_folder(takes / "S07-001", tmp_path / "a.zip").read_bytes()
    last = zip_folder(takes / "S88-001", tmp_path / "b.zip")
    with unpacked(last, tmp_path) as box:
        expected = _files(box.folder)
    for name, head in (("joined.zip", first), ("resumed.zip", first[:200])):
        archive = tmp_path / name
        archive.write_bytes(head + last.read_bytes())
        with zipfile.ZipFile(archive) as z:  # what zipfile (and unzip) read: the last zip
            assert sorted(i.filename for i in z.infolist()) == sorted(expected)
        with unpacked(archive, tmp_path) as box:  # was: a's files, or "not a readable zip archive"
            assert _files(box.folder) == expected, name
