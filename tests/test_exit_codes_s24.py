"""A command's exit code is the process's: a Ctrl-C that lands in code run from text (a dataclass or
namedtuple being defined as a module imports) made CPython kill a ``python -m STAGE`` process with SIGINT
at exit (returncode -2) after the command had printed its one line and returned 130."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from conftest import ROOT

_COMMAND = """
import argparse, sys
from capture.command import run

def main(args):
    exec("raise KeyboardInterrupt")  # as a Ctrl-C landing while a dataclass's __init__ is made

sys.exit(run("s2a-test", argparse.ArgumentParser, main, []))
"""


def test_a_ctrl_c_in_executed_text_exits_with_the_commands_code(tmp_path: Path):
    (tmp_path / "stage_like.py").write_text(_COMMAND)
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    proc = subprocess.run(
        [sys.executable, "-m", "stage_like"], capture_output=True, text=True, cwd=ROOT, env=env, timeout=120
    )
    assert proc.stderr == "s2a-test: interrupted\n", proc.stderr
    assert proc.returncode == 130, proc.returncode
