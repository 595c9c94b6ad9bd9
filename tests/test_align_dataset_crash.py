"""From the crash probe (align, dataset build): workers that outlive a killed command, a hang when
workers cannot start, a take's segments left half written, write errors that name no file, Ctrl-C
tracebacks from the fork server."""

from __future__ import annotations

import os
import re
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT
from dataset_helpers import make_aligned_take, write_aligned_set

import align.batch
from align import AlignOptions, align_folder
from capture import Audio, FrameStatus, InputError, Take, read_audio, write_take
from capture.csv_take import read_livelink_csv
from dataset import BuildOptions, build_dataset

SIGINT_BIT = 1 << (signal.SIGINT - 1)


def _raw_take(samples: Path, take_id: str, repeats: int = 1) -> Take:
    """The NeuroSync test take (20 s, 60 fps) ``repeats`` times over, its face lost for 1.5 s near the
    start: align cuts it into two segments."""
    folder = samples / "paired/neurosync-trainer-lite-testset"
    take = read_livelink_csv(folder / "testset.csv")
    audio = read_audio(folder / "audio.wav")
    n = take.values.shape[0] * repeats
    values = np.concatenate([take.values] * repeats)
    status = np.concatenate([take.frame_status] * repeats)
    status[800:890] = FrameStatus.FACE_LOST
    values[status != FrameStatus.TRACKED] = np.nan
    out = Take(take.meta, np.arange(n) / 60.0, values, status)
    out.meta.id = take_id
    samples_ = np.concatenate([audio.samples] * repeats)
    out.attach_audio(Audio(samples_, audio.sample_rate, audio.subtype), 0.0, "paired_frame_convention")
    return out


@pytest.fixture(scope="module")
def long_takes(samples, tmp_path_factory) -> Path:
    """Two raw takes of 2.7 min each: seconds of work for an align worker."""
    root = tmp_path_factory.mktemp("long")
    for i in range(2):
        write_take(_raw_take(samples, f"long{i}", repeats=8), root)
    return root


def _start(*args, **kw) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        start_new_session=True,  # its own process group: what a terminal's Ctrl-C reaches
        **kw,
    )


def _stat(pid: int) -> tuple[int, int] | None:
    """(ppid, process group) of a process, or None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()
    return int(fields[1]), int(fields[2])


def _group(pgid: int) -> list[int]:
    """The processes of the process group ``pgid``."""
    return [int(p) for p in os.listdir("/proc") if p.isdigit() and (_stat(int(p)) or (0, 0))[1] == pgid]


def _children(pid: int) -> list[int]:
    return [p for p in _group(pid) if (_stat(p) or (0, 0))[0] == pid]


def _wait_for(condition, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def _end_group(proc: subprocess.Popen) -> None:
    """Whatever is left of the test's command, its process group, ended."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.communicate()


def _visible(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith(".")) if folder.is_dir() else []


# -- 1. s2a-align --jobs 2 killed: its workers stop with it ------------------------------------------------
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_align_workers_stop_with_a_killed_align(long_takes, tmp_path, sig):
    out = tmp_path / "out"
    proc = _start("align", long_takes, "-o", out, "--jobs", 2, "--vad", "none")
    try:
        assert _wait_for(lambda: len(_children(proc.pid)) == 2, 20), "the workers did not start"
        workers = _children(proc.pid)
        time.sleep(0.3)  # at work on their takes
        proc.send_signal(sig)
        _out, err = proc.communicate(timeout=20)
        if sig == signal.SIGTERM:
            assert proc.returncode == 143, err
            assert err.strip().splitlines() == ["s2a-align: terminated (SIGTERM)"], err
        gone = _wait_for(lambda: not any(_stat(w) for w in workers), 3)
        assert gone, f"workers {workers} outlived s2a-align ({sig.name})"
        time.sleep(1.0)
        assert _visible(out) == []  # nothing written after the command was gone
    finally:
        _end_group(proc)


# -- 2. workers that cannot start: one line, exit 1, no hang -----------------------------------------------
def test_align_too_few_file_descriptors_for_workers_is_one_line_not_a_hang(long_takes, tmp_path):
    def few_files() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (14, 14))

    proc = _start(
        "align", long_takes, "-o", tmp_path / "out", "--jobs", 2, "--vad", "none", preexec_fn=few_files
    )
    try:
        _out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        _end_group(proc)
        pytest.fail("s2a-align hung after failing to start its workers")
    try:
        assert proc.returncode == 1, err
        (line,) = err.strip().splitlines()
        assert line.startswith("s2a-align: error: cannot start the worker processes (Too many open files)")
        assert "--jobs" in line and "ulimit -n" in line
        assert _wait_for(lambda: not _group(proc.pid), 5), "a worker outlived s2a-align"
    finally:
        _end_group(proc)


# -- 3. a take's segments appear together; the build says when a set is incomplete -------------------------
def test_a_take_s_segments_are_written_all_or_none(samples, tmp_path, monkeypatch):
    raw = tmp_path / "raw"
    folder = write_take(_raw_take(samples, "ns"), raw)
    out = tmp_path / "out"
    opts = AlignOptions(vad="none")
    real_write_take = align.batch.write_take
    calls = []

    def full_disk_at_the_second(take, where):
        calls.append(take.meta.id)
        if len(calls) == 2:
            raise InputError("cannot write the take: No space left on device", Path(where) / take.meta.id)
        return real_write_take(take, where)

    monkeypatch.setattr(align.batch, "write_take", full_disk_at_the_second)
    report = align_folder(folder, out, opts)
    assert "No space left on device" in report["error"]
    assert f"{out / 'ns.seg02'}: cannot write the take" in report["error"]  # the output, not a hidden folder
    assert calls == ["ns.seg01", "ns.seg02"]
    assert sorted(p.name for p in out.iterdir()) == []  # neither segment, and no hidden leftover
    monkeypatch.setattr(align.batch, "write_take", real_write_take)
    report = align_folder(folder, out, opts)
    assert report.get("error") is None and report["segments"] == 2
    assert _visible(out) == ["ns.seg01", "ns.seg02"]


def _segment(take_id: str, recording: str, k: int, count: int, seed: int) -> Take:
    take = make_aligned_take(take_id, 2.0, seed=seed)
    take.meta.extra["align"] |= {"parent": {"id": recording}, "segment": k, "segment_count": count}
    return take


def test_the_build_warns_of_a_take_whose_segments_are_partly_there(tmp_path):
    takes = tmp_path / "aligned"
    for i, (take_id, k) in enumerate(
        [("rec.seg01", 1), ("rec.seg03", 3), ("whole.seg01", 1), ("whole.seg02", 2)]
    ):
        count = 2 if take_id.startswith("whole") else 3
        write_take(_segment(take_id, take_id.split(".")[0], k, count, seed=i), takes)
    options = BuildOptions(features=("energy", "fbank"), max_sample_s=1.0)
    summary = build_dataset([takes], tmp_path / "ds", options)
    incomplete = [w for w in summary["warnings"] if "segments s2a-align cut" in w]
    assert len(incomplete) == 1, summary["warnings"]
    (warning,) = incomplete
    assert warning.startswith(
        f"take rec: {takes} holds 2 of the 3 segments s2a-align cut from it (rec.seg02 "
    )
    assert "re-run s2a-align on the raw take" in warning


def test_the_build_warns_of_a_take_aligned_twice_with_other_options(tmp_path):
    """One raw take aligned into two folders with other options (two segments there, one here): the ids
    differ (ids alike are refused as two takes of one id), so both alignments were built without a word."""
    first, second = tmp_path / "a1", tmp_path / "a2"
    for take, where, run in [
        (_segment("rec.seg01", "rec", 1, 2, seed=1), first, "f1"),
        (_segment("rec.seg02", "rec", 2, 2, seed=2), first, "f1"),
        (_segment("rec", "rec", 1, 1, seed=3), second, "f2"),
        (_segment("other", "other", 1, 1, seed=4), second, "f3"),
    ]:
        take.meta.extra["align"]["fingerprint"] = run
        write_take(take, where)
    options = BuildOptions(features=("energy", "fbank"), max_sample_s=1.0)
    summary = build_dataset([first, second], tmp_path / "ds", options)
    twice = [w for w in summary["warnings"] if "aligned twice" in w]
    assert twice == [
        f"take rec: aligned twice with other options (in {first} and {second}): the segments of each are "
        "built, so its speech counts twice in the dataset: build from one of those folders"
    ], summary["warnings"]
    once = build_dataset([first], tmp_path / "ds1", options)
    assert not [w for w in once["warnings"] if "aligned" in w], once["warnings"]


# -- 4. a full disk names the file the build was writing ----------------------------------------------------
@pytest.mark.parametrize(
    ("limit", "jobs", "where"),
    [(50_000, 2, r"\.work/samples/take0\d_c000\.tar"), (250_000, 1, r"train-000000\.tar")],
)
def test_a_build_on_a_full_disk_names_the_file(tmp_path, limit, jobs, where):
    takes = write_aligned_set(tmp_path / "takes", count=4, seconds=3.0)

    def small_disk() -> None:  # writes past `limit` bytes fail as on a full disk, write() naming no file
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    ds = tmp_path / "ds"
    proc = _start("dataset", "build", takes, "-o", ds, "--jobs", jobs, preexec_fn=small_disk)
    try:
        _out, err = proc.communicate(timeout=60)
    finally:
        _end_group(proc)
    lines = [x for x in err.splitlines() if not x.startswith("build: ")]
    assert proc.returncode == 1 and "Traceback" not in err, err
    (line,) = lines
    assert re.fullmatch(
        rf"s2a-dataset: error: {re.escape(str(ds))}/{where}: cannot be written: File too large", line
    )


# -- 5. Ctrl-C while the build's workers start: the build handles it, no process prints a traceback -------
def _sigint_blocked_or_ignored(pid: int) -> bool | None:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    masks = dict(line.split(":\t") for line in status.splitlines() if line.startswith(("SigBlk", "SigIgn")))
    return bool((int(masks["SigBlk"], 16) | int(masks["SigIgn"], 16)) & SIGINT_BIT)


def test_ctrl_c_reaches_only_the_build_not_its_fork_server_or_workers(tmp_path):
    takes = write_aligned_set(tmp_path / "takes", count=4, seconds=20.0)
    proc = _start("dataset", "build", takes, "-o", tmp_path / "ds", "--jobs", 2)
    try:
        seen: dict[int, bool] = {}  # every other process of the build's group: SIGINT blocked or ignored

        def workers_started() -> bool:
            for pid in _group(proc.pid):
                if pid != proc.pid and pid not in seen:
                    state = _sigint_blocked_or_ignored(pid)
                    if state is not None:
                        seen[pid] = state
            return sum(_stat(p) is not None and _stat(p)[0] != proc.pid for p in seen) >= 2  # workers

        assert _wait_for(workers_started, 20), "the workers did not start"
        assert seen and all(seen.values()), seen  # the fork server while it imports, and the workers
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal: the whole group
        _out, err = proc.communicate(timeout=20)
        assert proc.returncode == 130 and "Traceback" not in err, err
        assert err.strip().splitlines()[-1] == "s2a-dataset: interrupted"
        assert _wait_for(lambda: not _group(proc.pid), 10), "processes of the build outlived it"
    finally:
        _end_group(proc)
