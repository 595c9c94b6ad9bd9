"""The import guard (capture.import_guard) covers a stage command's imports to the end of its own module,
``cli.py``: it ended with the stage package's ``__init__``, so a Ctrl-C while ``cli.py`` imported what
the package had not (``capture.cli``: the live and simulate commands) was a KeyboardInterrupt traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest
from conftest import ROOT

from capture.import_guard import COMMANDS

CHECK = """
import signal, sys
sys.argv[0] = sys.argv[1]  # this process is the stage's console script
import {package}
from capture import import_guard
during = signal.getsignal(signal.SIGINT) is import_guard._stop_quietly
import {package}.cli
after = signal.getsignal(signal.SIGINT) is signal.default_int_handler
print(during, after)
"""


@pytest.mark.parametrize("package", ["capture", "align"])
def test_the_guard_lasts_until_the_command_module_has_imported(package):
    proc = subprocess.run(
        [sys.executable, "-c", CHECK.format(package=package), COMMANDS[package]],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert proc.stdout.split() == ["True", "True"], proc.stdout + proc.stderr
