"""s2a-dataset rebuilds that fail or are stopped, readers next to a running build, and takes rewritten
while a build reads them: the previous dataset stays readable until the new one is complete, validate
and stats wait for a build, and a take folder swapped by s2a-align is told apart from one without
meta.json."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_here
from dataset_helpers import make_aligned_take, write_aligned_set

import dataset.build as build_module
from capture import write_take
from capture.command import stops_deferred
from capture.errors import InputError
from capture.take import read_meta
from dataset import read_manifest
from dataset.build import BuildOptions, build_dataset, output_lock
from dataset.qa import validate

SMALL = {"max_sample_s": 0.5, "shard_bytes": int(0.06 * 1024 * 1024)}  # several samples and shards
SMALL_CLI = ("--max-sample-s", "0.5", "--shard-mb", "0.06")


def _opts(**kw) -> BuildOptions:
    return BuildOptions(**(SMALL | kw))


def _snapshot(ds: Path) -> dict[str, str]:
    """sha256 of the manifest and of every shard in ``ds``."""
    files = [ds / "manifest.json", *sorted(ds.glob("*.tar"))]
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def _dataset_files(ds: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(ds.iterdir()) if not p.name.startswith(".")}


def _readable(ds: Path) -> None:
    """validate (valid), stats and the manifest reader all read ``ds``."""
    proc = run_here("dataset", "validate", ds)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    proc = run_here("dataset", "stats", ds, "--json")
    assert proc.returncode == 0, proc.stderr
    read_manifest(ds)


def _add_take(aligned: Path, take_id: str, seed: int, nan: int = 0) -> Path:
    """A 2 s aligned take; ``nan`` of its audio samples NaN (a float WAV)."""
    folder = write_take(make_aligned_take(take_id, 2.0, subject="spk1", seed=seed), aligned)
    if nan:
        audio, rate = sf.read(folder / "audio.wav", dtype="float32")
        audio[1000 : 1000 + nan] = np.nan
        sf.write(folder / "audio.wav", audio, rate, subtype="FLOAT")
    return folder


@pytest.fixture()
def built(tmp_path) -> tuple[Path, Path]:
    """Five aligned takes and a dataset built from them by the command line."""
    aligned = write_aligned_set(tmp_path / "aligned", count=5, speakers=2, seconds=2.0)
    ds = tmp_path / "ds"
    proc = run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI)
    assert proc.returncode == 0, proc.stderr
    return aligned, ds


# ------------------------------------------------------------------ 1. a failed rebuild keeps the dataset


def test_rebuild_that_fails_on_a_take_leaves_the_previous_dataset_readable(built):
    aligned, ds = built
    before = _snapshot(ds)
    _add_take(aligned, "take05", seed=5, nan=96)
    proc = run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    (line,) = [x for x in proc.stderr.strip().splitlines() if not x.startswith("build: ")]
    assert "audio holds 96 NaN or infinite sample(s)" in line
    assert f"the previous dataset in {ds} is intact" in line
    assert _snapshot(ds) == before
    _readable(ds)


def test_rebuild_stopped_after_writing_new_shards_keeps_the_old_ones(built, tmp_path, monkeypatch):
    """Ctrl-C once the new dataset's shards are written, before its manifest: before, the old manifest was
    gone and its shards already overwritten; now both are as they were, and the rerun finishes the
    build from what was written, byte for byte a fresh build's."""
    aligned, ds = built
    before = _snapshot(ds)
    _add_take(aligned, "take05", seed=5)
    said = []
    monkeypatch.setenv("S2A_PROGRESS_INTERVAL_S", "0")  # every shard said: stopped after the second

    def say(message: str) -> None:
        said.append(message)
        if message.startswith("writing shards: ") and "] 2/" in message:
            raise KeyboardInterrupt()

    with pytest.raises(KeyboardInterrupt) as stopped:
        build_dataset([aligned], ds, _opts(), say=say)
    assert "is intact" in stopped.value.dataset_state
    assert _snapshot(ds) == before
    assert validate(ds).valid
    build_dataset([aligned], ds, _opts())
    fresh = tmp_path / "fresh"
    build_dataset([aligned], fresh, _opts())
    assert _dataset_files(ds) == _dataset_files(fresh)
    assert {p.name for p in (ds / ".work").iterdir()} == {"takes"}  # the take records only


def test_sigterm_during_a_rebuild_keeps_the_previous_dataset(tmp_path):
    aligned = write_aligned_set(tmp_path / "aligned", count=6, speakers=2, seconds=4.0)
    ds = tmp_path / "ds"
    assert run_here("dataset", "build", aligned, "-o", ds).returncode == 0
    before = _snapshot(ds)
    _add_take(aligned, "take06", seed=6)
    proc = subprocess.Popen(  # samples of another length: every take processed again
        [sys.executable, "-m", "dataset", "build", str(aligned), "-o", str(ds), "--max-sample-s", "3"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        for line in proc.stderr:  # the first take processed: six more to go, seconds of work
            if line.startswith("build: [") and " 1/7 " in line:
                proc.send_signal(signal.SIGTERM)
                break
        err = proc.stderr.read()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143 and "Traceback" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("s2a-dataset: terminated (SIGTERM); the previous dataset") and "intact" in last
    assert _snapshot(ds) == before
    _readable(ds)


def test_a_stop_during_the_swap_waits_for_it(built, monkeypatch):
    """Ctrl-C while the new shards are renamed into place: the swap finishes first (a manifest that
    matches its shards), then the build stops, saying the folder holds the new dataset."""
    aligned, ds = built
    _add_take(aligned, "take05", seed=5)
    real = build_module.write_manifest

    def ctrl_c_then_write(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        return real(*args, **kwargs)

    monkeypatch.setattr(build_module, "write_manifest", ctrl_c_then_write)
    with pytest.raises(KeyboardInterrupt) as stopped:
        build_dataset([aligned], ds, _opts())
    assert "holds the new dataset" in stopped.value.dataset_state
    splits = read_manifest(ds)["splits"]
    assert "take05" in [t for s in ("train", "val", "test") for t in splits[s]["takes"]]
    assert validate(ds, deep=True).valid


class _Killed(Exception):
    pass


def test_a_build_killed_in_the_swap_is_finished_by_the_next(built, tmp_path, monkeypatch):
    """The documented recovery: a kill between the shards' renames and the manifest (simulated) leaves a
    manifest that does not match its shards; the next build finishes the swap."""
    aligned, ds = built
    _add_take(aligned, "take05", seed=5)
    with monkeypatch.context() as m:
        m.setattr(build_module, "write_manifest", lambda *a, **k: (_ for _ in ()).throw(_Killed()))
        with pytest.raises(_Killed):
            build_dataset([aligned], ds, _opts())
    build_dataset([aligned], ds, _opts())
    fresh = tmp_path / "fresh"
    build_dataset([aligned], fresh, _opts())
    assert _dataset_files(ds) == _dataset_files(fresh)
    assert validate(ds, deep=True).valid


def test_a_build_killed_after_the_swaps_manifest_is_finished_by_the_next(built, monkeypatch):
    """A kill after the new manifest was written but before the shards it no longer lists were removed
    (a rebuild into fewer shards): the rerun found the dataset up to date and left them (shard_unlisted)."""
    aligned, ds = built
    before = sorted(p.name for p in ds.glob("*.tar"))
    bigger = {"shard_bytes": 64 * 1024 * 1024}  # one shard per split now
    with monkeypatch.context() as m:
        m.setattr(build_module, "_remove_unlisted_shards", lambda *a: (_ for _ in ()).throw(_Killed()))
        with pytest.raises(_Killed):
            build_dataset([aligned], ds, _opts(**bigger))
    assert sorted(p.name for p in ds.glob("*.tar")) == before  # the larger build's shards are still there
    summary = build_dataset([aligned], ds, _opts(**bigger))
    assert summary["up_to_date"]
    assert len(list(ds.glob("*.tar"))) == len(read_manifest(ds)["shards"]) < len(before)
    assert validate(ds, deep=True).valid and not validate(ds).problems


def test_a_stop_during_a_swap_that_fails_leaves_the_swaps_own_error():
    """SIGTERM held back during a swap that then failed (a full disk writing the manifest) replaced the
    swap's error with 'terminated'."""
    previous = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with pytest.raises(InputError, match="cannot be written"):
            with stops_deferred():
                signal.raise_signal(signal.SIGTERM)  # held back
                raise InputError("cannot be written: No space left on device")
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_rebuild_leaves_unchanged_shards_where_they_are(built):
    """Another normalisation changes the manifest, not a byte of the shards (they keep raw values): no
    shard is rewritten (each keeps its inode), though the manifest is new."""
    aligned, ds = built
    inodes = {p.name: p.stat().st_ino for p in ds.glob("*.tar")}
    manifest = (ds / "manifest.json").read_bytes()
    proc = run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI, "--normalization", "neutral")
    assert proc.returncode == 0, proc.stderr
    assert (ds / "manifest.json").read_bytes() != manifest
    assert {p.name: p.stat().st_ino for p in ds.glob("*.tar")} == inodes
    assert validate(ds, deep=True).valid


def test_up_to_date_rebuild_clears_the_cache_a_failed_rebuild_left(built):
    aligned, ds = built
    bad = _add_take(aligned, "take05", seed=5, nan=10)
    assert run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI).returncode == 1
    assert (ds / ".work").is_dir()
    shutil.rmtree(bad)  # back to the inputs of the dataset in the folder
    proc = run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI, "--json")
    assert proc.returncode == 0 and '"up_to_date": true' in proc.stdout, proc.stderr
    assert {p.name for p in (ds / ".work").iterdir()} == {"takes"}  # the take records only
    assert not [p for p in validate(ds).problems if p.code == "build_leftover"]


# ------------------------------------------------------------------ 2. readers next to a running build


def test_validate_and_stats_wait_for_a_running_build(built):
    _aligned, ds = built
    with output_lock(ds):  # what a running build holds
        for args in (("validate", ds), ("stats", ds), ("validate", ds / "manifest.json", "--json")):
            proc = run_here("dataset", *args)
            assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
            assert proc.stderr.strip() == (
                f"s2a-dataset: error: a build (pid {os.getpid()}) is writing into {ds}: wait for it to finish"
            )
    _readable(ds)  # the lock is gone with its build


def test_validate_during_a_first_build_says_a_build_is_running_not_no_dataset(tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    with output_lock(ds):
        proc = run_here("dataset", "validate", ds)
    assert proc.returncode == 1
    assert "is writing into" in proc.stderr and "not a dataset" not in proc.stderr, proc.stderr


# ------------------------------------------------------------------ 3. a take rewritten while it is read


def _swap_on_read(monkeypatch, take: Path, how: str) -> None:
    """Make the build's first read of ``take``'s metadata meet it as s2a-align --force rewriting it
    leaves it (``"swap"``: moved aside, then a new folder in its place) or as a take truly without
    meta.json (``"lost"``)."""
    real = build_module.read_meta
    done = []

    def read(folder):
        if Path(folder) != take or done:
            return real(folder)
        done.append(True)
        if how == "lost":
            (take / "meta.json").unlink()
            return real(folder)
        aside = take.with_name(f".{take.name}.old-test")
        os.replace(take, aside)  # the old take moved aside for the moment of the swap
        try:
            return real(folder)
        finally:
            shutil.copytree(aside, take)  # the new take in its place (another folder)
            shutil.rmtree(aside)

    monkeypatch.setattr(build_module, "read_meta", read)


def test_take_swapped_by_align_while_read_says_so(tmp_path, monkeypatch):
    aligned = write_aligned_set(tmp_path / "aligned", count=3, speakers=1, seconds=1.0)
    _swap_on_read(monkeypatch, aligned / "take01", "swap")
    with pytest.raises(InputError) as err:
        build_dataset([aligned], tmp_path / "ds", _opts())
    message = str(err.value)
    assert message.startswith(f"{aligned / 'take01'}: the take folder changed while it was read")
    assert f"is s2a-align writing into {aligned}?" in message and "no meta.json" not in message
    read_meta(aligned / "take01")  # the new take is there


def test_take_without_meta_json_still_says_so(tmp_path, monkeypatch):
    aligned = write_aligned_set(tmp_path / "aligned", count=3, speakers=1, seconds=1.0)
    _swap_on_read(monkeypatch, aligned / "take01", "lost")
    with pytest.raises(InputError) as err:
        build_dataset([aligned], tmp_path / "ds", _opts())
    assert str(err.value) == f"{aligned / 'take01'}: not a take folder (no meta.json)"


# ------------------------------------------------------------ 6. a rebuild processes only what changed


def test_adding_a_take_processes_that_take_only_and_equals_a_fresh_build(built, tmp_path):
    """The build removed its per-take work after success, so adding one take to N recomputed the
    features of all N + 1 (74.6 s against 80.6 s for a first build of 702 takes). The take records stay;
    the unchanged takes' samples come from the dataset's own shards, checked against their sha256."""
    aligned, ds = built
    _add_take(aligned, "take05", seed=5)
    proc = run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI)
    assert proc.returncode == 0, proc.stderr
    said = proc.stdout + proc.stderr
    assert re.search(r"\b(\d+) take\(s\) unchanged since the last build", said), said
    computed = [line for line in said.splitlines() if "s of audio" in line]
    assert len(computed) == 1 and "take05" in computed[0], said
    fresh = tmp_path / "fresh"
    assert run_here("dataset", "build", aligned, "-o", fresh, *SMALL_CLI).returncode == 0
    assert _dataset_files(ds) == _dataset_files(fresh)  # byte for byte
    assert {p.name for p in (ds / ".work").iterdir()} == {"takes"}
    assert validate(ds, deep=True).valid and not validate(ds).problems
    # a take removed: its records go too
    shutil.rmtree(aligned / "take05")
    assert run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI).returncode == 0
    assert not [p for p in (ds / ".work" / "takes").iterdir() if "take05" in p.name]


def test_a_damaged_shard_makes_its_takes_processed_again(built):
    aligned, ds = built
    shard = sorted(ds.glob("train-*.tar"))[0]
    shard.write_bytes(shard.read_bytes()[:1000])  # cut short
    _add_take(aligned, "take05", seed=5)
    proc = run_here("dataset", "build", aligned, "-o", ds, *SMALL_CLI)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert validate(ds, deep=True).valid
