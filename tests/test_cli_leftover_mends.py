"""Leftovers of the command-line contract: Ctrl-C while s2a-align and s2a-dataset import, out-of-range
option values of s2a-view and s2a-align as usage errors, the serial sync box's dropped lines in the JSON,
a GLB chunk longer than its file, and workers that cannot start under a low ``ulimit -n``."""

from __future__ import annotations

import functools
import os
import re
import resource
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, run_here
from dataset_helpers import write_aligned_set
from live_helpers import listen_with_sync_box

from capture.errors import InputError
from viewer.face import builtin_face
from viewer.gltf import load_gltf, write_glb


def _usage_error(proc: subprocess.CompletedProcess, prog: str, line: str) -> None:
    """argparse's usage-error form: exit 2, the usage first, the error last, no traceback."""
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[0].startswith(f"usage: {prog}") and "Traceback" not in proc.stderr, proc.stderr
    assert lines[-1] == line, proc.stderr


def _one_line_error(proc: subprocess.CompletedProcess, needle: str) -> str:
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    lines = [x for x in proc.stderr.strip().splitlines() if not x.startswith("build: ")]
    assert len(lines) == 1 and ": error: " in lines[0] and needle in lines[0], proc.stderr
    return lines[0]


# -- 1. Ctrl-C while the command still imports numpy, scipy, PyTorch --------------------------------------
STAGES = ("capture", "align", "dataset", "train", "viewer")


def _in_our_code(traceback: str) -> bool:
    """Whether a traceback passes through this repository's code after the guard is in place: a Ctrl-C
    before (Python's own start-up, runpy finding the module, capture importing the guard's few standard
    modules) is beyond any guard of ours: so is a stage's import of the guard (``from capture.import_guard
    import ...``, ``from . import import_guard``), slow on a loaded machine or a first run compiling
    bytecode."""
    frames = re.findall(r'File "([^"]+)", line \d+[^\n]*\n(?:[ \t]+(?!File ")(\S[^\n]*))?', traceback)
    ours = [(f, code) for f, code in frames if any(f"{os.sep}{pkg}{os.sep}" in f for pkg in STAGES)]
    return any(not f.endswith("import_guard.py") and "import_guard" not in code for f, code in ours)


@pytest.mark.parametrize(
    ("args", "prog"),
    [
        ([sys.executable, "-m", "align", "NOTHING", "-o", "OUT"], "s2a-align"),
        ([str(Path(sys.executable).parent / "s2a-align"), "NOTHING", "-o", "OUT"], "s2a-align"),
        ([sys.executable, "-m", "dataset", "build", "NOTHING", "-o", "OUT"], "s2a-dataset"),
        ([sys.executable, "-m", "viewer", "plot", "NOTHING", "-o", "OUT"], "s2a-view"),
    ],
)
def test_ctrl_c_while_the_command_imports_stops_without_a_traceback(tmp_path, args, prog):
    """Importing align or dataset takes 0.5 s or more (capture's numpy first): Ctrl-C there printed a
    KeyboardInterrupt traceback (or an error of a half-imported numpy)."""
    args = [{"NOTHING": str(tmp_path / "none"), "OUT": str(tmp_path / "out")}.get(a, a) for a in args]
    # The delays are shares of the command's own run to its error, measured here: on a loaded machine
    # its start-up (and every import) takes longer, and fixed delays all fell before Python's handler.
    began = time.monotonic()
    subprocess.run(args, capture_output=True, cwd=ROOT, timeout=120)
    took = time.monotonic() - began
    stopped = 0
    for share in (0.1, 0.2, 0.35, 0.5, 0.65, 0.8):
        proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        delay = round(share * took, 3)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
        if f"{prog}: error:" in err:  # imports were done before the signal (a fast machine): not this case
            continue
        if "Traceback" in err and not _in_our_code(err):  # Python still starting (a loaded machine)
            continue
        if proc.returncode == -signal.SIGINT and not err:  # before Python set its own Ctrl-C: the system's
            continue
        assert proc.returncode == 130 and "Traceback" not in err, (delay, err)
        assert err.strip().splitlines()[-1] == f"{prog}: interrupted", (delay, err)
        stopped += 1
    assert stopped, "every Ctrl-C came after the imports"


def test_a_program_that_imports_the_stages_keeps_its_own_ctrl_c(tmp_path):
    check = (
        "import signal, capture.cli, align.cli, dataset.cli, train.cli, viewer.cli; "
        "print(*(m.cli._guard for m in (capture, align, dataset, train, viewer)), "
        "signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
    )
    proc = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, cwd=ROOT)
    assert proc.stdout.split() == ["False"] * 5 + ["True"], proc.stdout + proc.stderr
    # a Ctrl-C while capture loads, before the guard, is still Python's KeyboardInterrupt there
    proc = subprocess.Popen(
        [sys.executable, "-c", "print('started', flush=True); import align"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    assert proc.stdout.readline() == "started\n"  # Python's own Ctrl-C is set (a loaded machine: later)
    time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    _out, err = proc.communicate(timeout=60)
    # Python's own traceback, not a command's one line: a KeyboardInterrupt, or, when it lands while a C
    # extension imports (NumPy's), the ImportError that extension makes of it (seen on a loaded machine)
    assert proc.returncode in (1, -signal.SIGINT), err
    assert "KeyboardInterrupt" in err or "ImportError" in err, err
    assert "interrupted" not in err, err


# -- 2. option values out of their range: usage errors (exit 2); input problems stay exit 1 ---------------
@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--max-offset-ms", "0", "must be between 20 and 10000, not 0"),
        ("--max-offset-ms", "nan", "must be between 20 and 10000, not nan"),
        ("--fps", "0", "must be between 1 and 1000, not 0"),
        ("--face-lead-ms", "600", "must be between -500 and 500, not 600"),
        ("--max-gap-ms", "-1", "must be between 0 and 60000, not -1"),
        ("--offset-ms", "1e9", "must be between -3600000 and 3600000, not 1000000000"),
        ("--max-disagreement-ms", "inf", "must be between 0 and 10000, not inf"),
        ("--min-segment-s", "1e308", "must be between 0 and 3600, not 1e+308"),
    ],
)
def test_align_options_out_of_range_are_usage_errors(tmp_path, option, value, message):
    proc = run_here("align", tmp_path / "none", "-o", tmp_path / "out", option, value)
    _usage_error(proc, "s2a-align", f"s2a-align: error: argument {option}: {message}")
    assert not (tmp_path / "out").exists()


@pytest.fixture(scope="module")
def take(tmp_path_factory) -> Path:
    return write_aligned_set(tmp_path_factory.mktemp("view") / "takes", count=1, seconds=1.0) / "take00"


@pytest.mark.parametrize(
    ("args", "sub", "line"),
    [
        (
            ["render", "TAKE", "-o", "OUT.png", "--size", "0"],
            "render",
            "argument --size: must be in 16..4096, not 0",
        ),
        (
            ["render", "TAKE", "-o", "OUT.png", "--frame", "-1"],
            "render",
            "argument --frame: must be a frame index",
        ),
        (["render", "TAKE", "-o", "OUT.png", "--time", "nan"], "render", "argument --time: must be seconds"),
        (
            ["render", "TAKE", "-o", "OUT.png", "--compare", "TAKE", "--compare-offset", "inf"],
            "render",
            "argument --compare-offset: must be a number of seconds, not inf",
        ),
        (["plot", "TAKE", "-o", "OUT.png", "--start", "nan"], "plot", "argument --start: must be a number"),
        (
            ["plot", "TAKE", "-o", "OUT.png", "--start", "5", "--end", "1"],
            "plot",
            "argument --start: 5 s must",
        ),
        (["stream", "TAKE", "--to", "127.0.0.1:9", "--speed", "0"], "stream", "argument --speed: must be in"),
        (
            ["report", "TAKE", "-o", "OUT.html", "--limit", "-1"],
            "report",
            "argument --limit: must be 0 or more",
        ),
    ],
)
def test_view_options_out_of_range_are_usage_errors(take, tmp_path, args, sub, line):
    names = {"TAKE": str(take), "OUT.png": str(tmp_path / "o.png"), "OUT.html": str(tmp_path / "o.html")}
    proc = run_here("viewer", *[names.get(a, a) for a in args])
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[0].startswith(f"usage: s2a-view {sub}"), proc.stderr
    assert lines[-1].startswith(f"s2a-view {sub}: error: {line}"), proc.stderr
    assert not (tmp_path / "o.png").exists() and not (tmp_path / "o.html").exists()


def test_a_view_option_value_the_input_rules_out_stays_an_input_error(take, tmp_path):
    proc = run_here("viewer", "render", take, "-o", tmp_path / "o.png", "--frame", "100000")
    _one_line_error(proc, "--frame 100000 is outside 0..")
    proc = run_here("viewer", "plot", take, "-o", tmp_path / "p.png", "--start", "50", "--end", "60")
    _one_line_error(proc, "--start/--end hold no frame")


# -- 3. the serial sync box's lines of line noise are counted in the JSON lines ----------------------------
def test_listen_counts_the_dropped_serial_lines_in_its_json(tmp_path):
    noise = [b"CLAP\n", b"\x00\x01\x02 garbage\n", b"\xff\xfe\xfd\n", b"MARK end\n"]
    lines, err, code = listen_with_sync_box(tmp_path, noise)
    assert code == 0, err
    assert lines[0]["sync_events"] == 2 and lines[0]["sync_lines_dropped"] == 2, lines
    assert err.count("the serial sync box sent a line that is not text") == 1, err
    lines, err, code = listen_with_sync_box(tmp_path / "clean", [b"CLAP\n"])
    assert code == 0 and lines[0]["sync_lines_dropped"] == 0, err


# -- 4. a GLB chunk longer than what follows it ------------------------------------------------------------
def _overrun_bin_chunk(path: Path, extra: int) -> Path:
    data = bytearray(path.read_bytes())
    json_len = struct.unpack_from("<I", data, 12)[0]
    bin_at = 12 + 8 + json_len
    bin_len = struct.unpack_from("<I", data, bin_at)[0]
    struct.pack_into("<I", data, bin_at, bin_len + extra)
    path.write_bytes(bytes(data))
    return path


def test_a_glb_chunk_longer_than_the_file_is_refused(take, tmp_path):
    good = write_glb(builtin_face(), tmp_path / "good.glb")
    assert load_gltf(good).channels
    bad = _overrun_bin_chunk(write_glb(builtin_face(), tmp_path / "bad.glb"), 64)
    with pytest.raises(InputError, match=r"bad\.glb: GLB chunk 1 says \d+ bytes, but only \d+ follow"):
        load_gltf(bad)
    proc = run_here("viewer", "render", take, "--face", bad, "-o", tmp_path / "o.png", "--size", "32")
    _one_line_error(proc, f"{bad}: GLB chunk 1 says")
    assert not (tmp_path / "o.png").exists()


# -- 5. workers that cannot start under a low open-file limit: one line, whoever notices first -------------
def test_a_build_with_too_few_file_descriptors_for_its_workers_is_one_line(tmp_path):
    takes = write_aligned_set(tmp_path / "takes", count=6, seconds=2.0)
    # here 18-22 fail, each a worker later (the last, 22, mid-start); the builds run at once (each its own
    # process with its own limit), as their interpreters' start-ups need not wait for each other
    builds = {
        limit: subprocess.Popen(
            [sys.executable, "-m", "dataset", "build", takes, "-o", tmp_path / f"ds{limit}", "--jobs", "4"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            preexec_fn=functools.partial(resource.setrlimit, resource.RLIMIT_NOFILE, (limit, limit)),
            env={**os.environ, "PYTHONWARNINGS": "ignore"},
        )
        for limit in (17, 19, 21, 22, 23)
    }
    refused = 0
    try:
        for limit, build in builds.items():
            out, err = build.communicate(timeout=120)
            if build.returncode == 0:
                continue
            refused += 1
            proc = subprocess.CompletedProcess(build.args, build.returncode, out, err)
            line = _one_line_error(proc, "cannot start the worker processes (Too many open files)")
            assert "ulimit -n" in line, (limit, proc.stderr)
    finally:  # none left running after a failure
        for build in builds.values():
            if build.poll() is None:
                build.kill()
                build.communicate()
    assert refused, "no open-file limit here was too low for 4 workers"


def test_a_script_given_dash_m_among_its_own_arguments_keeps_its_ctrl_c(tmp_path):
    """`python tool.py -m train` is the script's -m, not Python's: the import guard took its Ctrl-C."""
    script = tmp_path / "tool.py"
    script.write_text(
        "import signal, sys\nsys.path.insert(0, sys.argv[-1])\nimport capture\n"
        "print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)\n"
    )
    for args in (["-m", "train"], ["-m", "align"]):
        proc = subprocess.run(
            [sys.executable, str(script), *args, str(ROOT)], capture_output=True, text=True, cwd=tmp_path
        )
        assert proc.stdout.split() == ["True"], proc.stdout + proc.stderr
