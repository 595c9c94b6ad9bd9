"""Inputs a fuzzer found escaping as tracebacks: a .npy header cut short, sample metadata and manifest
fields of the wrong type (``s2a-dataset validate`` lists them, every reader refuses them), checkpoints
whose contents do not fit their weights (refused before a model is built), and alignment JSON keys
that do not name a file inside the JSON's folder."""

from __future__ import annotations

import io
import json
import re
import shutil
import struct
import tarfile
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_here
from dataset_helpers import build_default_dataset
from test_ppg_robustness import _json, _phone, _wav
from test_train_pipeline import TINY

from capture.errors import InputError
from dataset import read_manifest
from dataset.qa import validate
from dataset.shards import decode_npy
from train.alignments import find_alignments
from train.checkpoint import load_system
from train.config import resolve_config
from train.fit import fit


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    return build_default_dataset(tmp_path_factory.mktemp("fuzzfix"))


@pytest.fixture(scope="module")
def run(clean, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fuzzrun") / "run"
    fit(clean, out, resolve_config(sets=TINY + ["max_steps=2", "eval_every=2"]), say=lambda _m: None)
    return out


def _copy(clean: Path, tmp_path: Path) -> Path:
    ds = tmp_path / "ds"
    shutil.copytree(clean, ds)
    return ds


def _edit_member(ds: Path, suffix: str, change) -> None:
    """Rewrite the first member ending in ``suffix`` of the train shard through ``change(bytes)``."""
    manifest = json.loads((ds / "manifest.json").read_text())
    shard = ds / next(s["name"] for s in manifest["shards"] if s["split"] == "train")
    with tarfile.open(shard) as tar:
        members = [[m.name, tar.extractfile(m).read()] for m in tar.getmembers()]
    name = next(m for m in members if m[0].endswith(suffix))
    name[1] = change(name[1])
    with tarfile.open(shard, "w") as tar:
        for member, data in members:
            info = tarfile.TarInfo(member)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))


def _edit_manifest(ds: Path, edit) -> None:
    m = json.loads((ds / "manifest.json").read_text())
    edit(m)
    (ds / "manifest.json").write_text(json.dumps(m))


def _problems(ds: Path, deep: bool = False) -> list[tuple[str, str, str]]:
    report = validate(ds, deep=deep)
    assert not report.valid
    return [(p.code, p.location, p.message) for p in report.problems]


def _npy_with_header(header: bytes, data: bytes = b"") -> bytes:
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + data


# 1a. .npy headers


def test_npy_header_cut_short_or_declaring_a_huge_shape_is_an_input_error():
    unclosed = _npy_with_header(b"{'descr': '<f4', 'fortran_order': False, 'shape': (3,")
    with pytest.raises(InputError, match=r"anim.npy is not a readable .npy \(its header is cut short"):
        decode_npy(unclosed, "anim.npy")
    huge = _npy_with_header(
        b"{'descr': '<f8', 'fortran_order': False, 'shape': (10000000000000,), }", b"\0" * 16
    )
    with pytest.raises(InputError, match=r"declares shape \(10000000000000,\) .* the file holds 16"):
        decode_npy(huge, "anim.npy")
    for array in (
        np.arange(12, dtype=np.float32).reshape(3, 4),
        np.asfortranarray(np.eye(3)),
        np.zeros(0, bool),
    ):
        buf = io.BytesIO()
        np.save(buf, array)
        back = decode_npy(buf.getvalue())
        assert back.dtype == array.dtype and np.array_equal(back, array) and back.flags.writeable


def test_validate_lists_a_npy_header_cut_short(clean, tmp_path):
    ds = _copy(clean, tmp_path)
    _edit_member(ds, ".anim.npy", lambda b: b[:10] + b[10:].replace(b")", b" ", 1).replace(b"}", b" ", 1))
    found = _problems(ds)
    assert any(code == "sample_decode" and where.endswith(".anim.npy") for code, where, _ in found), found


# 1b. sample metadata


@pytest.mark.parametrize(
    "value, message",
    [(0, "metadata.take must be a string, not 0"), ([], "metadata.take must be a string, not []")],
)
def test_validate_lists_a_sample_take_of_the_wrong_type(clean, tmp_path, value, message):
    ds = _copy(clean, tmp_path)
    _edit_member(ds, ".json", lambda b: json.dumps(json.loads(b) | {"take": value}).encode())
    found = _problems(ds)
    assert any(code == "sample_decode" and msg == message for code, _, msg in found), found


def test_validate_lists_sample_metadata_nested_too_deeply(clean, tmp_path):
    ds = _copy(clean, tmp_path)
    _edit_member(ds, ".json", lambda b: b"[" * 100_000 + b"]" * 100_000)
    found = _problems(ds)
    assert ("sample_decode", "metadata is not a JSON object (nested too deeply)") in {
        (code, msg) for code, _, msg in found
    }, found


# 1c. manifest fields


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda m: m.update(members=[*m["members"][:3], None]), "members"),
        (lambda m: m.update(members=10**30), "members"),
        (lambda m: m["shards"][0].update(split=[]), "shards[0].split"),
        (lambda m: m["normalization"].pop("features"), "normalization.features"),
        (lambda m: m["normalization"].update(features="x"), "normalization.features"),
        (lambda m: m["features"].pop("dims"), "features.dims"),
    ],
    ids=[
        "members-null",
        "members-int",
        "split-list",
        "features-norm-missing",
        "features-norm-str",
        "no-dims",
    ],
)
def test_manifest_fields_of_the_wrong_type_are_listed_and_refused(clean, tmp_path, edit, field):
    ds = _copy(clean, tmp_path)
    _edit_manifest(ds, edit)
    for deep in (False, True):
        found = _problems(ds, deep)
        assert ("manifest_schema", f"manifest.json:{field}") in {(c, w) for c, w, _ in found}, found
    with pytest.raises(InputError, match=re.escape(f"manifest field {field} ")):
        read_manifest(ds)
    proc = run_here("dataset", "validate", ds)
    assert proc.returncode == 1 and "[manifest_schema]" in proc.stdout and "Traceback" not in proc.stderr


# 2. checkpoints whose contents do not fit


def _set(path: list, value):
    def edit(p):
        target = p
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return edit


CHECKPOINTS = [
    (_set(["dataset", "features", "dims"], 10**30), "malformed dataset 'features.dims'"),
    (_set(["inputs", "content"], [1, 2]), "malformed inputs"),
    (_set(["model_config"], "x"), "malformed 'model_config'"),
    (_set(["dataset", "normalization", "pitch", "speakers"], 2**40), "normalization.pitch.speakers"),
    (_set(["dataset", "normalization", "animation", "offset"], []), "normalization.animation.offset"),
    (
        _set(["dataset", "normalization", "features", "fbank", "std"], [1.0, 1.0]),
        "normalization.features.fbank",
    ),
    (_set(["inputs", "prosody_dim"], 2**40), "prosody_dim 1099511627776"),
    (_set(["config", "arch", "encoder_layers"], 10**12), "malformed arch.encoder_layers"),
    (_set(["config", "arch", "ff_dim"], 4096), "malformed state_dict"),
    (_set(["config", "arch", "max_frames"], 10**9), "bytes of tables when built"),
]


@pytest.mark.parametrize("edit, needle", CHECKPOINTS, ids=[n for _, n in CHECKPOINTS])
def test_checkpoint_contents_that_do_not_fit_are_refused_before_building(run, tmp_path, edit, needle):
    payload = torch.load(run / "last.pt", weights_only=True)
    edit(payload)
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(InputError, match="bad.pt: ") as err:
        load_system(tmp_path / "bad.pt")
    assert needle in str(err.value)


def test_eval_of_a_checkpoint_with_malformed_pitch_statistics_is_one_line(run, clean, tmp_path):
    payload = torch.load(run / "last.pt", weights_only=True)
    payload["dataset"]["normalization"]["pitch"]["speakers"] = {"spk": {"mean": "", "std": 1.0}}
    torch.save(payload, tmp_path / "bad.pt")
    proc = run_here("train", "eval", tmp_path / "bad.pt", "--data", clean)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "normalization.pitch.speakers.spk" in proc.stderr


# 3. alignment JSON keys


@pytest.mark.parametrize("key", ["/", "", ".", "../utt", "/tmp/utt", "sub/../../utt"])
def test_alignment_key_outside_the_json_folder_is_one_line(tmp_path, key):
    folder = tmp_path / "a"
    _wav(tmp_path / "utt.wav")  # audio beside the folder, that a ../ key would reach
    path = _json(folder, _phone())
    path.write_text(json.dumps({key: {"words": _phone()}}))
    with pytest.raises(InputError, match=f"utterance key {json.dumps(key)} must name an audio file inside"):
        find_alignments([folder])
    proc = run_here("train", "ppg", "--data", folder, "-o", tmp_path / "p.pt")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


def test_alignment_key_in_a_subfolder_is_read(tmp_path):
    _wav(tmp_path / "sub" / "utt.wav")
    (tmp_path / "align.json").write_text(json.dumps({"sub/utt": {"words": _phone()}}))
    [(audio, _segs)] = find_alignments([tmp_path / "align.json"])
    assert audio == tmp_path / "sub" / "utt.wav"
