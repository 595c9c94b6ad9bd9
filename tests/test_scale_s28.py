"""The dataset build at scale and its ``.work`` folder. The records an interrupted build leaves in
``.work`` (take records, shard records, the splits a rebuild replaces, aligned copies) held a name not
UTF-8 (a take, a speaker) as a lone surrogate (``"\\udce9"``), where the manifest and the shards write it
as shown text and its bytes (``capture.errors.strict_names``). Real files, real builds."""

from __future__ import annotations

import json
import os
from pathlib import Path

from dataset_helpers import make_aligned_take

from capture.errors import loads_names
from capture.take import write_take
from dataset import BuildOptions, build_dataset
from dataset.manifest import WORK, read_manifest

_CAFE = os.fsdecode(b"caf\xe9")  # a name in Latin-1, as another system's file name gives it


def _strict(path: Path) -> object:
    """JSON as a strict reader reads it: UTF-8, no lone surrogate (escaped or not)."""
    text = path.read_bytes().decode("utf-8")
    assert "\\udc" not in text.lower(), f"{path}: {text[:200]}"
    return json.loads(text)


def _takes(root: Path, ids: list[str], speaker: str = _CAFE) -> Path:
    for i, take_id in enumerate(ids):
        write_take(make_aligned_take(take_id, 1.0, subject=speaker if i % 2 else "bob", seed=i), root)
    return root


def test_the_work_records_are_strict_json_and_a_later_build_reuses_them(tmp_path):
    """Every JSON record in ``.work`` (kept, as a stopped build leaves them) is strict (the speaker
    ``caf\\xe9`` shown, its bytes beside it), and a later build takes the takes from them, the speaker
    read back as the same name."""
    takes = _takes(tmp_path / "takes", [f"take{i}" for i in range(5)])
    said: list[str] = []
    options = BuildOptions(features=("fbank",), keep_work=True)
    build_dataset([takes], tmp_path / "ds", options, say=said.append)
    records = sorted((tmp_path / "ds" / WORK).rglob("*.json"))
    assert len(records) >= 6  # five takes' records, the shards'
    for record in records:
        _strict(record)
    assert any(r.get("speaker_b64") for r in map(_strict, records))  # the name's bytes beside it
    # a record as builds before wrote it (the speaker a lone surrogate) is read as it was
    old = tmp_path / "ds" / WORK / "takes" / "take1.json"
    old.write_text(json.dumps(loads_names(old.read_text(encoding="utf-8"))), encoding="utf-8")
    assert "\\udce9" in old.read_text(encoding="utf-8")
    write_take(make_aligned_take("take9", 1.0, subject="bob", seed=9), takes)  # the inputs changed
    said.clear()
    build_dataset([takes], tmp_path / "ds", options, say=said.append)
    assert any("5 from the cache" in line for line in said), said
    assert {s["speaker"] for s in read_manifest(tmp_path / "ds")["samples"]} == {_CAFE, "bob"}
