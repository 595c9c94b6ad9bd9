"""Progress of long jobs by the clock (``capture.command.TimedProgress``): a line every few seconds with
done/total, the rate and the time left, none for a job over within the first interval. The helper runs
on a fake clock; ``s2a-view render`` and ``s2a-train predict`` run for real with the interval made 0
through ``$S2A_PROGRESS_INTERVAL_S``, so that every frame and window says its line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_here
from dataset_helpers import build_five_take_dataset, make_aligned_take
from test_train_pipeline import TINY

from capture import write_take
from capture.command import PROGRESS_INTERVAL_S, PROGRESS_INTERVAL_VAR, TimedProgress, duration_words


class FakeClock:
    """Seconds that pass only when the test says so."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _progress(total: int, interval: float = 5.0) -> tuple[TimedProgress, FakeClock, list[str]]:
    clock, lines = FakeClock(), []
    return TimedProgress("render: a.mp4", total, "frames", lines.append, interval, clock), clock, lines


def test_a_job_over_within_the_first_interval_says_nothing():
    job, clock, lines = _progress(100)
    for k in range(1, 101):
        clock.now += 0.04  # 4 s in all
        job.update(k)
    assert lines == []


def test_lines_come_once_per_interval_with_the_rate_and_the_time_left_then_a_last_line():
    job, clock, lines = _progress(216_000)
    for k in range(1, 216_001):
        clock.now += 1 / 33  # 33 frames/s: 1 h 49 min in all
        job.update(k)
        if k == 166:  # the first line: the first update 5 s after the start (165 frames is 4.9999 s)
            assert lines == ["render: a.mp4: 166/216,000 frames (0.1 %), 33 frames/s, about 1 h 49 min left"]
    said = [int(line.split(": ")[2].split("/")[0].replace(",", "")) for line in lines]
    assert set(np.diff(said[:-1])) == {166}  # a line every 5 s, not a tenth of the job (11 min) apart
    assert lines[-1] == "render: a.mp4: 216,000/216,000 frames (100.0 %), 33 frames/s, done in 1 h 49 min"
    assert lines[-2] == "render: a.mp4: 215,966/216,000 frames (99.9 %), 33 frames/s, about 1 s left"


def test_a_slow_job_says_each_unit_that_ends_after_an_interval_and_a_fraction_of_a_rate():
    job, clock, lines = _progress(10)
    clock.now += 8.0
    job.update(1)
    clock.now += 3.0
    job.update(2)  # 3 s after the last line: nothing
    clock.now += 3.0
    job.update(3)
    assert lines == [
        "render: a.mp4: 1/10 frames (10.0 %), 0.12 frames/s, about 1 min left",
        "render: a.mp4: 3/10 frames (30.0 %), 0.21 frames/s, about 33 s left",
    ]


def test_the_last_line_comes_at_once_when_anything_was_said():
    job, clock, lines = _progress(3)
    clock.now += 6.0
    job.update(1)
    clock.now += 0.5
    job.update(2)
    clock.now += 0.5
    job.update(3)
    assert lines[-1] == "render: a.mp4: 3/3 frames (100.0 %), 0.43 frames/s, done in 7 s"
    assert len(lines) == 2


def test_durations_read_as_a_person_reads_a_wait():
    assert [duration_words(s) for s in (0.4, 45, 89, 12 * 60, 3599, 6480)] == [
        "0 s",
        "45 s",
        "1 min",
        "12 min",
        "1 h 0 min",
        "1 h 48 min",
    ]


def test_the_interval_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv(PROGRESS_INTERVAL_VAR, "0.5")
    assert TimedProgress("x", 1, "frames").interval == 0.5
    for wrong in ("soon", "-1", "inf", "nan"):  # not a number of seconds: the default
        monkeypatch.setenv(PROGRESS_INTERVAL_VAR, wrong)
        assert TimedProgress("x", 1, "frames").interval == PROGRESS_INTERVAL_S
    monkeypatch.delenv(PROGRESS_INTERVAL_VAR)
    assert TimedProgress("x", 1, "frames").interval == PROGRESS_INTERVAL_S


def _render(take: Path, out: Path, interval: str | None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != PROGRESS_INTERVAL_VAR}
    if interval is not None:
        env[PROGRESS_INTERVAL_VAR] = interval
    cmd = [sys.executable, "-m", "viewer", "render", str(take), "-o", str(out), "--size", "64"]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc


def test_render_says_its_frames_by_the_clock(tmp_path):
    take = write_take(make_aligned_take("take00", 0.5, subject="spk0", seed=0), tmp_path / "takes")
    every = _render(take, tmp_path / "every.mp4", "0")
    lines = [line for line in every.stderr.splitlines() if line.startswith("render: every.mp4: ")]
    assert len(lines) == 30  # 0.5 s at 60 fps, a line a frame
    assert lines[0].startswith("render: every.mp4: 1/30 frames (3.3 %), ") and " frames/s, about " in lines[0]
    assert lines[-1].startswith("render: every.mp4: 30/30 frames (100.0 %), ") and ", done in " in lines[-1]
    quiet = _render(take, tmp_path / "quiet.mp4", None)  # 0.5 s of frames end within the first 5 s
    assert "render: " not in quiet.stderr, quiet.stderr


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    """A one-step model of the smallest shape on the five-take dataset."""
    from train.config import resolve_config
    from train.fit import fit

    root = tmp_path_factory.mktemp("progress")
    ds = build_five_take_dataset(root)
    fit(ds, root / "run", resolve_config(sets=TINY + ["max_steps=1", "eval_every=1"]), say=lambda _m: None)
    return root / "run"


def test_predict_counts_each_files_windows(tiny_run, tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    wav = tmp_path / "speech.wav"
    sf.write(wav, (0.1 * rng.standard_normal(70 * 16000)).astype(np.float32), 16000)  # 70 s: 4 windows
    monkeypatch.setenv(PROGRESS_INTERVAL_VAR, "0")
    proc = run_here("train", "predict", tiny_run, wav, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("predict: speech.wav: ")]
    assert [line.split(" (")[0] for line in lines] == [
        f"predict: speech.wav: {k}/4 windows" for k in range(1, 5)
    ]
    assert " windows/s, about " in lines[0] and ", done in " in lines[-1]
    monkeypatch.delenv(PROGRESS_INTERVAL_VAR)
    quiet = run_here("train", "predict", tiny_run, wav, "-o", tmp_path / "again")
    assert quiet.returncode == 0 and "predict: " not in quiet.stderr, quiet.stderr
