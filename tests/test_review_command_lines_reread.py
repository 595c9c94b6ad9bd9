"""Second reading of the command-line and render-output changes: the leading-dash hint names the
option whose value it is, a render's partial-file lock is let go when a stop arrives while it is taken,
and ``remote PHONE ACTION --help`` lists the options that action takes."""

from __future__ import annotations

import os

import pytest
from conftest import run_cli

import capture.file_lock
import viewer.output
from capture.file_lock import try_lock
from viewer.cli import build_parser


def test_the_hint_gives_option_equals_name_only_for_the_option_the_name_followed(capsys):
    """``render in.csv --size -o -x.mp4``: argparse says --size lacks its value; the hint said to write
    ``--size=-x.mp4``, a file name as the panel size. -x.mp4 is -o's value: only ./-x.mp4 is right."""
    parser = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["render", "in.csv", "--size", "-o", "-x.mp4"])
    line = capsys.readouterr().err.splitlines()[-1]
    assert line.startswith("s2a-view render: error: argument --size: expected one argument"), line
    assert line.endswith("(-x.mp4 is taken for an option: for a file of that name, write ./-x.mp4)"), line
    with pytest.raises(SystemExit):  # the option it followed, abbreviated: named in full
        parser.parse_args(["render", "in.csv", "--aud", "-s.wav", "-o", "o.mp4"])
    assert capsys.readouterr().err.endswith("write ./-s.wav, or --audio=-s.wav)\n")


def test_a_name_with_a_space_read_as_the_input_gets_no_hint(capsys):
    """argparse reads ``-my take.csv`` (a space in it) as a positional: it was the input here, yet an
    unrelated usage error said it was "taken for an option" and to write ./-my take.csv."""
    parser = build_parser()
    assert str(parser.parse_args(["render", "-my take.csv", "-o", "o.mp4"]).input) == "-my take.csv"
    with pytest.raises(SystemExit):
        parser.parse_args(["render", "-my take.csv", "-o", "o.mp4", "--size", "abc"])
    line = capsys.readouterr().err.splitlines()[-1]
    assert line == "s2a-view render: error: argument --size: invalid int value: 'abc'", line


def test_a_stop_while_the_partial_file_is_locked_lets_the_lock_go(tmp_path, monkeypatch):
    """Ctrl-C (or SIGTERM, raised where it lands) just after ``lock_partial`` took its lock left the
    descriptor open, and the lock with it: the next render of that name in the process was refused as
    "another command is writing this video"."""
    out, tmp = tmp_path / "take.mp4", tmp_path / ".take.mp4.partial.mp4"

    def lock_then_stopped(fd: int, shared: bool = False) -> bool:
        try_lock(fd, shared)  # the real lock, then the signal's exception
        raise KeyboardInterrupt

    monkeypatch.setattr(capture.file_lock, "try_lock", lock_then_stopped)
    before = len(os.listdir("/proc/self/fd"))
    with pytest.raises(KeyboardInterrupt):
        viewer.output.lock_partial(tmp, out)
    assert len(os.listdir("/proc/self/fd")) == before
    monkeypatch.setattr(capture.file_lock, "try_lock", try_lock)
    os.close(viewer.output.lock_partial(tmp, out))  # not refused


def test_remote_action_help_lists_the_options_it_takes():
    """``remote PHONE battery --json`` works, but ``remote PHONE battery --help`` listed only -h."""
    proc = run_cli("capture", "remote", "phone.local", "battery", "--help")
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    for shown in ("--reply-host ADDR", "--reply-port PORT", "--timeout S", "--json print the result as JSON"):
        assert shown in text, text
    assert "seconds to wait for each reply (default: 2)" in text


def test_json_lines_hold_numpy_numbers_as_numbers_and_their_nan_as_null(capsys):
    """``emit_json`` is strict for Python floats only: a NumPy number went through ``default=str``, so
    ``np.float32('nan')`` came out as the string "nan" and every NumPy number as a string."""
    import json

    import numpy as np

    from capture.command import emit_json

    emit_json(
        {
            "rmse": np.float32("nan"),
            "steps": np.int64(3),
            "mean": np.float64(0.5),
            "s": np.array([1.0, np.inf]),
        }
    )
    assert json.loads(capsys.readouterr().out) == {"rmse": None, "steps": 3, "mean": 0.5, "s": [1.0, None]}
