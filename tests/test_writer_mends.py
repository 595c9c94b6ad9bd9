"""The atomic writers after review: a failure to write named as the file (``name_failures``), a batch of
takes written into one folder that lists it once for leftovers (``batch_of_writes``), and a set of take
folders that appears all or none (``all_or_none``), all on real files."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from live_helpers import synthetic_take

import capture.atomic as atomic
from align import AlignOptions, align_takes
from capture import read_audio, read_livelink_csv, read_take, write_take
from capture.atomic import all_or_none, atomic_write, batch_of_writes, naming_failures, write_json_atomic
from capture.errors import InputError
from capture.file_lock import fcntl

ROOT = Path(__file__).resolve().parents[1]


def _take(take_id: str, seed: int):
    take = synthetic_take(30, seed=seed)
    take.meta.id = take_id
    return take


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# -- 1. a failure to write names the file, not its hidden partial nor nothing -------------------------------
FULL_DISK = """
import resource, sys
sys.path.insert(0, {root!r})
from capture.atomic import atomic_write
from capture.errors import InputError
resource.setrlimit(resource.RLIMIT_FSIZE, (10_000, 10_000))  # a write past 10 kB fails: EFBIG, no file named
try:
    with atomic_write(sys.argv[1], name_failures=True) as f:
        f.write(bytes(50_000))
except InputError as exc:
    print(exc)
"""


def test_a_write_past_the_disk_s_room_names_the_file(tmp_path):
    path = tmp_path / "big.bin"
    path.write_bytes(b"old")
    r = subprocess.run(
        [sys.executable, "-c", FULL_DISK.format(root=str(ROOT)), str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"{path}: cannot be written: File too large"
    assert path.read_bytes() == b"old" and _hidden(tmp_path) == []  # the old file, no partial left


def test_an_open_that_fails_names_the_file_not_its_partial(tmp_path):
    path = tmp_path / "missing" / "stats.json"
    with pytest.raises(InputError) as err:
        write_json_atomic(path, {"a": 1}, name_failures=True)
    assert str(err.value) == f"{path}: cannot be written: No such file or directory"
    with pytest.raises(FileNotFoundError):  # without the option: the OSError as it was
        write_json_atomic(path, {"a": 1})


def test_an_error_of_another_file_keeps_its_own_name(tmp_path):
    source = tmp_path / "gone.tar"
    with pytest.raises(FileNotFoundError) as err, atomic_write(tmp_path / "out.tar", name_failures=True) as f:
        f.write(source.read_bytes())
    assert err.value.filename == str(source) and list(tmp_path.iterdir()) == []
    with pytest.raises(FileNotFoundError), naming_failures(tmp_path / "shard.tar"):
        source.read_bytes()


# -- 2. a batch of N takes into one folder lists it once, not N times ----------------------------------------
def _count_listings(monkeypatch, folder: Path) -> list[int]:
    listed = [0]
    real = os.scandir

    def scandir(path="."):
        if isinstance(path, (str, os.PathLike)) and os.path.abspath(path) == str(folder):
            listed[0] += 1
        return real(path)

    monkeypatch.setattr(os, "scandir", scandir)
    return listed


@pytest.mark.skipif(fcntl is None, reason="no flock: leftovers are never looked for")
def test_a_batch_of_takes_lists_its_folder_once(tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    listed = _count_listings(monkeypatch, out)
    with batch_of_writes(out):
        for i in range(40):
            write_take(_take(f"t{i:02d}", i), out)
    assert listed[0] == 1
    assert sorted(p.name for p in out.iterdir()) == [f"t{i:02d}" for i in range(40)]
    write_take(_take("t00", 99), out)  # outside a batch: a listing per take, as before
    assert listed[0] == 2


@pytest.mark.skipif(fcntl is None, reason="no flock: leftovers cannot be told from live writes")
def test_a_batch_clears_the_leftovers_there_were_as_each_write_did(tmp_path, monkeypatch):
    # Leftovers of killed writes, made by hand as test_capture_crash does: a take moved aside
    # (.T.old-XXXX/take) by a write killed before it put the new one in place, a dead partial of T, a live
    # one (another process's write going on), and leftovers of the takes "U" and "T.old-1".
    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    write_take(_take("T", 0), tmp_path)
    write_take(_take("U", 0), tmp_path)
    aside = tmp_path / ".T.old-abcd1234"
    aside.mkdir()
    os.replace(tmp_path / "T", aside / "take")
    (tmp_path / ".T.partial-efgh5678").mkdir()
    live = tmp_path / ".T.partial-live0001"
    live.mkdir()
    (tmp_path / ".U.partial-ijkl9012").mkdir()
    other = tmp_path / ".T.old-1.old-abcd1234"
    other.mkdir()
    held = os.open(live, os.O_RDONLY)
    try:
        fcntl.flock(held, fcntl.LOCK_EX)
        with batch_of_writes(tmp_path):
            write_take(_take("V", 1), tmp_path)  # not T: T's leftovers stay
            assert not (tmp_path / "T").exists() and aside.exists()
            write_take(_take("T", 1), tmp_path)  # the old T back, then replaced; the dead partial gone
            assert _hidden(tmp_path) == [other.name, live.name, ".U.partial-ijkl9012"]
            write_take(_take("U", 1), tmp_path)
        assert _hidden(tmp_path) == [other.name, live.name]
        assert np.array_equal(read_take(tmp_path / "T").values, _take("T", 1).values)
    finally:
        os.close(held)


@pytest.mark.skipif(fcntl is None, reason="no flock: leftovers are never looked for")
def test_align_lists_its_output_folder_once_for_leftovers(samples, tmp_path, monkeypatch):
    folder = samples / "paired/neurosync-trainer-lite-testset"
    raw = tmp_path / "raw"
    for i in range(2):
        take = read_livelink_csv(folder / "testset.csv")
        take.meta.id = f"ns{i}"
        take.attach_audio(read_audio(folder / "audio.wav"), 0.0, "paired_frame_convention")
        write_take(take, raw)
    out = tmp_path / "out"
    listings = []
    real = atomic._leftovers_in
    monkeypatch.setattr(atomic, "_leftovers_in", lambda f: listings.append(Path(f)) or real(f))
    reports = align_takes([raw], out, AlignOptions(vad="none"))
    assert [r.get("error") for r in reports] == [None, None]
    assert listings == [out.resolve()]  # one listing of the batch, none per take


# -- 3. a set of takes appears all or none ---------------------------------------------------------------
def test_a_set_of_takes_appears_all_or_none(tmp_path):
    write_take(_take("a", 0), tmp_path)
    bad = _take("c", 2)
    bad.meta.extra["oops"] = float("nan")  # found while its folder is written: metadata cannot be JSON
    with pytest.raises(InputError, match=f"{tmp_path / 'c'}: take c: metadata cannot be written"):
        with all_or_none():
            write_take(_take("a", 1), tmp_path)
            write_take(_take("b", 1), tmp_path)
            assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["a"]
            write_take(bad, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"]  # the old a, no hidden folder left
    assert np.array_equal(read_take(tmp_path / "a").values, _take("a", 0).values)
    with all_or_none():
        paths = [write_take(_take(t, 3), tmp_path) for t in ("a", "b")]
        with pytest.raises(InputError):  # an error caught inside: that folder never appears
            write_take(bad, tmp_path)
    assert paths == [tmp_path / "a", tmp_path / "b"] and sorted(tmp_path.iterdir()) == paths
    assert np.array_equal(read_take(tmp_path / "b").values, _take("b", 3).values)
