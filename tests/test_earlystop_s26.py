"""SIGTERM (``timeout``, ``kill``, a batch scheduler) at the edges of a stage command's run: while it still
imports numpy, scipy and its stage's libraries (0.5-3 s), after the block that turns SIGTERM into a stop
has ended (the result being printed), and once the command's work is over. Each ended the process by
the signal (exit -15, no line); now a command stopped says ``s2a-X: terminated (SIGTERM)`` and exits
with 143, and one whose work was over ends with its own exit code. Real commands in subprocesses,
signalled at a moment a condition shows (a library mapped into the process), not after a fixed sleep.
And a stop between a shard writer's making and ``with`` taking it left its partial file."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT
from dataset_helpers import write_aligned_set
from test_stops_s25 import _python_ctrl_c  # noqa: F401 (the fixture: Python's Ctrl-C handler)

from capture.import_guard import COMMANDS
from dataset.shards import ShardReader, ShardWriter

SCRIPTS = Path(sys.executable).parent  # the console scripts pyproject.toml installs


def _mapped(pid: int, library: str) -> bool:
    """Whether ``library`` (a part of a shared object's path) is mapped into process ``pid``: it is being
    imported, or has been."""
    try:
        return library in Path(f"/proc/{pid}/maps").read_text()
    except OSError:  # gone
        return False


def _signalled_once(args: list[str], sig: int, library: str) -> tuple[subprocess.Popen, str, bool]:
    """``args`` run, and sent ``sig`` as soon as ``library`` is mapped into it (polled, whatever the
    machine's load); (the process, its stderr, whether it still ran when signalled)."""
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while proc.poll() is None and not _mapped(proc.pid, library) and time.monotonic() < deadline:
        time.sleep(0.002)
    running = proc.poll() is None
    if running:
        proc.send_signal(sig)
    _out, err = proc.communicate(timeout=120)
    return proc, err, running


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads what a process mapped from /proc")
@pytest.mark.parametrize(
    ("stage", "entry", "args"),
    [
        ("align", "module", ["NOTHING", "-o", "OUT"]),
        ("align", "script", ["NOTHING", "-o", "OUT"]),
        ("capture", "module", ["info", "NOTHING"]),
        ("dataset", "script", ["stats", "NOTHING"]),
        ("train", "module", ["eval", "NOTHING", "--data", "NOTHING"]),
        ("viewer", "script", ["plot", "NOTHING", "-o", "OUT"]),
    ],
)
@pytest.mark.parametrize(
    ("sig", "code", "said"),
    [(signal.SIGTERM, 143, "terminated (SIGTERM)"), (signal.SIGINT, 130, "interrupted")],
    ids=["sigterm", "ctrl-c"],
)
@pytest.mark.parametrize("library", ["_multiarray_umath", "scipy"])
def test_a_stop_while_the_command_imports_says_its_line(
    tmp_path, stage, entry, args, sig, code, said, library
):
    """numpy's core and then scipy load early in every stage's imports (capture's first): a SIGTERM as
    either was mapped ended the process by the signal, with no line (Ctrl-C said its line already)."""
    prog = COMMANDS[stage]
    args = [{"NOTHING": str(tmp_path / "none"), "OUT": str(tmp_path / "out")}.get(a, a) for a in args]
    command = [str(SCRIPTS / prog)] if entry == "script" else [sys.executable, "-m", stage]
    proc, err, running = _signalled_once(command + args, sig, library)
    lines = err.strip().splitlines()
    if not running or proc.returncode == 1:  # the command was over (a fast machine): its own error
        assert proc.returncode == 1 and lines[-1].startswith(f"{prog}: error: "), err
        return
    assert proc.returncode == code and "Traceback" not in err, (proc.returncode, err)
    assert lines == [f"{prog}: {said}"], err
    assert list(tmp_path.iterdir()) == []


# This process poses as the stage's console script (its argv[0], set before capture is imported) and runs
# its command; a SIGTERM reaches it at ``WHERE``: as the command module's function of that name is called
# (after the command's own SIGTERM block: the result printed), or ``after`` the command returned.
POSING = """
import importlib, os, signal, sys
prog, stage, where, *args = sys.argv[1:]
sys.argv = [prog, *args]
cli = importlib.import_module(stage + ".cli")


def signalled(real):
    def call(*a, **k):
        os.kill(os.getpid(), signal.SIGTERM)
        return real(*a, **k)
    return call


if where != "after":
    setattr(cli, where, signalled(getattr(cli, where)))
code = cli.main()
if where == "after":
    os.kill(os.getpid(), signal.SIGTERM)
sys.exit(code)
"""


def _posing(stage: str, where: str, *args) -> subprocess.CompletedProcess:
    command = [sys.executable, "-c", POSING, COMMANDS[stage], stage, where, *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=300)


@pytest.mark.parametrize(
    ("stage", "args", "code", "said"),
    [
        ("capture", ["info", "NOTHING"], 1, "s2a-capture: error: "),
        ("viewer", ["plot", "NOTHING", "-o", "OUT"], 1, "s2a-view: error: "),
        ("viewer", ["export-face", "-o", "OUT.glb"], 0, ""),
    ],
)
def test_a_sigterm_once_the_command_is_over_leaves_its_exit_code(tmp_path, stage, args, code, said):
    """The command had printed its result (or error) and returned: a SIGTERM as Python exited ended the
    process by the signal (exit -15), as if the work had been cut short."""
    names = {"NOTHING": tmp_path / "none", "OUT": tmp_path / "out.png", "OUT.glb": tmp_path / "face.glb"}
    args = [names.get(a, a) for a in args]
    proc = _posing(stage, "after", *args)
    assert proc.returncode == code and "Traceback" not in proc.stderr, (proc.returncode, proc.stderr)
    assert proc.stderr.startswith(said) and "terminated" not in proc.stderr, proc.stderr
    assert code or (tmp_path / "face.glb").is_file()


@pytest.fixture(scope="module")
def takes(tmp_path_factory) -> Path:
    return write_aligned_set(tmp_path_factory.mktemp("earlystop") / "takes", count=2, seconds=1.0)


def test_a_sigterm_after_the_build_s_stop_block_says_its_line(takes, tmp_path):
    """The build turns SIGTERM into a stop while it writes (``sigterm_stops``); after that block, as the
    summary was printed, SIGTERM ended the process by the signal with no line. The dataset written
    stays whole, and its lock is gone."""
    out = tmp_path / "ds"
    proc = _posing("dataset", "emit_json", "build", takes, "-o", out, "--features", "fbank", "--json")
    lines = [x for x in proc.stderr.splitlines() if not x.startswith("build: ")]
    assert proc.returncode == 143 and lines == ["s2a-dataset: terminated (SIGTERM)"], proc.stderr
    assert proc.stdout == ""
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".") and p.name != ".work") == []
    ok = subprocess.run(
        [sys.executable, "-m", "dataset", "validate", out, "--json"], capture_output=True, text=True, cwd=ROOT
    )
    assert ok.returncode == 0 and json.loads(ok.stdout)["dataset"] == str(out), ok.stderr


def test_a_stop_between_a_shard_writer_made_and_its_with_leaves_no_partial_file(tmp_path):
    """``ShardWriter(path)`` made the partial file, and ``with`` took the writer only after: a stop met
    between the two (here as ``with`` begins) left ``.train-000000.tar.partial`` beside the shards."""
    writer = ShardWriter(tmp_path / "train-000000.tar")
    with pytest.raises(KeyboardInterrupt):
        signal.raise_signal(signal.SIGINT)
        with writer:
            pytest.fail("the block ran after the stop")
    assert list(tmp_path.iterdir()) == []
    with ShardWriter(tmp_path / "train-000000.tar") as writer:  # made and taken at once, it writes
        writer.add("take-000", {"json": b"{}"})
        writer.close()
    assert [key for key, _ in ShardReader(tmp_path / "train-000000.tar")] == ["take-000"]
