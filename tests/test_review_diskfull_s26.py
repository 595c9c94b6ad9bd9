"""A render whose ``-o`` is a FIFO nobody reads waits for a reader (as ``cat > FIFO`` does), and Ctrl-C or
SIGTERM then stops it as anywhere else: one line, exit 130 or 143, no partial file, the FIFO left as it
was. The render only notes a stop between frames (``stops_between_frames``), and opening the FIFO waited
on, deaf to both: only SIGKILL ended it, leaving ``.NAME.partial`` behind."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT


def _waiting_for_a_reader(proc: subprocess.Popen) -> bool:
    """Wait until ``proc`` is blocked opening a FIFO (Linux's ``wait_for_partner``); False once it ended."""
    wchan = Path(f"/proc/{proc.pid}/wchan")
    while proc.poll() is None:
        try:
            if wchan.read_text() == "wait_for_partner":
                return True
        except OSError:
            pytest.skip("no /proc/PID/wchan here to see the render wait for a reader")
        time.sleep(0.2)
    return False


@pytest.mark.parametrize(
    "name, sig, code, line",
    [
        ("face.png", signal.SIGTERM, 143, "s2a-view: terminated (SIGTERM)"),
        ("face.mp4", signal.SIGINT, 130, "s2a-view: interrupted"),
    ],
)
def test_a_render_waiting_for_a_fifo_reader_stops_on_a_signal(name, sig, code, line, sim_take, tmp_path):
    if not sys.platform.startswith("linux"):
        pytest.skip("reads /proc/PID/wchan")
    fifo = tmp_path / name
    os.mkfifo(fifo)
    command = [sys.executable, "-m", "viewer", "render", sim_take, "--size", "64", "-o", fifo]
    proc = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        waited = _waiting_for_a_reader(proc)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert waited, f"the render ended without waiting for a reader ({proc.returncode}):\n{err}"
    assert proc.returncode == code and err.strip() == line, err
    assert stat.S_ISFIFO(fifo.lstat().st_mode), "the FIFO was replaced"
    assert [p.name for p in tmp_path.iterdir()] == [name], "a partial file was left behind"


def test_a_checkpoint_written_to_a_pipe_reaches_its_reader_and_the_pipe_stays(tmp_path):
    """``s2a-train ppg -o`` writes through ``write_atomically``: it renamed its partial file over the path,
    a FIFO (or, as root, ``/dev/null``) replaced by a regular file."""
    fifo = tmp_path / "ppg.pt"
    os.mkfifo(fifo)
    reader = subprocess.Popen(["cat", str(fifo)], stdout=subprocess.PIPE)
    try:
        code = "import sys; from pathlib import Path; from train.checkpoint import write_atomically; "
        code += "write_atomically(Path(sys.argv[1]), lambda tmp: tmp.write_bytes(b'weights' * 1000))"
        proc = subprocess.run(
            [sys.executable, "-c", code, fifo], cwd=ROOT, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0, proc.stderr
        got, _ = reader.communicate(timeout=60)
    finally:
        if reader.poll() is None:
            reader.kill()
            reader.communicate()
    assert got == b"weights" * 1000
    assert stat.S_ISFIFO(fifo.lstat().st_mode), "the FIFO was replaced by a file"
    assert [p.name for p in tmp_path.iterdir()] == ["ppg.pt"], "a partial file was left behind"
