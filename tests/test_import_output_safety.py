"""s2a-capture import into folders others write or that hold other things: one import at a time, never
into a dataset, never over an aligned take, and a changed source said when its take is replaced."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

from capture.file_lock import try_lock
from tests.conftest import run_here


def _csv(samples, tmp_path):
    src = tmp_path / "src" / "S07-001.csv"
    src.parent.mkdir()
    shutil.copy(samples / "livelinkface/alexdjulin_S07/S07-001.csv", src)
    return src


def test_a_second_import_into_a_folder_being_written_is_refused(samples, tmp_path):
    """Two imports at once each took the same free ids and overwrote each other's takes (both exit 0)."""
    src, out = _csv(samples, tmp_path), tmp_path / "takes"
    out.mkdir()
    fd = os.open(out / ".import.lock", os.O_RDWR | os.O_CREAT)
    try:
        assert try_lock(fd)
        os.write(fd, b"4242\n")
        proc = run_here("capture", "import", src, "-o", out)
    finally:
        os.close(fd)
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip() == (
        f"s2a-capture: error: another s2a-capture import (pid 4242) is writing into {out}: wait for it or "
        "choose another -o"
    )
    assert [p.name for p in out.iterdir()] == [".import.lock"]
    # once it is released, the import runs and leaves no lock file behind
    proc = run_here("capture", "import", src, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["S07-001"]


def test_import_into_a_dataset_folder_is_refused(samples, tmp_path):
    src, ds = _csv(samples, tmp_path), tmp_path / "ds"
    ds.mkdir()
    (ds / "manifest.json").write_text("{}")
    proc = run_here("capture", "import", src, "-o", ds)
    assert proc.returncode == 1 and "is a dataset folder (it holds manifest.json)" in proc.stderr, proc.stderr
    assert sorted(p.name for p in ds.iterdir()) == ["manifest.json"]


def test_an_aligned_take_of_the_same_source_is_not_replaced(samples, tmp_path):
    """The aligned take made from an import was replaced by a raw re-import (same first source file)."""
    src, out = _csv(samples, tmp_path), tmp_path / "takes"
    assert run_here("capture", "import", src, "-o", out).returncode == 0
    meta_path = out / "S07-001" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["source_kind"] = "aligned"  # as s2a-align writes it, keeping its parent's sources
    meta_path.write_text(json.dumps(meta))
    proc = run_here("capture", "import", src, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "take id 'S07-001' is taken in" in proc.stderr and "by an aligned take" in proc.stderr
    assert json.loads(meta_path.read_text())["source_kind"] == "aligned"
    assert (out / "S07-001-2").is_dir()


def test_a_reimport_of_a_changed_source_says_it_replaces_the_take(samples, tmp_path):
    src, out = _csv(samples, tmp_path), tmp_path / "takes"
    assert run_here("capture", "import", src, "-o", out).returncode == 0
    same = run_here("capture", "import", src, "-o", out)
    assert same.returncode == 0 and "warning" not in same.stderr, same.stderr
    lines = src.read_text().splitlines(keepends=True)
    src.write_text("".join(lines[:-10]))  # the source edited: ten rows fewer
    changed = run_here("capture", "import", src, "-o", out)
    assert changed.returncode == 0, changed.stderr
    assert f"replaces {out / 'S07-001'}, imported from it before its contents changed" in changed.stderr
    assert sorted(p.name for p in out.iterdir()) == ["S07-001"]


def test_a_take_folder_imported_as_dot_is_named_after_the_folder(tmp_path):
    """`cd TAKE && s2a-capture import . -o OUT` named the take `take` (the name of `.` is empty)."""
    assert (
        run_here("capture", "simulate", "-o", tmp_path / "phone", "--seconds", "3", "--mov").returncode == 0
    )
    (folder,) = [p for p in (tmp_path / "phone").iterdir() if p.is_dir()]
    (folder / "take.json").unlink()  # sent without it: the folder's name is the take's
    renamed = folder.rename(folder.parent / "UPPER_1")
    for given in (".", "./"):
        proc = subprocess.run(
            [sys.executable, "-m", "capture", "import", given, "-o", str(tmp_path / f"out{len(given)}")],
            cwd=renamed,
            capture_output=True,
            text=True,
        )
        assert proc.returncode == 0, proc.stderr
        assert [p.name for p in (tmp_path / f"out{len(given)}").iterdir()] == ["UPPER_1"], proc.stderr


def test_align_and_build_on_recordings_not_imported_say_to_import_first(tmp_path):
    assert run_here("capture", "simulate", "-o", tmp_path / "phone", "--seconds", "3").returncode == 0
    for args, stage in (
        (["align", tmp_path / "phone", "-o", tmp_path / "al"], "s2a-align"),
        (["dataset", "build", tmp_path / "phone", "-o", tmp_path / "ds"], "s2a-dataset build"),
    ):
        proc = run_here(*args)
        assert proc.returncode == 1, proc.stderr
        assert "only 1 recording(s) not imported yet" in proc.stderr, proc.stderr
        hint = f"run s2a-capture import {tmp_path / 'phone'} -o TAKES first, then {stage} TAKES"
        assert hint in proc.stderr, proc.stderr
    (tmp_path / "empty").mkdir()
    proc = run_here("align", tmp_path / "empty", "-o", tmp_path / "al")
    assert proc.stderr.strip().endswith(f"no takes found under {tmp_path / 'empty'}"), proc.stderr
