"""An output path that is a device or a pipe (``/dev/full``, ``/dev/null``, a FIFO) is written into, not
replaced: the commands wrote a hidden partial file and renamed it over the path, which put a regular file
in place of the device (as root: ``s2a-train export RUN -o /dev/null`` replaced /dev/null) and never saw
that ``/dev/full`` is full. ``/dev/full`` is bind-mounted over a file in the test's folder inside
``unshare -r -m`` (its own mount namespace), so that no command can touch the machine's /dev."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, run_cli
from test_train_pipeline import TINY

# Run "$@" with /dev/full bound over the file $OUT (opened once: a mount without devices cannot); say
# whether $OUT is still the device afterwards.
ON_A_FULL_DEVICE = r"""
touch "$OUT" && mount --bind /dev/full "$OUT" && head -c 1 "$OUT" >/dev/null || exit 99  # nodev: skip
"$@"; code=$?
[ -c "$OUT" ] && echo device_kept >&2
exit $code
"""


@pytest.fixture(scope="module")
def run(built, tmp_path_factory) -> Path:
    """A Transformer-S2A run of 2 steps on the shared five-take dataset (``built``)."""
    out = tmp_path_factory.mktemp("diskfull") / "run"
    sets = [a for s in [*TINY, "arch.max_frames=200", "window=120"] for a in ("--set", s)]
    run_cli("train", "fit", "--data", built, "-o", out, "--max-steps", 2, *sets, check=True)
    return out


def _on_full_device(out: Path, module: str, *args) -> subprocess.CompletedProcess:
    if subprocess.run(["unshare", "-r", "-m", "true"], capture_output=True).returncode != 0:
        pytest.skip("needs unshare -r -m (user and mount namespaces) to bind /dev/full")
    command = [sys.executable, "-m", module, *map(str, args)]
    proc = subprocess.run(
        ["unshare", "-r", "-m", "bash", "-c", ON_A_FULL_DEVICE, "bash", *command],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=dict(os.environ, OUT=str(out)),
        timeout=300,
    )
    if proc.returncode == 99:
        pytest.skip("cannot bind /dev/full here")
    return proc


@pytest.mark.parametrize(
    "name, what",
    [
        ("out.csv", "the CSV"),
        ("m.onnx", "the ONNX file"),
        ("face.png", "the image"),
        ("face.mp4", "the video"),
        ("plot.svg", "the plot"),
        ("report.html", "the report"),
    ],
)
def test_an_output_on_a_full_device_is_one_line_saying_so_and_the_device_stays(
    name, what, run, built, sim_take, tmp_path
):
    out = tmp_path / name
    audio = next(sim_take.glob("*.wav"))
    module, *args = {
        "out.csv": ("train", "predict", run, audio),
        "m.onnx": ("train", "export", run),
        "face.png": ("viewer", "render", sim_take, "--size", 64),
        "face.mp4": ("viewer", "render", sim_take, "--size", 64),
        "plot.svg": ("viewer", "plot", sim_take),
        "report.html": ("viewer", "report", built),
    }[name]
    proc = _on_full_device(out, module, *args, "-o", out)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 1 and lines[-1] == "device_kept", proc.stderr
    error = lines[-2]
    assert f"{out}: cannot write {what}: " in error and "no space left on device" in error.lower(), error
    assert "Traceback" not in proc.stderr and sum(": error: " in line for line in lines) == 1, proc.stderr
    assert [p.name for p in tmp_path.iterdir()] == [name], "a partial file was left behind"


def test_an_output_that_is_a_pipe_gets_the_bytes_and_stays_a_pipe(sim_take, tmp_path):
    fifo = tmp_path / "face.png"
    os.mkfifo(fifo)
    reader = subprocess.Popen(["cat", str(fifo)], stdout=subprocess.PIPE)
    try:
        proc = run_cli("viewer", "render", sim_take, "--size", 64, "-o", fifo)
        assert proc.returncode == 0, proc.stderr
        assert stat.S_ISFIFO(fifo.stat().st_mode), "the pipe was replaced by a file"
        got, _ = reader.communicate(timeout=60)
        assert got.startswith(b"\x89PNG") and len(got) > 1000
        assert [p.name for p in tmp_path.iterdir()] == ["face.png"]
    finally:
        if reader.poll() is None:
            reader.kill()
            reader.communicate()


def test_an_output_that_is_a_disk_is_refused_and_left_alone(sim_take, tmp_path):
    """A block device named as the output (a slip of ``-o /dev/sdb``) is never written over, nor replaced by
    a file. The node made here (loop device 7:250) is never opened."""
    out = tmp_path / "face.png"
    try:
        os.mknod(out, stat.S_IFBLK | 0o600, os.makedev(7, 250))
    except OSError:
        pytest.skip("cannot make a block device node here (not root)")
    proc = subprocess.run(
        [sys.executable, "-m", "viewer", "render", str(sim_take), "--size", "64", "-o", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert proc.returncode == 1, proc.stderr
    refused = "a disk or partition (a block device): not written over"
    assert refused in proc.stderr.splitlines()[-1], proc.stderr
    assert stat.S_ISBLK(os.lstat(out).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["face.png"]
