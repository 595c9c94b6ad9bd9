"""A command whose output went to its standard output (``-o /dev/stdout``) sends its result lines to stderr;
the next command run in the same process (a script, a test) prints its own on stdout again."""

from __future__ import annotations

import os

from conftest import run_here


def test_the_next_command_in_a_process_prints_its_result_on_stdout(sim_take, tmp_path):
    run_here("capture", "import", sim_take, "-o", tmp_path / "takes", check=True)
    (take,) = [p for p in (tmp_path / "takes").iterdir() if (p / "meta.json").is_file()]
    link = tmp_path / "stdout.csv"
    os.symlink("/proc/self/fd/1", link)  # this process's standard output, as /dev/stdout names it
    first = run_here("capture", "export-csv", take, "-o", link, "--json")
    assert first.returncode == 0, first.stderr
    assert '"path"' in first.stderr and first.stdout == "", (first.stdout, first.stderr)  # the JSON line
    second = run_here("capture", "export-csv", take, "-o", tmp_path / "x.csv", "--json")
    assert second.returncode == 0, second.stderr
    assert '"path"' in second.stdout and "x.csv" in second.stdout, (second.stdout, second.stderr)
