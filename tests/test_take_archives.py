"""Takes in zip archives: shared from the phone, compressed by Finder or Windows Explorer, downloaded as a
folder; and archives that are damaged, hostile or unreadable here."""

from __future__ import annotations

import json
import shutil
import stat
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from capture import read_take
from capture.errors import InputError
from capture.take_archive import UNPACK_PREFIX, member_name, unpacked
from capture.transfer_litter import Litter
from tests.conftest import run_here


def zip_folder(folder: Path, archive: Path, inside: str | None = None, finder: bool = False) -> Path:
    """``folder``'s files zipped under ``inside/`` (default: the folder's name; "" for none); ``finder``
    adds the ``__MACOSX/.../._X`` entries Finder's Compress writes."""
    prefix = folder.name if inside is None else inside
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                name = "/".join(filter(None, [prefix, p.relative_to(folder).as_posix()]))
                z.write(p, name)
                if finder:
                    parent, _, leaf = name.rpartition("/")
                    z.writestr("/".join(filter(None, ["__MACOSX", parent, "._" + leaf])), b"\x00\x05\x16\x07")
    return archive


def imported(out: Path) -> list[Path]:
    return sorted(p for p in out.iterdir() if (p / "meta.json").is_file()) if out.is_dir() else []


def test_a_take_folder_zipped_by_finder_imports_with_its_audio_named_by_its_members(sim_take, tmp_path):
    archive = zip_folder(sim_take, tmp_path / "take.zip", finder=True)
    out = tmp_path / "out"
    proc = run_here("capture", "import", archive, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "macOS metadata" in proc.stderr and "Traceback" not in proc.stderr
    (folder,) = imported(out)
    take = read_take(folder)
    assert take.audio is not None and len(take.time) > 100
    member = f"{archive.resolve()}/{sim_take.name}/"
    assert take.meta.sources and all(s.path.startswith(member) for s in take.meta.sources), take.meta.sources
    assert [p.name for p in out.iterdir() if p.name.startswith(UNPACK_PREFIX)] == []  # nothing left unpacked
    # the same archive again replaces its take: the same source, not a second take beside it
    proc = run_here("capture", "import", archive, "-o", out)
    assert proc.returncode == 0 and "renamed" not in proc.stderr and "written as" not in proc.stderr
    assert imported(out) == [folder]


def test_a_take_folders_contents_zipped_without_the_folder_keep_the_takes_id(sim_take, tmp_path):
    archive = zip_folder(sim_take, tmp_path / "shared from phone.zip", inside="")
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out", "--json")
    assert proc.returncode == 0, proc.stderr
    (folder,) = imported(tmp_path / "out")
    assert folder.name == sim_take.name  # take.json's identifier, not the archive's or a temporary name
    (summary,) = [json.loads(line) for line in proc.stdout.splitlines()]
    assert summary["source"] == str(archive)


def test_loose_csvs_and_their_audio_in_an_archive_pair(samples, tmp_path):
    loose = tmp_path / "loose"
    loose.mkdir()
    shutil.copy(samples / "livelinkface/alexdjulin_S07/S07-001.csv", loose / "S07-001.csv")
    t = np.arange(16000 * 68) / 16000  # as long as the take's 2,030 rows at 30 fps
    sf.write(
        loose / "S07-001.wav", 0.3 * np.sin(2 * np.pi * 220 * t) * (np.sin(2 * np.pi * 3 * t) > 0), 16000
    )
    archive = zip_folder(loose, tmp_path / "loose.zip", inside="")
    proc = run_here("capture", "import", archive, "--pair-audio", "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    (folder,) = imported(tmp_path / "out")
    assert read_take(folder).audio is not None


def test_archives_in_a_folder_and_in_an_archive_are_imported_one_level_down(sim_take, samples, tmp_path):
    downloads = tmp_path / "downloads"
    (downloads / "session").mkdir(parents=True)
    zip_folder(sim_take, downloads / "session" / "take1.zip")
    shutil.copy(samples / "livelinkface/alexdjulin_S88/S88-001.csv", downloads / "S88-001.csv")
    with zipfile.ZipFile(downloads / "session" / "csv.zip", "w") as z:
        z.write(samples / "livelinkface/alexdjulin_S07/S07-001.csv", "S07-001.csv")
    proc = run_here("capture", "import", downloads, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert {p.name for p in imported(tmp_path / "out")} == {sim_take.name, "S88-001", "S07-001"}
    # Google Drive's download of that folder: one archive holding the others
    outer = zip_folder(downloads, tmp_path / "drive-download.zip")
    proc = run_here("capture", "import", outer, "-o", tmp_path / "out2")
    assert proc.returncode == 0, proc.stderr
    assert {p.name for p in imported(tmp_path / "out2")} == {sim_take.name, "S88-001", "S07-001"}
    take = read_take(tmp_path / "out2" / "S07-001")
    assert take.meta.sources[0].path == f"{outer.resolve()}/downloads/session/csv.zip/S07-001.csv"
    # three levels down is one too many: named, not unpacked
    (tmp_path / "wrap").mkdir()
    shutil.copy(outer, tmp_path / "wrap" / "drive-download.zip")
    three = zip_folder(tmp_path / "wrap", tmp_path / "three.zip")
    proc = run_here("capture", "import", three, "-o", tmp_path / "out3")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert [p.name for p in imported(tmp_path / "out3")] == ["S88-001"]
    assert "three.zip/wrap/drive-download.zip/downloads/session/take1.zip: a zip archive" in proc.stderr


def test_info_reads_an_archive(sim_take, tmp_path):
    archive = zip_folder(sim_take, tmp_path / "take.zip")
    proc = run_here("capture", "info", archive, "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["frames"] > 100


def _raw_zip(path: Path, members: list[tuple[zipfile.ZipInfo, bytes]]) -> Path:
    with zipfile.ZipFile(path, "w") as z:
        for info, data in members:
            z.writestr(info, data)
    return path


@pytest.mark.parametrize(
    "name", ["../escaped.csv", "/tmp/absolute.csv", "C:/Users/x.csv", "a\\..\\..\\b.csv"]
)
def test_members_outside_the_folder_refuse_the_archive_and_write_nothing(samples, tmp_path, name):
    csv = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_bytes()
    archive = _raw_zip(
        tmp_path / "evil.zip", [(zipfile.ZipInfo("ok.csv"), csv), (zipfile.ZipInfo(name), csv)]
    )
    out = tmp_path / "sub" / "out"
    proc = run_here("capture", "import", archive, "-o", out)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "would be written outside the folder unpacked into" in proc.stderr
    assert not imported(out) and not (tmp_path / "sub" / "escaped.csv").exists()
    assert not list(out.glob(f"{UNPACK_PREFIX}*"))


def test_links_in_an_archive_are_not_made(samples, tmp_path):
    csv = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_bytes()
    link = zipfile.ZipInfo("T/S07-001.csv")
    link.create_system = 3
    link.external_attr = (stat.S_IFLNK | 0o777) << 16
    archive = _raw_zip(tmp_path / "links.zip", [(link, b"/etc/passwd"), (zipfile.ZipInfo("S88.csv"), csv)])
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in imported(tmp_path / "out")] == ["S88"]


def _patched(path: Path, offset_in_header: int, fmt: str, value: int) -> None:
    """Set a field of every local and central header of a zip (offsets from each header's signature)."""
    data = bytearray(path.read_bytes())
    for sig, extra in ((b"PK\x03\x04", 0), (b"PK\x01\x02", 2)):  # central headers have one more field first
        start = 0
        while (i := data.find(sig, start)) >= 0:
            struct.pack_into(fmt, data, i + offset_in_header + extra, value)
            start = i + 4
    path.write_bytes(bytes(data))


def test_encrypted_and_deflate64_archives_say_what_to_do(samples, tmp_path):
    csv = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_bytes()[:4000]
    locked = _raw_zip(tmp_path / "locked.zip", [(zipfile.ZipInfo("S07-001.csv"), csv)])
    _patched(locked, 6, "<H", 0x1)  # general purpose flags: encrypted
    proc = run_here("capture", "import", locked, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "is encrypted: unzip it with its password" in proc.stderr, proc.stderr
    big = _raw_zip(tmp_path / "explorer.zip", [(zipfile.ZipInfo("S07-001.csv"), csv)])
    _patched(big, 8, "<H", 9)  # compression method: Deflate64
    proc = run_here("capture", "import", big, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "Deflate64" in proc.stderr and "7-Zip" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_cut_short_or_damaged_archive_is_one_line_and_the_other_sources_import(samples, tmp_path):
    csv_path = samples / "livelinkface/alexdjulin_S07/S07-001.csv"
    whole = tmp_path / "whole.zip"
    with zipfile.ZipFile(whole, "w", zipfile.ZIP_DEFLATED) as z:
        z.write(csv_path, "S07-001.csv")
    cut = tmp_path / "cut.zip"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    damaged = tmp_path / "damaged.zip"
    data = bytearray(whole.read_bytes())
    data[len(data) // 3] ^= 0xFF  # inside the compressed CSV
    damaged.write_bytes(bytes(data))
    out = tmp_path / "out"
    proc = run_here("capture", "import", cut, damaged, csv_path, "-o", out)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 2, proc.stderr
    assert "cut.zip: not a readable zip archive" in errors[0] and "cut short" in errors[0]
    assert "damaged.zip: member S07-001.csv is damaged" in errors[1]
    assert [p.name for p in imported(out)] == ["S07-001"]
    assert not list(out.glob(f"{UNPACK_PREFIX}*"))


def test_two_members_of_one_name_refuse_the_archive(samples, tmp_path):
    csv = (samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_bytes()
    with pytest.warns(UserWarning, match="Duplicate name"):
        archive = _raw_zip(
            tmp_path / "twice.zip", [(zipfile.ZipInfo("a.csv"), csv), (zipfile.ZipInfo("a.csv"), b"x")]
        )
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out")
    assert proc.returncode == 1 and "holds two members named a.csv" in proc.stderr, proc.stderr


def test_an_archive_larger_than_the_free_space_is_refused_before_unpacking(samples, tmp_path, monkeypatch):
    archive = tmp_path / "a.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("zeros.csv", bytes(50 << 20))  # 50 MB of zeros: 50 kB compressed
    assert archive.stat().st_size < 1 << 20
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: usage._replace(free=80 << 20))
    needs = r"unpacking it needs 119\.5 MB \(67\.1 MB of it to spare\) and .* has 83\.9 MB free"
    with (
        pytest.raises(InputError, match=needs),
        unpacked(archive, tmp_path),
    ):
        pass
    assert not list(tmp_path.glob(f"{UNPACK_PREFIX}*"))


def test_names_written_as_utf8_without_the_flag_are_read_as_utf8():
    finder = zipfile.ZipInfo("Caf\u00e9/x.csv".encode().decode("cp437"))  # as zipfile reads Finder's name
    assert member_name(finder) == "Caf\u00e9/x.csv"
    old = zipfile.ZipInfo("\u00e9t\u00e9.csv")  # a real code page 437 name (bytes not UTF-8)
    old.filename = b"\x82t\x82.csv".decode("cp437")
    assert member_name(old) == "\u00e9t\u00e9.csv"
    windows = zipfile.ZipInfo("T\\T.csv")
    assert member_name(windows) == "T/T.csv"


def test_what_a_killed_import_left_unpacked_is_removed_by_the_next(sim_take, tmp_path):
    out = tmp_path / "out"
    left = out / f"{UNPACK_PREFIX}abcd1234" / "take"
    left.mkdir(parents=True)
    (left / "big.mov").write_bytes(bytes(1000))
    archive = zip_folder(sim_take, tmp_path / "take.zip")
    proc = run_here("capture", "import", archive, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in out.iterdir() if not p.name.startswith(".import")] == [sim_take.name]


def test_align_on_a_folder_of_archives_says_to_import_them(sim_take, tmp_path):
    (tmp_path / "in").mkdir()
    zip_folder(sim_take, tmp_path / "in" / "take.zip")
    proc = run_here("align", tmp_path / "in", "-o", tmp_path / "al")
    assert proc.returncode == 1 and "run s2a-capture import" in proc.stderr, proc.stderr


def test_unpacked_counts_litter_and_names_members(sim_take, tmp_path):
    archive = zip_folder(sim_take, tmp_path / "take.zip", finder=True)
    tally = Litter()
    with unpacked(archive, tmp_path, tally) as box:
        assert (box.folder / sim_take.name / "take.json").is_file()
        assert box.shown(box.folder / "x.csv") == f"{archive}/x.csv"
        assert not list(box.folder.rglob("._*")) and not (box.folder / "__MACOSX").exists()
    assert not box.folder.exists()
    assert any("macOS metadata" in line for line in tally.lines())


def test_archives_named_dot_zip_are_one_error_each_and_the_others_import(samples, tmp_path):
    """``..zip`` has the stem ``.``: unpacking into a folder of that name failed with a bare
    ``File exists`` naming a hidden folder, and stopped the whole import."""
    csv = samples / "livelinkface/alexdjulin_S07/S07-001.csv"
    (tmp_path / "z").mkdir()
    for name in ("..zip", "...zip", "good.zip"):
        with zipfile.ZipFile(tmp_path / "z" / name, "w") as z:
            z.write(csv, "S07-001.csv" if name == "good.zip" else f"{name[:2]}S07.csv")
    proc = run_here("capture", "import", tmp_path / "z", "-o", tmp_path / "out")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert len(imported(tmp_path / "out")) == 3 and UNPACK_PREFIX not in proc.stderr


def test_info_reads_archives_in_a_folder_in_an_archive_and_of_imported_takes(sim_take, samples, tmp_path):
    folder = tmp_path / "fz"
    folder.mkdir()
    zip_folder(sim_take, folder / "take.zip")
    proc = run_here("capture", "info", folder, "--json")
    assert proc.returncode == 0 and json.loads(proc.stdout)["frames"] > 100, proc.stderr
    outer = zip_folder(folder, tmp_path / "outer.zip")
    proc = run_here("capture", "info", outer, "--json")
    assert proc.returncode == 0 and json.loads(proc.stdout)["frames"] > 100, proc.stderr
    # a zip of takes imported already: info reads them; import says what they are
    out = tmp_path / "out"
    run_here("capture", "import", sim_take, "-o", out, check=True)
    ours = zip_folder(out / sim_take.name, tmp_path / "ours.zip")
    proc = run_here("capture", "info", ours, "--json")
    assert proc.returncode == 0 and json.loads(proc.stdout)["frames"] > 100, proc.stderr
    proc = run_here("capture", "import", ours, "-o", tmp_path / "again")
    assert proc.returncode == 1 and "it holds takes imported already" in proc.stderr, proc.stderr


def test_an_archive_imported_again_through_a_link_replaces_its_take(sim_take, tmp_path):
    (tmp_path / "z").mkdir()
    zip_folder(sim_take, tmp_path / "z" / "take.zip")
    (tmp_path / "zl").symlink_to(tmp_path / "z")
    out = tmp_path / "out"
    run_here("capture", "import", tmp_path / "z" / "take.zip", "-o", out, check=True)
    proc = run_here("capture", "import", tmp_path / "zl" / "take.zip", "-o", out)
    assert proc.returncode == 0 and "written as" not in proc.stderr, proc.stderr
    assert len(imported(out)) == 1
    assert read_take(imported(out)[0]).meta.sources[0].path.startswith(str((tmp_path / "z").resolve()))


def test_an_import_without_the_folder_lock_leaves_what_others_unpacked(sim_take, tmp_path):
    out = tmp_path / "out"
    busy = out / f"{UNPACK_PREFIX}other123" / "take"
    busy.mkdir(parents=True)
    (out / ".import.lock").symlink_to(tmp_path / "elsewhere")  # cannot be locked: the import runs unlocked
    proc = run_here("capture", "import", zip_folder(sim_take, tmp_path / "take.zip"), "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert busy.is_dir()  # another import's, perhaps: only an import holding the lock clears them
