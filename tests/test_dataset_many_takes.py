"""A dataset of many takes on the console: the build's progress at most a line a second, the takes taken
from the cache counted, not named; warnings saying the same of many takes printed as one line."""

from __future__ import annotations

from pathlib import Path

from conftest import run_cli
from dataset_helpers import write_aligned_set

from dataset.cli import grouped_warnings

SMALL_CLI = ("--max-sample-s", "0.5", "--shard-mb", "0.06")
FLAG = "align flagged its audio/face offset (low_confidence): check it, or build with --skip-flagged"


def test_warnings_alike_of_many_takes_are_one_line_at_the_first_ones_place():
    warnings = [f"take t{i}: {FLAG}" for i in range(6)]
    warnings.insert(2, "the training split holds 40 % of the audio")
    warnings += [
        "take t9: its audio has no energy above 4 kHz",
        "take t1: its audio has no energy above 4 kHz",
    ]
    assert grouped_warnings(warnings) == [
        f"6 takes (t0, t1, t2 and 3 more): {FLAG}",
        "the training split holds 40 % of the audio",
        "take t9: its audio has no energy above 4 kHz",  # two alike stay two lines
        "take t1: its audio has no energy above 4 kHz",
    ]
    assert grouped_warnings([f"take t{i}: {FLAG}" for i in range(4)], named=4) == [
        f"4 takes (t0, t1, t2, t3): {FLAG}"
    ]
    # a take said twice is one take of the group, and the group one line
    twice = [f"take {t}: {FLAG}" for t in ("a", "b", "a", "c", "d", "b")]
    assert grouped_warnings(twice) == [f"4 takes (a, b, c and 1 more): {FLAG}"]


def test_a_rebuild_from_the_cache_says_one_line_not_one_per_take(tmp_path: Path):
    aligned = write_aligned_set(tmp_path / "aligned", count=8, speakers=2, seconds=1.0)
    ds = tmp_path / "ds"
    first = run_cli("dataset", "build", aligned, "-o", ds, *SMALL_CLI, "--normalization", "zscore")
    assert first.returncode == 0, first.stderr
    again = run_cli("dataset", "build", aligned, "-o", ds, *SMALL_CLI, "--normalization", "neutral")
    assert again.returncode == 0, again.stderr
    bars = [line for line in again.stderr.splitlines() if line.startswith("build: [")]
    assert len(bars) == 1 and "8/8" in bars[0] and "8 from the cache" in bars[0], again.stderr
