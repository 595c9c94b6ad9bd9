"""Review of the shards hashed as they are read: the "hashed once per process" memory tells a shard
replaced by another file of the same size and modification time (``cp -p``) from the one it hashed."""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

import pytest
from dataset_helpers import build_five_take_dataset
from test_dataset_leftovers_s22 import _flip_a_finite_value, _train_shard

from capture.errors import InputError
from dataset.torch_dataset import ShardDataset


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    return build_five_take_dataset(tmp_path_factory.mktemp("review_s22"))


@pytest.fixture
def ds(built, tmp_path) -> Path:
    return Path(shutil.copytree(built, tmp_path / "ds", ignore=shutil.ignore_patterns(".work")))


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
