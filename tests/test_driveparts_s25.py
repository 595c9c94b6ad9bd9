"""A Google Drive download of a large folder comes in parts (``Takes-20250301T101500Z-001.zip``,
``-002.zip``, ...), one take's CSV in one part and its .mov in another: ``s2a-capture import`` reads the
parts of one download as one archive, each file named after its part; a part missing is said, a file in
two parts refused, a part alone read as an archive of its own."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import pytest
from conftest import run_cli
from test_audio_decode_memory import _encoded

from capture import read_take
from capture.take_archive import UNPACK_PREFIX

STEM = "Takes-20250301T101500Z"
TAKES = {"S07-001": "alexdjulin_S07", "S88-001": "alexdjulin_S88"}


@pytest.fixture(scope="module")
def takes(samples: Path, tmp_path_factory) -> Path:
    """The folder ``Takes`` uploaded to Drive: two Live Link Face take folders, each the app's CSV (its
    first 4 s) and a .mov of the take's name holding 4 s of AAC."""
    root = tmp_path_factory.mktemp("drive") / "Takes"
    mov = _encoded("aac", "mov", "fltp", 2, seconds=4.0)
    for take, sample in TAKES.items():
        (root / take).mkdir(parents=True)
        lines = (samples / "livelinkface" / sample / f"{take}.csv").read_text().splitlines(keepends=True)
        (root / take / f"{take}.csv").write_text("".join(lines[:121]))
        (root / take / f"{take}.mov").write_bytes(mov)
    return root


def _part(folder: Path, number: int, takes: Path, files: list[str]) -> Path:
    """Part ``number`` of the download as Drive writes it: ``files`` (paths in ``takes``) under ``Takes/``."""
    folder.mkdir(parents=True, exist_ok=True)
    part = folder / f"{STEM}-{number:03d}.zip"
    with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
        for name in files:
            z.write(takes / name, f"Takes/{name}")
    return part


def _download(folder: Path, takes: Path, numbers: tuple[int, ...] = (1, 2, 3)) -> list[Path]:
    """The parts ``numbers`` of the download: the CSVs in 001, each take's .mov in a part of its own."""
    files = {
        1: ["S07-001/S07-001.csv", "S88-001/S88-001.csv"],
        2: ["S07-001/S07-001.mov"],
        3: ["S88-001/S88-001.mov"],
    }
    return [_part(folder, n, takes, files[n]) for n in numbers]


def _imported(out: Path) -> dict[str, Path]:
    return {p.name: p for p in out.iterdir() if (p / "meta.json").is_file()} if out.is_dir() else {}


def _unpacked_left(out: Path) -> list[str]:
    return [p.name for p in out.glob(f"{UNPACK_PREFIX}*")] if out.is_dir() else []


def test_the_parts_of_a_download_import_as_one_archive_named_by_part(takes, tmp_path):
    parts = _download(tmp_path / "Downloads", takes)
    for given in (parts, [tmp_path / "Downloads"]):  # named, or found in the folder searched
        out = tmp_path / f"out{len(given)}"
        proc = run_cli("capture", "import", *given, "-o", out)
        assert proc.returncode == 0, proc.stderr
        assert "Traceback" not in proc.stderr and "warning" not in proc.stderr, proc.stderr
        found = _imported(out)
        assert sorted(found) == sorted(TAKES)
        for number, take in ((2, "S07-001"), (3, "S88-001")):
            imported = read_take(found[take])
            assert imported.audio is not None and len(imported.time) > 100
            paths = sorted(s.path for s in imported.meta.sources)
            assert paths == [
                f"{parts[0].resolve()}/Takes/{take}/{take}.csv",
                f"{parts[number - 1].resolve()}/Takes/{take}/{take}.mov",
            ]
        assert _unpacked_left(out) == []
    # the folder of parts zipped in turn: the parts read one level down, named as its members
    outer = tmp_path / "backup.zip"
    with zipfile.ZipFile(outer, "w") as z:
        for part in parts:
            z.write(part, f"Downloads/{part.name}")
    proc = run_cli("capture", "import", outer, "-o", tmp_path / "nested")
    assert proc.returncode == 0 and "warning" not in proc.stderr, proc.stderr
    take = read_take(_imported(tmp_path / "nested")["S07-001"])
    assert sorted(s.path for s in take.meta.sources) == [
        f"{outer.resolve()}/Downloads/{STEM}-001.zip/Takes/S07-001/S07-001.csv",
        f"{outer.resolve()}/Downloads/{STEM}-002.zip/Takes/S07-001/S07-001.mov",
    ]


def test_a_part_missing_is_said_once_and_the_whole_takes_import(takes, tmp_path):
    parts = _download(tmp_path / "Downloads", takes, (1, 3))
    out = tmp_path / "out"
    proc = run_cli("capture", "import", *parts, "-o", out)
    assert proc.returncode == 0, proc.stderr
    (said,) = [line for line in proc.stderr.splitlines() if "part 002" in line]
    assert str(parts[0]) in said and "Google Drive" in said
    found = _imported(out)
    assert read_take(found["S88-001"]).audio is not None  # all its files are in 001 and 003
    assert read_take(found["S07-001"]).audio is None  # its .mov was in 002: imported as the CSV alone
    assert _unpacked_left(out) == []
    # the part downloaded, the download imported again: the take replaced by itself with its audio
    parts = _download(tmp_path / "Downloads", takes)
    proc = run_cli("capture", "import", tmp_path / "Downloads", "-o", out)
    assert proc.returncode == 0 and "part 002" not in proc.stderr and "written as" not in proc.stderr
    assert sorted(_imported(out)) == sorted(TAKES)
    assert read_take(found["S07-001"]).audio is not None


def test_info_reads_the_parts_of_a_download_as_one(takes, tmp_path):
    _download(tmp_path / "Downloads", takes)
    proc = run_cli("capture", "info", tmp_path / "Downloads", "--json")
    assert proc.returncode == 0, proc.stderr
    summaries = [json.loads(line) for line in proc.stdout.splitlines()]
    assert sorted(s["id"] for s in summaries) == sorted(TAKES)
    assert all(s["audio_sample_rate"] for s in summaries)


def test_a_file_in_two_parts_is_refused_in_one_line_naming_both(takes, tmp_path):
    parts = _download(tmp_path / "Downloads", takes, (1, 2))
    _part(tmp_path / "Downloads", 3, takes, ["S88-001/S88-001.mov", "S07-001/S07-001.mov"])
    out = tmp_path / "out"
    proc = run_cli("capture", "import", tmp_path / "Downloads", "-o", out)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "S07-001/S07-001.mov" in proc.stderr and f"{STEM}-003.zip" in proc.stderr
    assert str(parts[1]) in proc.stderr
    assert _imported(out) == {} and _unpacked_left(out) == []


def test_a_part_alone_is_an_archive_of_its_own(takes, tmp_path):
    (only_movs,) = _download(tmp_path / "a", takes, (2,))
    out = tmp_path / "out"
    proc = run_cli("capture", "import", only_movs, "-o", out)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "holds no Live Link Face CSV or take folder" in proc.stderr
    assert "one part of a Google Drive download" in proc.stderr
    # a part holding whole takes imports them, named by it
    whole = _part(tmp_path / "b", 2, takes, ["S07-001/S07-001.csv", "S07-001/S07-001.mov"])
    shutil.copy(only_movs, tmp_path / "b" / f"{STEM}-002 (1).zip")  # a copy's name: no part of it
    proc = run_cli("capture", "import", whole, "-o", out)
    assert proc.returncode == 0, proc.stderr
    take = read_take(_imported(out)["S07-001"])
    assert take.audio is not None
    assert all(s.path.startswith(f"{whole.resolve()}/Takes/S07-001/") for s in take.meta.sources)
