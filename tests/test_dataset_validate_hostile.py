"""s2a-dataset validate / stats and the shard reader against hostile datasets: a manifest that lists a
sample twice, and a dataset swapped in (as a build does) while validate reads it."""

from __future__ import annotations

import io
import json
import os
import shutil
import sys
from pathlib import Path

import pytest
from conftest import run_cli
from dataset_helpers import build_five_take_dataset

from capture.errors import InputError
from dataset import cli
from dataset.torch_dataset import ShardDataset


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    return build_five_take_dataset(tmp_path_factory.mktemp("hostile"))


@pytest.fixture
def ds(built, tmp_path) -> Path:
    """A fresh copy of the built dataset, on a path with a space and a non-ASCII letter."""
    copy = tmp_path / "data sét"
    shutil.copytree(built, copy)
    return copy


def test_a_sample_listed_twice_is_named_by_validate_stats_and_the_reader(ds):
    manifest = json.loads((ds / "manifest.json").read_text())
    manifest["samples"].append(dict(manifest["samples"][0]))  # a hand-merged manifest
    (ds / "manifest.json").write_text(json.dumps(manifest))
    key = manifest["samples"][0]["key"]
    twice = f"samples[{len(manifest['samples']) - 1}].key: '{key}' is listed twice (also samples[0])"

    proc = run_cli("dataset", "validate", ds)
    assert proc.returncode == 1, proc.stdout
    assert twice in proc.stdout and "Traceback" not in proc.stderr
    # stats used to count the sample's hours twice and exit 0
    proc = run_cli("dataset", "stats", ds)
    assert proc.returncode == 1 and "is listed twice" in proc.stderr
    assert "Traceback" not in proc.stderr
    with pytest.raises(InputError, match="is listed twice"):
        ShardDataset(ds, "train")


class _SwapOnProgress(io.StringIO):
    """stderr that, at validate's first progress line, replaces the manifest with a copy of itself by
    a rename: what a build does when it swaps a new dataset in."""

    def __init__(self, ds: Path):
        super().__init__()
        self.ds = ds
        self.swapped = False

    def write(self, text: str) -> int:
        if not self.swapped and "[1/" in text:
            copy = self.ds / ".manifest.json.new"
            shutil.copyfile(self.ds / "manifest.json", copy)
            os.replace(copy, self.ds / "manifest.json")
            self.swapped = True
        return super().write(text)


def test_validate_refuses_a_dataset_swapped_while_it_reads(ds, monkeypatch, capsys):
    stderr = _SwapOnProgress(ds)
    monkeypatch.setattr(sys, "stderr", stderr)
    rc = cli.main(["validate", str(ds)])
    assert stderr.swapped
    assert rc == 1, capsys.readouterr().out  # was 0: "valid" for a dataset it half read before the swap
    assert "the dataset changed while validate read it" in stderr.getvalue()
    assert "run s2a-dataset validate again" in stderr.getvalue()


def test_validate_and_stats_of_an_unchanged_dataset_still_pass(ds, capsys):
    assert cli.main(["validate", str(ds / "manifest.json")]) == 0
    assert cli.main(["stats", str(ds), "--json"]) == 0
    assert "changed while" not in capsys.readouterr().err
