"""s2a-dataset validate: ten injected corruptions, each reported with its location and exit code 1."""

from __future__ import annotations

import io
import json
import shutil
import tarfile
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_cli
from dataset_helpers import build_default_dataset

from dataset.qa import CHECKS, VALIDATORS, moments, validate, validate_takes


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    return build_default_dataset(tmp_path_factory.mktemp("clean"))


def _manifest(ds: Path) -> dict:
    return json.loads((ds / "manifest.json").read_text())


def _save_manifest(ds: Path, m: dict) -> None:
    (ds / "manifest.json").write_text(json.dumps(m, indent=2))


def _shard(ds: Path, split: str = "train") -> Path:
    return ds / next(s["name"] for s in _manifest(ds)["shards"] if s["split"] == split)


def _rewrite(shard: Path, edit) -> None:
    """Rewrite a shard through ``edit(list of [name, bytes]) -> list`` (a user-made damaged shard)."""
    with tarfile.open(shard) as tar:
        members = [[m.name, tar.extractfile(m).read()] for m in tar.getmembers()]
    members = edit(members)
    with tarfile.open(shard, "w") as tar:
        for name, data in members:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _edit_member(suffix: str, change):
    def edit(members):
        for m in members:
            if m[0].endswith(suffix):
                m[1] = change(m[1])
                break
        return members

    return edit


def flip_byte(ds):
    p = _shard(ds)
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x01
    p.write_bytes(bytes(data))


def truncate(ds):
    p = _shard(ds)
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2 + 100])


def remove(ds):
    _shard(ds, "test").unlink()


def manifest_checksum(ds):
    m = _manifest(ds)
    m["shards"][0]["sha256"] = "0" * 64
    _save_manifest(ds, m)


def nan_feature(ds):
    def change(b):
        a = np.load(io.BytesIO(b))
        a[5, 3] = np.nan
        return _npy(a)

    _rewrite(_shard(ds), _edit_member(".fbank.npy", change))


def channel_count(ds):
    _rewrite(_shard(ds), _edit_member(".anim.npy", lambda b: _npy(np.load(io.BytesIO(b))[:, :-1])))


def length_mismatch(ds):
    _rewrite(_shard(ds), _edit_member(".energy.npy", lambda b: _npy(np.load(io.BytesIO(b))[:-3])))


def take_in_two_splits(ds):
    # a copy of a train sample under a new key, filed in the test shard
    with tarfile.open(_shard(ds)) as tar:
        first = [[m.name, tar.extractfile(m).read()] for m in tar.getmembers()]
    key = first[0][0].split(".", 1)[0]
    copy = [[n.replace(key, "zz_leak", 1), d] for n, d in first if n.startswith(key + ".")]
    for m in copy:
        if m[0].endswith(".json"):
            meta = json.loads(m[1])
            meta.update(key="zz_leak", split="test")
            m[1] = json.dumps(meta).encode()
    _rewrite(_shard(ds, "test"), lambda members: members + copy)


def duplicate_key(ds):
    with tarfile.open(_shard(ds)) as tar:
        first = [[m.name, tar.extractfile(m).read()] for m in tar.getmembers()]
    key = first[0][0].split(".", 1)[0]
    again = [m for m in first if m[0].startswith(key + ".")]
    _rewrite(_shard(ds, "val"), lambda members: members + again)


def wrong_sample_rate(ds):
    def change(b):
        x, rate = sf.read(io.BytesIO(b))
        buf = io.BytesIO()
        sf.write(buf, x, 22050, format="FLAC")
        return buf.getvalue()

    _rewrite(_shard(ds), _edit_member(".flac", change))


CASES = [
    (flip_byte, True, "shard_checksum"),
    (truncate, False, "shard_size"),
    (remove, False, "shard_missing"),
    (manifest_checksum, True, "shard_checksum"),
    (nan_feature, False, "nonfinite"),
    (channel_count, False, "channel_count"),
    (length_mismatch, False, "length_mismatch"),
    (take_in_two_splits, False, "split_leakage"),
    (duplicate_key, False, "duplicate_key"),
    (wrong_sample_rate, False, "sample_rate"),
]


@pytest.mark.parametrize(("corrupt", "deep", "code"), CASES, ids=[c[0].__name__ for c in CASES])
def test_each_corruption_is_reported(clean, tmp_path, corrupt, deep, code):
    ds = tmp_path / "ds"
    shutil.copytree(clean, ds)
    corrupt(ds)
    args = ["dataset", "validate", ds, "--json"] + (["--deep"] if deep else [])
    proc = run_cli(*args)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    report = json.loads(proc.stdout)
    assert not report["valid"]
    codes = {p["code"] for p in report["problems"]}
    assert code in codes, report["problems"]
    where = [p["location"] for p in report["problems"] if p["code"] == code]
    assert all(where) and "Traceback" not in proc.stderr
    human = run_cli(*args[:-1] if not deep else [a for a in args if a != "--json"])
    assert human.returncode == 1 and f"[{code}]" in human.stdout


def test_clean_dataset_has_no_problems_and_checks_are_data(clean):
    report = validate(clean, deep=True)
    assert report.valid and report.problems == []
    assert set(VALIDATORS) == {"manifest", "shard", "sample", "splits", "takes"}
    assert len({c.code for c in CHECKS}) == len(CHECKS) >= 20


def test_still_channel_flags_a_take_that_leaves_an_animated_channel_still():
    rng = np.random.default_rng(0)
    channels = ["jawOpen", "mouthFunnel", "cheekPuff"]
    fps = 30.0

    def take(seconds: float, still: bool) -> np.ndarray:
        x = np.abs(rng.normal(0.0, [0.15, 0.1, 0.005], size=(int(seconds * fps), 3)))
        if still:
            x[:, 1] = 0.01 + rng.normal(0.0, 0.002, len(x))  # funnel barely moves in this take
        return x

    def seen(*takes):
        return [{"meta": {"take": name}, "moments": moments(x)} for name, x in takes]

    manifest = {"channels": channels, "fps": fps}
    found = validate_takes(manifest, seen(*((f"t{i}", take(40, i == 2)) for i in range(4))))
    assert [(p.code, p.location, p.severity) for p in found] == [("still_channel", "take t2", "warning")]
    # the still channel is named with its std; cheekPuff hardly moves anywhere, so it is not
    assert "mouthFunnel (std 0.002" in found[0].message and "cheekPuff" not in found[0].message
    # a take's samples add up: t2 in two 20 s samples is judged as one 40 s take
    halves = [("t0", take(40, False)), ("t1", take(40, False)), ("t3", take(40, False))]
    parts = [("t2", take(20, True)), ("t2", take(20, True))]
    assert [p.location for p in validate_takes(manifest, seen(*halves, *parts))] == ["take t2"]
    # short takes are not judged, and two takes give no majority
    assert validate_takes(manifest, seen(*halves, ("t2", take(20, True)))) == []
    assert validate_takes(manifest, seen(("t0", take(40, False)), ("t2", take(40, True)))) == []
    # samples without usable animation or take metadata are skipped
    assert (
        validate_takes(manifest, [{"meta": None, "moments": None}, {"meta": {"take": "x"}, "moments": None}])
        == []
    )
