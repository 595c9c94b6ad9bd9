"""A take whose id is not UTF-8 (a file name in Latin-1 from another system) in a dataset build: the
split's seeded order hashed the id's text and stopped the build with a UnicodeEncodeError traceback;
two such ids giving one sample key (``caf\\xe9.1``, ``caf\\xe9_1``) were keyed by the same hash. Real
takes, a real build, validate through its command line."""

from __future__ import annotations

import os

from conftest import run_cli
from dataset_helpers import make_aligned_take

from capture.take import write_take
from dataset import BuildOptions, build_dataset
from dataset.manifest import read_manifest


def test_takes_whose_ids_are_not_utf8_build_and_validate(tmp_path):
    ids = [os.fsdecode(b"caf\xe9%d" % i) for i in range(4)] + [
        os.fsdecode(b"caf\xe9.9"),
        os.fsdecode(b"caf\xe9_9"),
    ]
    ids += [f"take{i}" for i in range(4)]
    for i, take_id in enumerate(ids):
        write_take(make_aligned_take(take_id, 1.0, subject=f"spk{i % 3}", seed=i), tmp_path / "takes")
    build_dataset([tmp_path / "takes"], tmp_path / "ds", BuildOptions())
    samples = read_manifest(tmp_path / "ds")["samples"]
    keys = [s["key"] for s in samples]
    assert len(samples) == len(ids) and len(set(keys)) == len(keys)
    assert {s["take"] for s in samples} == set(ids)
    checked = run_cli("dataset", "validate", str(tmp_path / "ds"))
    assert checked.returncode == 0 and "Traceback" not in checked.stderr, checked.stderr
