"""Progress of long jobs by the clock (``capture.command.TimedProgress``): a line every few seconds with
done/total, the rate and the time left, none for a job over within the first interval, and every step
of a job said (one that cannot count its work says how long it has run). The helper runs on a fake
clock; ``s2a-view render``, ``s2a-train predict`` and ``s2a-dataset build`` run for real with the
interval made 0 through ``$S2A_PROGRESS_INTERVAL_S``, so that every frame, window and take says its
line."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_here
from dataset_helpers import build_five_take_dataset, make_aligned_take, write_aligned_set
from test_train_pipeline import TINY

from capture import write_take
from capture.command import PROGRESS_INTERVAL_S, PROGRESS_INTERVAL_VAR, TimedProgress, duration_words
from dataset.manifest import TAKE_RECORDS


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


def test_the_interval_runs_across_the_steps_of_a_job():
    job, clock, lines = _progress(10)
    for k in range(1, 11):
        clock.now += 0.6  # 6 s: lines at 5 s and at the end
        job.update(k)
    job.step("audio", 4, "s")
    clock.now += 3.0  # 3 s after the last line: a step that started with it stays quiet
    job.update(1)
    clock.now += 2.0
    job.update(2)
    assert lines[2:] == ["render: a.mp4: audio: 2/4 s (50.0 %), 0.4 s/s, about 5 s left"]
    job.update(4)  # the step's end: said, as the job said something
    assert lines[-1] == "render: a.mp4: audio: 4/4 s (100.0 %), 0.8 s/s, done in 5 s"


def test_a_step_that_cannot_count_says_how_long_it_has_run():
    lines: list[str] = []
    job = TimedProgress("predict: a.wav", say=lines.append, interval=0.05)
    deadline = time.monotonic() + 60  # a library call that reports nothing, as long as two lines take
    with job.ticking("features of 1 h 0 min of audio"):  # on a busy machine (0.1 s on a quiet one)
        while len(lines) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert len(lines) >= 3, lines  # one at once (the interval passed), then each 0.05 s, then the end
    said = "predict: a.wav: features of 1 h 0 min of audio: "
    assert all(re.fullmatch(rf"{said}\d+ s so far", line) for line in lines[:-1]), lines
    assert re.fullmatch(rf"{said}done in \d+ s", lines[-1]), lines
    quiet: list[str] = []
    short = TimedProgress("predict: a.wav", say=quiet.append, interval=5.0)
    with short.ticking("features"):
        time.sleep(0.2)
    assert quiet == []


def test_a_job_at_once_says_its_first_unit_with_a_bar():
    clock, lines = FakeClock(), []
    job = TimedProgress("", 8, "takes", lines.append, 5.0, clock, at_once=True, bar=20)
    clock.now += 1.0
    job.update(1, "take00 (2.0 s of audio)")
    clock.now += 1.0
    job.update(2, "take01 (2.0 s of audio)")
    assert lines == [
        "[##                  ] 1/8 takes (12.5 %), 1 takes/s, about 7 s left: take00 (2.0 s of audio)"
    ]


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


def test_render_says_its_frames_by_the_clock_and_then_its_audio_and_file(tmp_path):
    take = write_take(make_aligned_take("take00", 0.5, subject="spk0", seed=0), tmp_path / "takes")
    every = _render(take, tmp_path / "every.mp4", "0")
    said = [line for line in every.stderr.splitlines() if line.startswith("render: every.mp4: ")]
    lines = [line for line in said if " frames (" in line]
    assert len(lines) == 30  # 0.5 s at 60 fps, a line a frame
    assert lines[0].startswith("render: every.mp4: 1/30 frames (3.3 %), ") and " frames/s, about " in lines[0]
    assert lines[-1].startswith("render: every.mp4: 30/30 frames (100.0 %), ") and ", done in " in lines[-1]
    after = said[said.index(lines[-1]) + 1 :]  # the encoder's last frames, the audio, the file's index
    assert after[0] == "render: every.mp4: finishing the video: 0 s so far", after
    assert after[1].startswith("render: every.mp4: finishing the video: done in ")
    assert after[2].startswith("render: every.mp4: audio: 0/1 s (0.0 %)"), after
    audio_end = next(i for i, line in enumerate(after) if line.startswith("render: every.mp4: audio: 1/1 s"))
    assert ", done in " in after[audio_end]
    assert after[audio_end + 1 :] == [
        "render: every.mp4: writing the file: 0 s so far",
        "render: every.mp4: writing the file: done in 0 s",
    ]
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


def test_predict_says_every_step_of_each_file(tiny_run, tmp_path, monkeypatch):
    """Reading the audio (the decoder reports nothing) and the CSV say how long they have run; the
    16 kHz audio, the spectra, the pitch and the windows, which go in blocks, how many are done, the
    rate and the time left (an hour of audio: 20 s, 29 s and 5 s of silence before)."""
    rng = np.random.default_rng(0)
    wav = tmp_path / "speech.wav"
    sf.write(wav, (0.1 * rng.standard_normal(70 * 16000)).astype(np.float32), 16000)  # 70 s: 4 windows
    monkeypatch.setenv(PROGRESS_INTERVAL_VAR, "0")
    proc = run_here("train", "predict", tiny_run, wav, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("predict: speech.wav: ")]
    step_of = {line: line.split(" (")[0].rsplit(": ", 1)[0] for line in lines}
    steps = [step_of[line] for line in lines if " windows (" not in line]
    assert list(dict.fromkeys(steps)) == [
        "predict: speech.wav: reading the audio",
        "predict: speech.wav: 16 kHz mono audio",
        "predict: speech.wav: checking the audio for clipping",
        "predict: speech.wav: measuring the audio's bandwidth and level",
        "predict: speech.wav: features of 1 min of audio: spectra",
        "predict: speech.wav: features of 1 min of audio: pitch",
        "predict: speech.wav: writing speech.csv",
    ]
    for step in ("reading the audio", "writing speech.csv"):
        mine = [line for line in lines if step_of[line].endswith(step)]
        assert mine[0].endswith(" s so far") and ": done in " in mine[-1], mine
    for step, unit in (("16 kHz mono audio", "blocks"), ("spectra", "blocks"), ("pitch", "pieces")):
        mine = [line for line in lines if step_of[line].endswith(step)]
        assert mine[0].endswith(f": 0/{mine[-1].split('/')[1].split()[0]} {unit} (0.0 %)"), mine
        assert f" {unit}/s" in mine[1] and ", done in " in mine[-1] and "(100.0 %)" in mine[-1], mine
    windows = [line for line in lines if " windows (" in line]
    assert [line.split(" (")[0] for line in windows] == [
        f"predict: speech.wav: {k}/4 windows" for k in range(1, 5)
    ]
    assert " windows/s, about " in windows[0] and ", done in " in windows[-1]
    order = [lines.index(line) for line in (windows[0], windows[-1])]
    assert step_of[lines[order[0] - 1]].endswith(": pitch") and ", done in " in lines[order[0] - 1]
    assert lines[order[1] + 1] == "predict: speech.wav: writing speech.csv: 0 s so far"
    monkeypatch.delenv(PROGRESS_INTERVAL_VAR)
    sf.write(wav, (0.1 * rng.standard_normal(3 * 16000)).astype(np.float32), 16000)  # done within 5 s
    quiet = run_here("train", "predict", tiny_run, wav, "-o", tmp_path / "again")
    assert quiet.returncode == 0 and "predict: " not in quiet.stderr, quiet.stderr


def test_the_build_says_its_takes_by_the_same_clock(tmp_path, monkeypatch):
    """The build's own one-a-second throttle is gone: its takes are said by ``TimedProgress``, the first
    at once, then every interval, and the last, with the rate and the time left."""
    from dataset import BuildOptions, build_dataset

    aligned = write_aligned_set(tmp_path / "aligned", count=3, speakers=1, seconds=1.0)
    options = BuildOptions(features=("fbank",), max_sample_s=0.5)
    monkeypatch.setenv(PROGRESS_INTERVAL_VAR, "0")
    lines: list[str] = []
    build_dataset([aligned], tmp_path / "every", options, say=lines.append)
    bars = [line for line in lines if line.startswith("[")]
    assert [line.split(": ")[-1] for line in bars] == [f"take0{i} (1.0 s of audio)" for i in range(3)]
    assert bars[0].startswith("[#######             ] 1/3 takes (33.3 %), ") and " takes/s, about " in bars[0]
    assert bars[-1].startswith("[####################] 3/3 takes (100.0 %), ") and ", done in " in bars[-1]
    monkeypatch.setenv(PROGRESS_INTERVAL_VAR, "60")
    lines.clear()
    build_dataset([aligned], tmp_path / "few", options, say=lines.append)
    bars = [line for line in lines if line.startswith("[")]
    assert [line.split(": ")[-1] for line in bars] == ["take00 (1.0 s of audio)", "take02 (1.0 s of audio)"]


def test_units_taken_from_a_cache_count_in_the_share_not_in_the_rate():
    job, clock, lines = _progress(100)
    clock.now += 1.0
    job.update(60, "cached", skipped=60)  # a second of checking the cache: no rate of work
    clock.now += 5.0
    job.update(70, skipped=60)  # 10 computed in 6 s
    clock.now += 0.5
    job.update(80, skipped=None, at_once=True)  # as many skipped as last time, said whatever the clock
    assert lines == [
        "render: a.mp4: 70/100 frames (70.0 %), 1.7 frames/s, about 18 s left",
        "render: a.mp4: 80/100 frames (80.0 %), 3.1 frames/s, about 6 s left",
    ]
    job.step("", 5, "frames")
    job.update(5, "all 5 from the cache", skipped=5, at_once=True)
    assert lines[-1] == "render: a.mp4: 5/5 frames (100.0 %), done in 0 s: all 5 from the cache"


def test_the_rate_counts_from_when_the_first_unit_of_work_began():
    job, clock, lines = _progress(10)
    clock.now += 10.0  # worker processes starting: no work done
    job.update(1, skipped=0, at_once=True, began=clock.now - 0.5)  # the first unit took 0.5 s
    clock.now += 0.5
    job.update(2, at_once=True, began=clock.now - 1.5)  # a second worker's, begun before the first
    clock.now += 4.0
    job.update(10)
    assert lines == [
        "render: a.mp4: 1/10 frames (10.0 %), 2 frames/s, about 4 s left",
        "render: a.mp4: 2/10 frames (20.0 %), 1.3 frames/s, about 6 s left",
        "render: a.mp4: 10/10 frames (100.0 %), 1.8 frames/s, done in 14 s",  # the whole step's time
    ]


def test_the_build_rates_its_takes_from_the_first_take_begun_and_names_only_takes_computed(
    tmp_path, monkeypatch
):
    """Starting the build's worker processes took seconds, counted as the first take's (18 s left said
    of 0.3 s); a line said while takes from the cache were counted named one of them as the take done."""
    from dataset import BuildOptions, build_dataset

    aligned = write_aligned_set(tmp_path / "aligned", count=4, speakers=1, seconds=1.0)
    options = BuildOptions(features=("fbank",), max_sample_s=0.5, keep_work=True, jobs=2)
    monkeypatch.setenv(PROGRESS_INTERVAL_VAR, "0")
    lines: list[tuple[float, str]] = []
    build_dataset([aligned], tmp_path / "ds", options, say=lambda x: lines.append((time.monotonic(), x)))
    started = next(t for t, x in lines if x.startswith("reading takes: 4/4"))  # the takes' step begins
    said, first = next((t, x) for t, x in lines if x.startswith("[#####  "))
    left = float(first.split("about ")[1].split(" s left")[0])  # seconds: a minute is far off
    assert left < said - started, (said - started, first)  # not the workers' start-up over again
    records = tmp_path / "ds" / ".work" / TAKE_RECORDS
    (again,) = [p for p in records.glob("*.json") if json.loads(p.read_text())["take"] == "take02"]
    again.unlink()  # take02 computed again, between takes from the cache
    texts: list[str] = []
    build_dataset([aligned], tmp_path / "ds", replace(options, jobs=1, shard_bytes=60_000), say=texts.append)
    bars = [x.split(": ", 1)[1] for x in texts if x.startswith("[")]
    assert bars == [
        "1 from the cache",
        "2 from the cache",
        "take02 (1.0 s of audio; 2 from the cache)",
        "take02 (1.0 s of audio; 3 from the cache)",
    ], texts


def _build_cli(takes: Path, ds: Path, interval: str, *extra: str) -> list[str]:
    """The lines ``s2a-dataset build`` says on stderr, run as a user runs it."""
    env = {k: v for k, v in os.environ.items() if k != PROGRESS_INTERVAL_VAR} | {
        PROGRESS_INTERVAL_VAR: interval
    }
    cmd = [sys.executable, "-m", "dataset", "build", str(takes), "-o", str(ds), "--features", "fbank"]
    cmd += ["--max-sample-s", "0.5", "--keep-work", *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return [line for line in proc.stderr.splitlines() if not line.startswith("s2a-dataset: warning: ")]


def test_the_build_says_its_shards_by_the_clock_and_a_build_from_the_cache_says_so_once(tmp_path):
    """The shards were a line each (hundreds of shards, hundreds of lines): now a line at most every
    interval with the count, rate and time left, and the last always. A rebuild whose takes all come
    from the cache says that in one line (no rate of 3,000 takes/s), then its shards."""
    takes = write_aligned_set(tmp_path / "takes", count=4, speakers=1, seconds=1.0)
    every = _build_cli(takes, tmp_path / "ds", "0", "--shard-mb", "0.03")  # a shard a sample: 8
    shards = [line for line in every if line.startswith("build: writing shards: [")]
    assert [line.split("] ")[1].split(" (")[0] for line in shards] == [f"{k}/8 shards" for k in range(1, 9)]
    assert " shards/s, about " in shards[0] and shards[-1].endswith(", done in 0 s: test-000001.tar (0.0 MB)")
    assert every.index(shards[0]) > max(i for i, line in enumerate(every) if " takes (" in line)
    assert not [line for line in every if line.startswith("build: shard ")]
    cached = _build_cli(takes, tmp_path / "ds", "60", "--shard-mb", "0.06")  # other shards, same takes
    assert cached == [
        "build: [####################] 4/4 takes (100.0 %), done in 0 s: all 4 from the cache",
        "build: writing shards: [####################] 5/5 shards (100.0 %), "
        + cached[1].split("(100.0 %), ")[1],
    ], cached
    assert cached[1].endswith(": test-000000.tar (0.1 MB)") and " shards/s, done in " in cached[1]


def test_raw_takes_the_build_aligns_are_said_by_the_clock(tmp_path, monkeypatch):
    """Raw takes the build aligns itself were a line each ("aligning X"): now the first at once (aligning
    is slow), then a line every interval, and the last."""
    from dataset import BuildOptions, build_dataset

    for i in range(2):
        take = make_aligned_take(f"raw{i}", 1.5, seed=i)
        take.meta.source_kind = "livelink_csv"
        del take.meta.extra["align"]
        write_take(take, tmp_path / "raw")
    monkeypatch.setenv(PROGRESS_INTERVAL_VAR, "60")
    lines: list[str] = []
    build_dataset([tmp_path / "raw"], tmp_path / "ds", BuildOptions(features=("fbank",)), say=lines.append)
    reading = [line for line in lines if line.startswith("reading takes: ")]
    assert reading[0] == "reading takes: 0/2 takes (0.0 %): aligning raw0", lines
    assert len(reading) == 2 and reading[1].startswith("reading takes: 2/2 takes (100.0 %), "), lines
    assert reading[1].endswith(": raw1 aligned: 1 take(s)") and not [
        x for x in lines if x.startswith("aligning")
    ]
