"""A name's text holding a backslash and ``udcff`` (a file named on Linux after a Windows path,
``C:\\udcafe``) is not the repr of a byte: messages rewrote such text as ``\\xff`` and so did every JSON
value and result line, a JSON ``path`` then naming another file with no ``path_b64`` to recover it. A
byte's repr in a message (a usage error's value refused) is still shown as ``\\xff``. Real command lines
in subprocesses, real files."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys

import pytest
from conftest import ROOT, run_python

import capture.command as command

_LITERAL = "a\\udcff_1.csv"  # a backslash, then "udcff": valid UTF-8, no byte to show


def _stage(module: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)], capture_output=True, text=True, cwd=ROOT, timeout=300
    )


def test_a_json_path_holding_a_backslash_and_udcff_names_the_file(samples, tmp_path):
    csv = tmp_path / _LITERAL
    shutil.copy(samples / "livelinkface" / "neurosync_MySlate_166" / "MySlate_166_iPhone_cal.csv", csv)
    proc = _stage("capture", "info", csv, "--json")
    assert proc.returncode == 0, proc.stderr
    record = json.loads(proc.stdout)
    assert record["path"] == str(csv) and "path_b64" not in record, record["path"]
    assert command.named(record, "path") == str(csv)
    table = _stage("capture", "info", csv)
    assert table.returncode == 0 and str(csv) in table.stdout, table.stdout


def test_a_usage_error_shows_a_backslash_in_a_value_as_its_repr_does(tmp_path):
    """argparse shows the value refused as its repr, a backslash doubled: ``'x\\\\udcff'`` is a backslash
    and ``udcff``, not a byte."""
    proc = _stage("align", tmp_path, "-o", tmp_path / "out", "--max-gap-ms", "x\\udcff")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "invalid float value: 'x\\\\udcff'" in proc.stderr.splitlines()[-1], proc.stderr


@pytest.mark.parametrize(
    ("text", "shown"),
    [
        ("invalid value: 'x\\udcff'", "invalid value: 'x\\xff'"),  # a byte's repr
        ('invalid choice: "it\'s\\udcff"', 'invalid choice: "it\'s\\xff"'),  # a repr in double quotes
        ("'x\\\\udcff'", "'x\\\\udcff'"),  # a backslash's repr, then udcff
        ("'x\\\\\\udcff'", "'x\\\\\\xff'"),  # a backslash's, then a byte's
        ('"\\ud83d\\udc80"', '"\\ud83d\\udc80"'),  # an emoji (U+1F480) as JSON escapes it
        ("caf\udce9", "caf\\xe9"),  # the byte itself
    ],
)
def test_a_message_shows_only_a_byte_s_repr_as_its_byte(text, shown):
    from capture.errors import printable_message

    assert printable_message(text) == shown


def test_a_program_importing_the_packages_keeps_its_sigterm():
    """Not a stage command: SIGTERM ends it by the signal, with no line, whatever it imported."""
    code = "import os, signal, capture.command, dataset.shards; os.kill(os.getpid(), signal.SIGTERM)"
    proc = run_python(code)
    assert proc.returncode == -signal.SIGTERM and proc.stderr == "", (proc.returncode, proc.stderr)
