"""s2a-dataset validate decodes each sample's JSON metadata once, on the quick and the deep path, and
reports metadata that does not decode as before."""

from __future__ import annotations

import io
import json
import shutil
import tarfile
from collections import Counter
from pathlib import Path

import pytest
from dataset_helpers import build_five_take_dataset

from dataset import qa, shards
from dataset.shards import ShardReader


@pytest.fixture(scope="module")
def ds(tmp_path_factory) -> Path:
    return build_five_take_dataset(tmp_path_factory.mktemp("decode_once"))


def _sample_json(ds: Path) -> dict[bytes, str]:
    """Each sample's ``json`` member (bytes) and the sample's key, over every shard of ``ds``."""
    found = {}
    for entry in json.loads((ds / "manifest.json").read_text())["shards"]:
        for key, members in ShardReader(ds / entry["name"]):
            found[members["json"]] = key
    return found


def _count_loads(monkeypatch) -> Counter:
    """Count json.loads by its argument, as the shard module (the sample decoder's) calls it."""
    calls: Counter = Counter()
    loads = json.loads

    def counting(data, *args, **kwargs):
        calls[bytes(data) if isinstance(data, (bytes, bytearray)) else data] += 1
        return loads(data, *args, **kwargs)

    monkeypatch.setattr(shards.json, "loads", counting)
    return calls


@pytest.mark.parametrize("deep", [False, True], ids=["quick", "deep"])
def test_each_sample_json_is_decoded_once(ds, monkeypatch, deep):
    samples = _sample_json(ds)
    assert len(samples) >= 5
    calls = _count_loads(monkeypatch)
    report = qa.validate(ds, deep=deep)
    assert report.valid and report.problems == []
    assert report.samples == len(samples)
    assert {samples[data]: calls[data] for data in samples} == {key: 1 for key in samples.values()}


def test_metadata_that_does_not_decode_is_reported_once_and_decoded_once(ds, tmp_path, monkeypatch):
    broken = shutil.copytree(ds, tmp_path / "ds")
    shard = next(iter(sorted(broken.glob("*.tar"))))
    with tarfile.open(shard) as tar:
        members = [(m.name, tar.extractfile(m).read()) for m in tar.getmembers()]
    name = next(n for n, _ in members if n.endswith(".json"))
    key = name[: -len(".json")]
    bad = b'{"key": "not closed"'
    with tarfile.open(shard, "w") as tar:
        for n, data in members:
            data = bad if n == name else data
            info = tarfile.TarInfo(n)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    calls = _count_loads(monkeypatch)
    report = qa.validate(broken)
    decode = [p for p in report.problems if p.code == "sample_decode"]
    assert [p.location for p in decode] == [f"{shard.name}:{key}.json"]
    assert decode[0].message.startswith("metadata is not a JSON object (")
    assert calls[bad] == 1
    # the sample's frames are not counted: the shard's total differs from the manifest's
    assert any(p.code == "shard_contents" and p.location == shard.name for p in report.problems)
