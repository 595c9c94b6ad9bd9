"""Names whose bytes are not UTF-8 where JSON lines and messages still lost or mangled them: a dict keyed by
names (``dataset stats``' hours per speaker, a speaker named after a CSV file's ``{slate}_{take}_{subject}``)
kept no bytes of a key, and a usage error naming such a file (a name taken for an option, a value refused)
showed ``\\udcff`` where every other message shows ``\\xff``. Real command lines in subprocesses."""

from __future__ import annotations

import base64
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT
from dataset_helpers import make_aligned_take
from test_trainuse_s25 import _strict_records

import capture.command as command
from capture.csv_take import parse_take_prefix
from capture.errors import strict_names
from capture.take import write_take

_CAFE = b"caf\xe9"  # a speaker named in Latin-1, as another system's file name gives it
SPEAKER = os.fsdecode(_CAFE)


def _stage(module: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)], capture_output=True, cwd=ROOT, timeout=300
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A dataset of three 1 s takes, two of them of the speaker ``caf\\xe9`` (the subject of a CSV named
    ``MySlate_1_caf\\xe9.csv``), one of ``bob``."""
    root = tmp_path_factory.mktemp("names26")
    _slate, _take, subject = parse_take_prefix(os.fsdecode(b"MySlate_1_" + _CAFE))
    assert subject == SPEAKER
    for i, who in enumerate((subject, subject, "bob")):
        write_take(make_aligned_take(f"take{i:02d}", 1.0, subject=who, seed=i), root / "takes")
    proc = _stage("dataset", "build", root / "takes", "-o", root / "ds", "--features", "fbank")
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    return root / "ds"


def test_stats_hours_per_speaker_keep_the_bytes_of_a_speaker_not_utf8(dataset):
    proc = _stage("dataset", "stats", dataset, "--json")
    assert proc.returncode == 0 and b"Traceback" not in proc.stderr, proc.stderr
    (record,) = _strict_records(proc.stdout)
    assert set(record["hours_per_speaker"]) == {"caf\\xe9", "bob"}  # as messages show it
    assert record["hours_per_speaker_keys_b64"] == {"caf\\xe9": base64.b64encode(_CAFE).decode()}
    assert set(command.named_keys(record, "hours_per_speaker")) == {SPEAKER, "bob"}


def test_a_map_keyed_by_names_all_utf8_gets_no_bytes_beside_it():
    record = strict_names({"hours_per_speaker": {"bob": 1.0, "Zoë": 2.0}, "path": "x"})
    assert record == {"hours_per_speaker": {"bob": 1.0, "Zoë": 2.0}, "path": "x"}
    assert command.named_keys(record, "hours_per_speaker") == {"bob": 1.0, "Zoë": 2.0}


@pytest.mark.parametrize(
    ("module", "args", "shown"),
    [
        # a file named like an option: the hint says how to give it
        ("viewer", ["plot", os.fsdecode(b"-d\xff.csv"), "-o", "x.png"], "write ./-d\\xff.csv"),
        # argparse's own message, the value as its repr
        (
            "align",
            ["takes", "-o", "out", "--max-gap-ms", os.fsdecode(b"x\xff")],
            "invalid float value: 'x\\xff'",
        ),
    ],
    ids=["taken-for-an-option", "value-refused"],
)
def test_a_usage_error_naming_a_name_not_utf8_shows_its_bytes_as_elsewhere(module, args, shown):
    proc = subprocess.run(
        [sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert shown in last and "\\udc" not in last, last
