"""A hostile trainer's review of the packaged shards: what a reader following docs/dataset.md alone finds
in them, and the reader (``ShardDataset``) on damaged or hand-edited datasets: a sample whose json names
another speaker than the manifest (its pitch normalised with the wrong statistics, or not at all), a
normalisation std too small to divide by, schema versions other than this toolkit's, and the members a
reader holds in its shuffle buffer. A real dataset of five 2 s takes (1 s samples), copied per test."""

from __future__ import annotations

import io
import json
import tarfile
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from capture.errors import InputError
from dataset.shards import ShardReader
from dataset.torch_dataset import ShardDataset


def _edit_manifest(ds: Path, edit) -> None:
    manifest = json.loads((ds / "manifest.json").read_text())
    edit(manifest)
    (ds / "manifest.json").write_text(json.dumps(manifest))


def test_docs_alone_read_what_shard_dataset_yields(built):
    """numpy, tarfile and json with the formulas of docs/dataset.md give ShardDataset's items."""
    m = json.loads((built / "manifest.json").read_text())
    anim = m["normalization"]["animation"]
    assert anim["kind"] == "zscore"
    offset, scale = np.array(anim["offset"]), np.array(anim["scale"])
    items = {item["key"]: item for item in ShardDataset(built, "val")}
    shard = next(s["name"] for s in m["shards"] if s["split"] == "val")
    samples: dict[str, dict[str, bytes]] = {}
    with tarfile.open(built / shard) as tar:
        for member in tar:
            key, ext = member.name.split(".", 1)
            samples.setdefault(key, {})[ext] = tar.extractfile(member).read()
    assert set(samples) == set(items) == {s["key"] for s in m["samples"] if s["split"] == "val"}
    for key, members in samples.items():
        meta = json.loads(members["json"])
        x = np.load(io.BytesIO(members["anim.npy"]))
        mask = np.load(io.BytesIO(members["mask.npy"]))
        assert x.dtype == np.float32 and x.shape == (meta["frames"], len(m["channels"]))
        assert mask.dtype == bool and mask.shape == (meta["frames"],)
        np.testing.assert_allclose(items[key]["anim"], (x - offset) / scale * mask[:, None], atol=1e-6)
        for name in m["features"]["names"]:
            f = np.load(io.BytesIO(members[f"{name}.npy"]))
            assert f.dtype == np.float32 and f.shape == (meta["frames"], m["features"]["dims"][name])
            if name == "pitch":
                st = m["normalization"]["pitch"]["speakers"][meta["speaker"]]
                f = np.stack([np.where(f[:, 1] > 0.5, (f[:, 0] - st["mean"]) / st["std"], 0), f[:, 1]], 1)
            else:
                st = m["normalization"]["features"][name]
                f = (f - np.array(st["mean"])) / np.array(st["std"])
            np.testing.assert_allclose(items[key][name], f, atol=1e-5)


def test_sample_naming_another_speaker_is_an_error(ds):
    """A sample json whose speaker is not the manifest's (damaged in place, the shard's size unchanged):
    the reader normalised its pitch with that name's statistics, or for an unknown name passed raw
    log-F0 (about 4.8 where the others lie within ±2) without a word. ``validate`` reports it too."""
    m = json.loads((ds / "manifest.json").read_text())
    sample = next(s for s in m["samples"] if s["split"] == "val")
    path = ds / sample["shard"]
    data = path.read_bytes()
    old = f'"speaker":"{sample["speaker"]}"'.encode()
    for other in ("spk9", "spk0" if sample["speaker"] != "spk0" else "spk1"):
        path.write_bytes(data.replace(old, old.replace(sample["speaker"].encode(), other.encode())))
        with pytest.raises(InputError, match=f"sample {sample['key']}: its json's speaker '{other}' is not"):
            list(ShardDataset(ds, "val"))


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda n: n["features"]["fbank"]["std"].__setitem__(3, 1e-45), "normalization.features.fbank.std"),
        (lambda n: n["pitch"]["speakers"]["spk0"].update(std=1e-300), "normalization.pitch.speakers.spk0"),
    ],
)
def test_std_too_small_to_divide_by_is_refused(ds, edit, field):
    """The build stores std 1 where a feature's or a speaker's log-F0 std is below 1e-6 (0 was refused
    already); a smaller positive one, hand-edited, made the reader yield infinite features silently."""
    _edit_manifest(ds, lambda m: edit(m["normalization"]))
    with pytest.raises(InputError, match=f"{field}.* at least 1e-6"):
        ShardDataset(ds, "train")


def test_schema_versions_other_than_this_toolkits_say_what_to_do(ds):
    """A newer dataset says a newer toolkit wrote it; one without a version (or an older one) says to
    rebuild; ``true`` (equal to 1 in Python) is not a version."""
    for version, hint in ((2, "a newer toolkit wrote it"), (None, "rebuild it"), (0, "rebuild it")):
        _edit_manifest(ds, lambda m, v=version: m.update(schema_version=v))
        with pytest.raises(
            InputError, match=f"schema version {version}, this toolkit reads version 1 .{hint}"
        ):
            ShardDataset(ds, "train")
    _edit_manifest(ds, lambda m: m.update(schema_version=True))
    with pytest.raises(InputError, match="schema version True"):
        ShardDataset(ds, "train")


def _peak_bytes(data: ShardDataset) -> int:
    """Peak traced Python memory of a pass over ``data`` (after a first pass: first-use allocations)."""
    assert sum(1 for _ in data) == len(data)
    tracemalloc.start()
    try:
        for _ in data:
            pass
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_shuffle_buffer_holds_only_the_members_read(built):
    """A shuffle buffer as large as the split held every sample's FLAC also with ``audio=False``
    (buffering raised the peak by 213 kB, the split's FLAC being 209 kB): the reader now skips the
    members it does not decode (56 kB)."""
    m = json.loads((built / "manifest.json").read_text())
    shards = [built / s["name"] for s in m["shards"] if s["split"] == "train"]
    flac_bytes = sum(len(members["flac"]) for shard in shards for _key, members in ShardReader(shard))
    read = {"window": 30, "features": "fbank"}
    buffered = _peak_bytes(ShardDataset(built, "train", shuffle_buffer=64, **read))
    unbuffered = _peak_bytes(ShardDataset(built, "train", **read))
    assert buffered - unbuffered < flac_bytes / 2, (buffered, unbuffered, flac_bytes)
    # ShardReader(exts): those members only, every sample still
    for shard in shards:
        read_back = list(ShardReader(shard, {"json", "flac"}))
        assert [key for key, _ in read_back] == sorted(
            s["key"] for s in m["samples"] if s["shard"] == shard.name
        )
        assert all(set(members) == {"json", "flac"} for _key, members in read_back)
