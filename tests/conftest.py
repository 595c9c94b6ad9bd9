"""Shared fixtures: the real sample data beside the checkout (../shared/samples)."""

from __future__ import annotations

import contextlib
import gc
import importlib
import io
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import pytest

# Under pytest-xdist (make test: two workers on two cores) each worker's PyTorch, and every command a test
# starts, takes one thread: two workers of two threads each fought over the cores (a test's torch work
# took up to 4x as long).
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT.parent / "shared" / "samples"


@pytest.fixture(scope="session")
def samples() -> Path:
    if not SAMPLES.is_dir():
        pytest.skip(f"real samples not found at {SAMPLES}")
    return SAMPLES


@pytest.fixture(scope="module")
def sim_take(tmp_path_factory) -> Path:
    """A simulated Live Link Face take folder (take.json, frame_log.csv, .mov with audio, CSV): 2 s at
    16 kHz, made once per test module (a module may define its own)."""
    root = tmp_path_factory.mktemp("sim")
    run_cli("capture", "simulate", "-o", root, "--seconds", 2, "--mov", "--sample-rate", 16000, check=True)
    (folder,) = [p for p in root.iterdir() if p.is_dir()]
    return folder


@pytest.fixture
def unpack_tmp(tmp_path, monkeypatch) -> Path:
    """The temporary folder the viewer unpacks archives into (Python's, pointed at ``tmp_path/tmp``)."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


def run_cli(module: str, *args: str, check: bool = False) -> subprocess.CompletedProcess:
    """Run a stage's command line as a user would (``python -m <stage> ...``)."""
    proc = subprocess.run(
        [sys.executable, "-m", module, *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    if check and proc.returncode != 0:
        raise AssertionError(f"{module} {args} failed ({proc.returncode}):\n{proc.stderr}")
    return proc


def run_python(code: str, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """``python -c code *args`` in the checkout, its output captured as text."""
    return subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=ROOT, timeout=timeout
    )


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """A real dataset of five 2 s takes (``dataset_helpers.build_five_take_dataset``), built once per
    test module (a module may define its own)."""
    from dataset_helpers import build_five_take_dataset

    return build_five_take_dataset(tmp_path_factory.mktemp("five_takes"))


@pytest.fixture
def ds(built, tmp_path) -> Path:
    """A copy of ``built`` to damage."""
    return Path(shutil.copytree(built, tmp_path / "ds", ignore=shutil.ignore_patterns(".work")))


# The end of a rank's script: without interpreter shutdown, as train.cli._leave_distributed_process ends
# a torchrun worker (gloo's threads releasing the last collective's tensors while Python shuts down
# abort the process, "terminate called without an active exception", on a busy machine).
_LEAVE_RANK = "\nimport os as _os, sys as _sys\n_sys.stdout.flush()\n_sys.stderr.flush()\n_os._exit(0)\n"


def run_gloo_ranks(script: str, args: list[str], timeout: float = 300) -> list[list[str]]:
    """``python -c script RANK *args`` for ranks 0 and 1 at once (a gloo group on loopback, as the
    script sets it up); the JSON lines (``{...}``) each printed, every rank having printed some and
    exited with 0. A rank that ran the script to its end leaves as s2a-train's ranks do
    (``_LEAVE_RANK``)."""
    script += _LEAVE_RANK
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if sys.platform.startswith("linux"):  # gloo on loopback: no dependence on what the hostname resolves to
        env["GLOO_SOCKET_IFNAME"] = "lo"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", script, str(rank), *args],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for rank in (0, 1)
    ]
    try:
        outs = [p.communicate(timeout=timeout) for p in procs]
    finally:  # a rank waiting at a collective the other never joins: never left behind
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    lines = [[line for line in out.splitlines() if line.startswith("{")] for out, _ in outs]
    assert all(lines) and all(p.returncode == 0 for p in procs), [err[-2000:] for _, err in outs]
    return lines


def _warning_to_stderr(message, category, filename, lineno, file=None, line=None) -> None:
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def run_here(module: str, *args: str, check: bool = False) -> subprocess.CompletedProcess:
    """A stage's command line run in this process, as ``run_cli`` returns it: for tests whose subject is
    what a command does rather than the command line itself (each stage's commands are also run as
    subprocesses elsewhere), without an interpreter's and PyTorch's start-up per call. A traceback
    here is an exception the test fails with."""
    main = importlib.import_module(f"{module}.cli").main
    gc.collect()  # what earlier tests left to the collector warns now, not into this command's stderr
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
        # Python's warnings reach the user's stderr as lines, not pytest's record: a test of one-line
        # errors must see them
        warnings.simplefilter("default")
        warnings.showwarning = _warning_to_stderr
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code if isinstance(exc.code, int) else 1
    if check and code != 0:
        raise AssertionError(f"{module} {args} failed ({code}):\n{err.getvalue()}")
    return subprocess.CompletedProcess([module, *map(str, args)], code, out.getvalue(), err.getvalue())


def import_rig_take(samples: Path, folder: Path) -> Path:
    """The first two seconds of a real FACEGOOD take (116 rig controls at 30 fps, none a Live Link
    channel), imported with ``s2a-capture import`` as a user would; the take folder."""
    import numpy as np
    import soundfile as sf

    from capture.paired import load_npy

    fg = samples / "paired" / "facegood-audio2face"
    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "rig.npy", load_npy(fg / "bs_value" / "bs_value_1114_2_05.npy")[:60])  # a Python 2 .npy
    audio, rate = sf.read(fg / "wav" / "1114_2_05.wav")
    sf.write(folder / "rig.wav", audio[: 2 * rate], rate)
    args = ["--matrix", folder / "rig.npy", "--audio", folder / "rig.wav", "--names", fg / "bs_names.txt"]
    run_cli("capture", "import", *args, "--fps", 30, "--id", "rig", "-o", folder / "takes", check=True)
    return folder / "takes" / "rig"
