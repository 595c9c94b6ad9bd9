"""Second review of outputs written into (``capture.atomic.written_into``). ``-o /dev/stdout`` with the
standard output sent to a file: the link ``/dev/stdout`` was replaced by the output (as root; a normal
user's command failed, "Permission denied" in /dev) and the file stayed empty; it is written through the
process's own standard output now. The private folders outputs written into are assembled in
(``s2a-partial-XXXX``) were left in the temporary folder by a process killed outright (SIGKILL); the
next process making one removes them (those of live processes are locked)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from conftest import ROOT, run_cli


def stdout_link(folder):
    """A symbolic link standing for ``/dev/stdout`` (``/proc/self/fd/1``), made in ``folder``: root replacing
    the system's own would break it for every other process."""
    link = folder / "stdout"
    os.symlink("/proc/self/fd/1", link)
    return link


def test_dev_stdout_sent_to_a_file_gets_the_csv(sim_take, tmp_path):
    run_cli("capture", "import", sim_take, "-o", tmp_path / "takes", check=True)
    (take,) = [p for p in (tmp_path / "takes").iterdir() if (p / "meta.json").is_file()]
    run_cli("capture", "export-csv", take, "-o", tmp_path / "take.csv", check=True)
    link, printed = stdout_link(tmp_path), tmp_path / "printed.csv"
    with open(printed, "wb") as stdout:
        proc = subprocess.run(
            [sys.executable, "-m", "capture", "export-csv", str(take), "-o", str(link)],
            stdout=stdout,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            timeout=300,
        )
    assert proc.returncode == 0, proc.stderr
    assert os.path.islink(link), "the link standing for /dev/stdout was replaced"
    assert printed.read_bytes() == (tmp_path / "take.csv").read_bytes()


def test_a_finished_file_given_to_dev_stdout_follows_what_was_printed(tmp_path):
    """``put_in_place`` (an ONNX file, a checkpoint, an MP4) into the standard output sent to a file opened
    for appending: after what the process printed, nothing before it overwritten."""
    link, log = stdout_link(tmp_path), tmp_path / "log"
    log.write_text("earlier\n")
    code = (
        "import sys; from pathlib import Path; from capture.atomic import partial_path, put_in_place\n"
        "print('printed first')\n"
        "out = Path(sys.argv[1]); tmp = partial_path(out)\n"
        "tmp.write_text('the file\\n'); put_in_place(tmp, out)\n"
        "print('printed after')\n"
    )
    with open(log, "a") as stdout:
        proc = subprocess.run(
            [sys.executable, "-c", code, str(link)],
            stdout=stdout,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
    assert proc.returncode == 0, proc.stderr
    assert os.path.islink(link)
    assert log.read_text() == "earlier\nprinted first\nthe file\nprinted after\n"


# Prints the private folder a device's partial file is assembled in, then waits for a line on stdin.
HOLD_A_PRIVATE_FOLDER = (
    "import sys; from pathlib import Path; from capture.atomic import partial_path\n"
    "print(partial_path(Path('/dev/null')).parent, flush=True); sys.stdin.readline()\n"
)


def holding_a_private_folder(env):
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD_A_PRIVATE_FOLDER],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env=env,
    )
    return proc, proc.stdout.readline().strip()


def test_the_private_folder_of_a_killed_process_is_removed_by_the_next(tmp_path):
    env = dict(os.environ, TMPDIR=str(tmp_path))
    killed, killed_folder = holding_a_private_folder(env)
    live, live_folder = holding_a_private_folder(env)
    try:
        (tmp_path / killed_folder / ".x.partial").write_text("half an output")
        killed.send_signal(signal.SIGKILL)
        killed.wait(timeout=60)
        assert os.path.isdir(killed_folder)  # no exit handler ran
        proc = subprocess.run(
            [sys.executable, "-c", HOLD_A_PRIVATE_FOLDER],
            input="\n",
            capture_output=True,
            text=True,
            cwd=ROOT,
            env=env,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stderr
        assert not os.path.exists(killed_folder)
        assert os.path.isdir(live_folder), "a live process's folder was removed"
        assert not os.path.exists(proc.stdout.strip()), "the folder outlived its process"
    finally:
        live.communicate("\n", timeout=60)
        if killed.poll() is None:
            killed.kill()
            killed.wait()
    assert not os.path.exists(live_folder)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("s2a-partial-")]
