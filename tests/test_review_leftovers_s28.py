"""Second review of the leftovers of session 28 (tests/test_leftovers_s28.py): a file written before them,
with a key of its own ending in ``_b64 (1)`` or ``_b64 (02)`` holding the bytes of a name beside it, read
back with that key gone (taken for bytes kept at a count, which ``strict_names`` never writes so); a
stage command run from a program's own script leaves that program's SIGTERM at exit as it was."""

from __future__ import annotations

import json
import os
import signal

import pytest
from conftest import run_python

from capture.errors import loads_names, strict_names

CAFE = os.fsdecode(b"caf\xe9")  # a name in Latin-1, as another system's file name gives it


@pytest.mark.parametrize("own", ["a_b64 (1)", "a_b64 (02)"])
def test_a_file_written_before_with_a_counted_key_of_its_own_reads_as_before(own):
    """As the writer before the counts wrote ``{"a": CAFE, own: <CAFE's bytes>}``: the name's bytes under
    ``a_b64``, the key of its own beside them. Read as bytes kept at a count, that key was lost and
    ``a_b64`` came back as a key of its own."""
    value = {"a": CAFE, own: "Y2Fm6Q=="}
    written_before = json.dumps({"a": "caf\\xe9", "a_b64": "Y2Fm6Q==", own: "Y2Fm6Q=="})
    assert loads_names(written_before) == value
    assert loads_names(json.dumps(strict_names(value))) == value


def test_bytes_kept_at_a_count_read_back_beside_counted_keys_of_its_own():
    """The counts ``strict_names`` writes (2 on) are still read as such, past keys of its own."""
    value = {"a": CAFE, "a_b64": "aGVsbG8=", "a_b64 (1)": "Y2Fm6Q==", "a_b64 (9)": "x", "a_b64 (10)": CAFE}
    written = strict_names(value)
    assert written["a_b64 (11)"] == "Y2Fm6Q==", written
    assert loads_names(json.dumps(written)) == value


# A program of the user's own (``python script.py``, not a stage command) that runs a command's ``main``
# and sends itself a SIGTERM as Python exits: its SIGTERM stays the default, ending it by the signal.
OWN_PROGRAM = """
import atexit, os, signal, sys
import capture.cli as cli
code = cli.main(["info", sys.argv[1]])
atexit.register(lambda: os.kill(os.getpid(), signal.SIGTERM))
sys.exit(code)
"""


def test_a_program_running_a_command_keeps_its_own_sigterm_at_exit(tmp_path):
    """A guard (as before the leftovers): the command's exit hooks act in a stage command's process only."""
    proc = run_python(OWN_PROGRAM, str(tmp_path / "none"), timeout=120)
    assert "s2a-capture: error: " in proc.stderr, proc.stderr
    assert proc.returncode == -signal.SIGTERM, (proc.returncode, proc.stderr)
