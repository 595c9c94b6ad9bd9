"""Leftovers of the dataset stage: importing ``dataset.torch_dataset`` (what a spawned DataLoader worker
does) no longer imports the build, its features, PPG and pitch tracking; ``s2a-dataset build`` says its
warnings on stderr; a shard whose bytes changed in place (a finite value flipped) is found by the reader
and by ``validate`` without ``--deep``; a member twice in a sample is damage in every mode of reading."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import ROOT, run_here
from dataset_helpers import make_aligned_take
from test_import_guard_window import CHECK

from capture import write_take
from capture.errors import InputError
from capture.import_guard import COMMANDS
from capture.take import sha256_file
from dataset.manifest import read_manifest, write_manifest
from dataset.qa import validate
from dataset.shards import ShardReader
from dataset.torch_dataset import ShardDataset, check_shards

HEAVY = ("dataset.build", "dataset.features", "dataset.ppg", "dataset.pitch", "dataset.qa")


# -- 1. the package imports lazily -------------------------------------------------------------------------
def test_a_dataloader_worker_importing_the_reader_imports_no_build():
    """A spawned worker re-imports dataset.torch_dataset: the eager package imported the build, its
    features (scipy), PPG, pitch tracking and the validator too."""
    check = f"import sys, dataset.torch_dataset; print([m for m in {HEAVY!r} if m in sys.modules])"
    proc = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, cwd=ROOT)
    assert proc.stdout.strip() == "[]", proc.stdout + proc.stderr


def test_every_name_the_package_exports_is_there_on_first_use():
    check = (
        "import dataset; names = list(dataset.__all__); from dataset import *; "
        "print(len(names), all(globals()[n] is getattr(dataset, n) for n in names)); "
        "from dataset import ShardReader, build_dataset, validate; dataset.nothing_of_that_name"
    )
    proc = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, cwd=ROOT)
    assert proc.stdout.split() == ["34", "True"], proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        "AttributeError: module 'dataset' has no attribute 'nothing_of_that_name'"
    )


def test_the_guard_still_covers_s2a_datasets_imports():
    """s2a-dataset's command module imports what the package no longer does, under the guard."""
    check = CHECK.format(package="dataset") + f"print(all(m in sys.modules for m in {HEAVY!r}))\n"
    proc = subprocess.run(
        [sys.executable, "-c", check, COMMANDS["dataset"]], capture_output=True, text=True, cwd=ROOT
    )
    assert proc.stdout.split() == ["True", "True", "True"], proc.stdout + proc.stderr


# -- 2. build warnings on stderr ---------------------------------------------------------------------------
def test_build_says_its_warnings_on_stderr_and_its_result_on_stdout(tmp_path):
    for i in range(2):
        take = make_aligned_take(f"t{i}", 1.2, subject="s0", seed=i)
        take.meta.extra["align"]["flags"] = ["low_confidence"]
        write_take(take, tmp_path / "takes")
    proc = run_here("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds", "--features", "fbank")
    assert proc.returncode == 0, proc.stderr
    assert len(proc.stdout.splitlines()) == 1 and "2 takes" in proc.stdout, proc.stdout
    warned = [line for line in proc.stderr.splitlines() if line.startswith("s2a-dataset: warning: take t0:")]
    assert warned and "low_confidence" in warned[0], proc.stderr


# -- 3. a shard's bytes checked against the manifest's sha256 as it is read --------------------------------
def _train_shard(ds: Path) -> Path:
    (shard,) = [s["name"] for s in read_manifest(ds)["shards"] if s["split"] == "train"]
    return ds / shard


def _flip_a_finite_value(shard: Path) -> None:
    """The last byte of the last sample's first animation value changed: still finite, same size."""
    with tarfile.open(shard) as tar:
        member = [m for m in tar if m.name.endswith(".anim.npy")][-1]
        data = tar.extractfile(member).read()
    x = np.load(io.BytesIO(data))
    value_at = member.offset_data + len(data) - x.nbytes  # the array's first value, past the .npy header
    raw = bytearray(shard.read_bytes())
    raw[value_at] ^= 0x01  # the lowest mantissa bit of a float32
    shard.write_bytes(bytes(raw))
    changed = np.frombuffer(bytes(raw[value_at : value_at + 4]), np.float32)[0]
    assert np.isfinite(changed) and changed != x.flat[0]


def test_a_finite_value_flipped_in_a_shard_is_found_by_the_reader_and_validate(ds):
    shard = _train_shard(ds)
    good = sha256_file(shard)
    _flip_a_finite_value(shard)
    read = ShardReader(shard, {"json", "anim.npy"}, good)  # the audio skipped: hashed all the same
    differs = r"sha256 \w{16}\.\.\. differs from the manifest's"
    with pytest.raises(InputError, match=differs) as caught:
        for _ in read:
            pass
    assert caught.value.path == str(shard) and read.digest == sha256_file(shard)
    with pytest.raises(InputError, match="its bytes changed since the build") as caught:
        list(ShardDataset(ds, "train"))
    assert caught.value.path == str(shard)
    assert len(list(ShardDataset(ds, "train", verify_sha256=False))) == 6  # the documented way off
    report = validate(ds)  # without --deep
    assert [(p.code, p.location) for p in report.problems] == [("shard_checksum", shard.name)]


def test_a_shard_hashed_in_one_epoch_is_hashed_again_once_its_file_changed(ds):
    """A process hashes a shard once while its file stays the same: a change in place is seen."""
    data = ShardDataset(ds, "train")
    assert len(list(data)) == len(list(data)) == 6
    _flip_a_finite_value(_train_shard(ds))
    with pytest.raises(InputError, match="differs from the manifest's"):
        list(data)


def test_workers_sharing_a_damaged_shard_find_it(ds):
    """Two workers (or ranks) and one shard of six samples: each keeps every second one; the one reading
    its end hashes it, the other leaves it after its fifth."""
    _flip_a_finite_value(_train_shard(ds))
    loader = torch.utils.data.DataLoader(ShardDataset(ds, "train"), batch_size=1, num_workers=2)
    with pytest.raises(InputError, match="differs from the manifest's"):
        list(loader)
    assert len(list(ShardDataset(ds, "train", rank=0, world_size=2))) == 3  # leaves early: not hashed
    with pytest.raises(InputError, match="differs from the manifest's"):
        list(ShardDataset(ds, "train", rank=1, world_size=2))


def test_a_clean_dataset_reads_with_its_shards_hashed(built):
    (a,) = [s for s in read_manifest(built)["shards"] if s["split"] == "train"]
    read = ShardReader(built / a["name"], sha256=a["sha256"])
    assert sum(1 for _ in read) == a["samples"] and read.digest == a["sha256"]
    loader = torch.utils.data.DataLoader(ShardDataset(built, "train"), batch_size=1, num_workers=2)
    assert len(list(loader)) == a["samples"]


# -- 4. a member twice in a sample -------------------------------------------------------------------------
def _flac_twice(ds: Path) -> Path:
    """The train shard rewritten with its first sample's audio twice in a row, the manifest updated to
    match (a shard written by other tools): only the reader can tell."""
    shard = _train_shard(ds)
    with tarfile.open(shard) as tar:
        members = [(m, tar.extractfile(m).read()) for m in tar]
    flac = next(i for i, (m, _) in enumerate(members) if m.name.endswith(".flac"))
    members.insert(flac + 1, members[flac])
    with tarfile.open(shard, "w", format=tarfile.PAX_FORMAT) as tar:
        for m, data in members:
            tar.addfile(m, io.BytesIO(data))
    manifest = read_manifest(ds)
    entry = next(s for s in manifest["shards"] if s["name"] == shard.name)
    entry.update(bytes=shard.stat().st_size, sha256=sha256_file(shard))
    write_manifest(ds, manifest)
    return shard


READERS = {
    "reader, every member": lambda ds, shard: list(ShardReader(shard)),
    "reader, the audio skipped": lambda ds, shard: list(ShardReader(shard, {"json", "anim.npy"})),
    "ShardDataset without audio": lambda ds, shard: list(ShardDataset(ds, "train")),
    "ShardDataset with audio": lambda ds, shard: list(ShardDataset(ds, "train", audio=True)),
    "check_shards (headers)": lambda ds, shard: check_shards(ds, read_manifest(ds), ("train",)),
}


@pytest.mark.parametrize("read", READERS.values(), ids=READERS.keys())
def test_a_member_twice_is_damage_in_every_mode(ds, read):
    shard = _flac_twice(ds)
    with pytest.raises(InputError, match=r"member \S+\.flac appears twice") as caught:
        read(ds, shard)
    assert caught.value.path == str(shard)


def test_validate_reports_a_member_twice(ds):
    shard = _flac_twice(ds)
    report = validate(ds)
    problems = [(p.code, p.location) for p in report.problems]
    assert ("shard_unreadable", shard.name) in problems and not report.valid
    assert json.loads(json.dumps(report.to_json()))["valid"] is False


# -- review: a shard replaced with cp -p is hashed again -------------------------------------------------
def test_a_shard_replaced_by_cp_p_with_its_size_and_mtime_is_hashed_again(ds, tmp_path):
    """A damaged copy given the shard's modification time, copied over it with ``cp -p``: same path,
    inode, size and mtime; only the change time tells the file is not the one hashed in epoch 0."""
    shard = _train_shard(ds)
    damaged = tmp_path / shard.name
    shutil.copyfile(shard, damaged)
    _flip_a_finite_value(damaged)
    kept = shard.stat()
    subprocess.run(["touch", "-r", str(shard), str(damaged)], check=True)
    data = ShardDataset(ds, "train")
    assert len(list(data)) == 6  # epoch 0: the shard hashed, the manifest's
    time.sleep(0.02)  # past the file system's clock tick
    subprocess.run(["cp", "-p", str(damaged), str(shard)], check=True)
    now = shard.stat()
    assert (now.st_ino, now.st_size, now.st_mtime_ns) == (kept.st_ino, kept.st_size, kept.st_mtime_ns)
    with pytest.raises(InputError, match="differs from the manifest's") as caught:
        list(data)
    assert caught.value.path == str(shard)
