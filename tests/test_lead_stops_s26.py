"""Every s2a-capture and s2a-dataset command stops on SIGTERM as on Ctrl-C (one line, exit 143, no partial
folder), not only those that set it up themselves; and a few more messages show a name's bytes as \\xff."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from conftest import ROOT, run_here
from test_live_leftovers_s22 import FPS, write_frames_log


def _wait_for(condition, proc: subprocess.Popen, timeout: float = 120.0) -> bool:
    """True once ``condition()`` holds; False when the process ended first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.005)
    raise AssertionError("the command neither got there nor ended")


def test_sigterm_mid_simulate_says_its_line_and_leaves_no_partial_take(tmp_path):
    out = tmp_path / "sim"
    proc = subprocess.Popen(
        [sys.executable, "-m", "capture", "simulate", "-o", str(out), "--takes", "40", "--seconds", "4"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )

    def partial() -> bool:
        return out.is_dir() and any(".partial" in p.name for p in out.iterdir())

    reached = _wait_for(partial, proc)
    if reached:
        proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert "Traceback" not in err, err
    if not reached:  # the command finished first (a very fast machine): nothing to stop
        assert proc.returncode == 0, err
        return
    assert proc.returncode == 143, (proc.returncode, err)
    assert err.strip().splitlines()[-1] == "s2a-capture: terminated (SIGTERM)", err
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]


def test_sigterm_mid_a_command_without_its_own_stop_handling_says_its_line(tmp_path):
    """dataset validate sets up no SIGTERM handling of its own; here its work is made endless (the stand-in
    for a validate of a large dataset) so that the SIGTERM lands inside it."""
    started = tmp_path / "started"
    proc = subprocess.Popen(
        [sys.executable, "-c", _VALIDATE_UNTIL_STOPPED, str(started)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert _wait_for(started.exists, proc), proc.communicate()[1]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, (proc.returncode, err)
    assert err.strip().splitlines()[-1] == "s2a-dataset: terminated (SIGTERM)", err


# The dataset stage's own main, its validate handler (looked up by name as the parser is built) replaced by
# endless work.
_VALIDATE_UNTIL_STOPPED = """
import sys, time
from pathlib import Path
import dataset.cli as cli

def endless(args):
    Path(sys.argv[1]).write_text("")
    while True:
        time.sleep(0.01)

cli.cmd_validate = endless
sys.exit(cli.main(["validate", "anywhere"]))
"""


def test_recover_names_a_session_not_utf8_as_bytes(tmp_path):
    """Its takes cannot be written (the output is under a file): the line naming the session shows \\xff."""
    session = Path(os.fsdecode(bytes(tmp_path) + b"/rec\xff.recording"))
    values = np.full(61, 0.25, np.float32)
    write_frames_log(session, [(10 * 3600 * FPS + i, 1.0 + i / FPS, values) for i in range(120)])
    (tmp_path / "a_file").write_text("")
    proc = run_here("capture", "recover", session, "-o", tmp_path / "a_file" / "out")
    assert proc.returncode == 1
    line = next((x for x in proc.stderr.splitlines() if "take(s) not written" in x), None)
    # ascii(): a message holding a surrogate would crash the xdist worker that reports it
    assert line is not None and "rec\\xff.recording: 1 take(s)" in line, ascii(proc.stderr)
