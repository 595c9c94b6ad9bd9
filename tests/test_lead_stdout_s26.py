"""A result that stdout cannot take (``> /dev/full``, a full disk) is one line saying so; a closed pipe
(``| head``) still ends quietly."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import ROOT

S07 = "livelinkface/alexdjulin_S07"


@pytest.mark.parametrize("json_lines", [False, True])
def test_a_result_on_a_full_stdout_says_what_could_not_be_written(samples, json_lines):
    csv = next((samples / S07).glob("*.csv"))
    with open("/dev/full", "w") as full:
        proc = subprocess.run(
            [sys.executable, "-m", "capture", "info", str(csv), *(["--json"] if json_lines else [])],
            cwd=ROOT,
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
        )
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "s2a-capture: error: cannot write to standard output: No space left on device"
    ], proc.stderr


def test_a_result_into_a_closed_pipe_ends_quietly(samples):
    csv = next((samples / S07).glob("*.csv"))
    proc = subprocess.Popen(
        [sys.executable, "-m", "capture", "info", str(csv)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    proc.stdout.close()  # the reader went away before the result (| head that has its lines)
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(timeout=120) == 0, err
    assert err == "", err
