"""Outputs that are devices or pipes, written by a normal user: ``-o /dev/null`` (or a FIFO in a folder the
user cannot write) failed with "Permission denied", since the hidden partial file was made beside the
output first (in /dev). It is written straight into now (``capture.atomic.written_into``), or, for a file
that must be finished first (an ONNX file checked before it is given), assembled in a private temporary
folder. The tests run as root here: each command runs with the privileges of ``nobody`` (its inputs in a
folder anyone can read); as another user, as that user."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from conftest import ROOT, run_cli
from test_train_pipeline import TINY

NOBODY = 65534


def as_a_normal_user(home: Path, module: str, *args) -> subprocess.CompletedProcess:
    """``python -m module *args`` as a user who may not write /dev (root: as ``nobody``, through
    ``setpriv``: this interpreter may lie in a folder only root can search, which ``os.setuid`` before
    ``exec`` cannot reach)."""
    drop = []
    if os.geteuid() == 0:
        drop = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"]
        probe = [*drop, sys.executable, "-c", "import capture"]  # the interpreter and the project readable
        if shutil.which("setpriv") is None or subprocess.run(probe, cwd=ROOT, capture_output=True).returncode:
            pytest.skip("cannot run a command as a normal user here (no setpriv, or it cannot drop root)")
    return subprocess.run(
        [*drop, sys.executable, "-m", module, *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=dict(os.environ, HOME=str(home), MPLCONFIGDIR=str(home / "mpl"), PYTHONDONTWRITEBYTECODE="1"),
        timeout=300,
    )


@pytest.fixture(scope="module")
def readable(built):
    """A folder anyone can read holding the five takes, their dataset and a 2-step Transformer-S2A run on
    it (``run``), and ``sealed``, a folder of this user's (``nobody`` may not write it)."""
    folder = Path(tempfile.mkdtemp(prefix="outputs_s27-"))
    try:
        folder.chmod(0o755)
        shutil.copytree(built.parent / "takes", folder / "takes")
        shutil.copytree(built, folder / "ds", ignore=shutil.ignore_patterns(".work"))
        sets = [a for s in [*TINY, "arch.max_frames=200", "window=120"] for a in ("--set", s)]
        run_cli(
            "train", "fit", "--data", folder / "ds", "-o", folder / "run", "--max-steps", 2, *sets, check=True
        )
        (folder / "sealed").mkdir(mode=0o755)
        (folder / "home").mkdir(mode=0o777)
        (folder / "home").chmod(0o777)
        for path in folder.rglob("*"):
            path.chmod(path.stat().st_mode | 0o444 | (0o111 if path.is_dir() else 0))
        yield folder
    finally:
        for path in folder.rglob("*"):
            if path.is_dir():
                path.chmod(0o755)
        shutil.rmtree(folder)


def command_line(command: str, folder: Path) -> list:
    """The stage and arguments of ``command`` on ``readable``'s inputs, all but ``-o``."""
    take, run = folder / "takes" / "take00", folder / "run"
    return {
        "export-csv": ["capture", "export-csv", take],
        "predict": ["train", "predict", run, take / "audio.wav"],
        "export": ["train", "export", run],
        "plot": ["viewer", "plot", take],
        "report": ["viewer", "report", folder / "takes"],
        "export-face": ["viewer", "export-face"],
    }[command]


@pytest.mark.parametrize("command", ["export-csv", "predict", "export"])
def test_a_normal_user_writes_to_dev_null(command, readable):
    proc = as_a_normal_user(readable / "home", *command_line(command, readable), "-o", "/dev/null")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


@pytest.mark.parametrize(
    "command, name",
    [
        ("export-csv", "take.csv"),
        ("predict", "voice.csv"),
        ("export", "m.onnx"),
        ("plot", "plot.svg"),
        ("report", "report.html"),
        ("export-face", "face.glb"),
    ],
)
def test_a_normal_user_writes_into_a_fifo_in_a_folder_they_cannot_write(command, name, readable, tmp_path):
    sealed = readable / "sealed"
    fifo = sealed / name
    os.mkfifo(fifo, 0o666)
    fifo.chmod(0o666)
    if os.geteuid() != 0:  # run as this user: the folder closed to its owner too while the command runs
        sealed.chmod(0o555)
    received = tmp_path / "received"
    with open(received, "wb") as into:  # not a pipe of ours: one read only at the end fills and stalls
        reader = subprocess.Popen(["cat", str(fifo)], stdout=into)
    try:
        proc = as_a_normal_user(readable / "home", *command_line(command, readable), "-o", fifo)
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
        reader.wait(timeout=60)
        assert received.stat().st_size > 100
        assert stat.S_ISFIFO(fifo.lstat().st_mode)
        assert [p.name for p in fifo.parent.iterdir()] == [name]
    finally:
        if reader.poll() is None:
            reader.kill()
            reader.communicate()
        sealed.chmod(0o755)
        fifo.unlink()


def test_predict_to_dev_stdout_gives_the_csv_on_standard_output(readable):
    """One audio file and ``-o /dev/stdout`` (no .csv: was taken as a folder to make, an error). Run as
    this user: another's process cannot open this one's pipe through /dev/stdout."""
    run, wav = readable / "run", readable / "takes" / "take00" / "audio.wav"
    proc = run_cli("train", "predict", run, wav, "-o", "/dev/stdout")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("Timecode,BlendShapeCount,"), proc.stdout[:200]
    assert proc.stdout.count("\n") > 100
    # the CSV alone: the result line after it (``/dev/stdout: 120 frames``) goes to stderr
    assert all(line[:2].isdigit() for line in proc.stdout.splitlines()[1:]), proc.stdout[-300:]
    assert "/dev/stdout: " in proc.stderr, proc.stderr


def test_one_audio_file_and_a_name_without_csv_makes_a_folder_and_says_so(readable, tmp_path):
    """``-o out`` for one audio file is a folder receiving ``audio.csv`` (as for several files), and the
    command says so: most tools would write the file ``out``."""
    run, wav = readable / "run", readable / "takes" / "take00" / "audio.wav"
    proc = run_cli("train", "predict", run, wav, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "out" / "audio.csv").is_file()
    note = f"note: {tmp_path / 'out'} is a folder, made for audio.csv: give -o X.csv to write the CSV itself"
    assert note in proc.stderr.splitlines(), proc.stderr
    again = run_cli("train", "predict", run, wav, "-o", tmp_path / "out")  # now an existing folder: no note
    assert again.returncode == 0 and " is a folder, made for " not in again.stderr, again.stderr
