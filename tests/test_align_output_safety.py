"""``s2a-align`` and its output folder over repeated and overlapping runs: one run at a time writes into a
folder (a second is refused at once, a killed one blocks nothing), and aligned takes whose raw take is
gone are named in a warning and removed with ``--prune``, never anything else."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, run_cli, run_here

from capture import find_takes, read_meta
from capture.file_lock import held_elsewhere

FAST = ("--vad", "none", "--no-video")  # no speech model to load: the tests stay fast
LOCK = ".align.lock"
TWO_SEGMENTS = "20250107_SimSpk01_2"  # seed 1: a face lost for long enough to cut this take (and _6) in two


@pytest.fixture(scope="module")
def raw_takes(tmp_path_factory) -> Path:
    """Six imported simulated take folders (one speaker, 5 s each)."""
    root = tmp_path_factory.mktemp("raw")
    run_cli("capture", "simulate", "-o", root / "sim", "--takes", 6, "--seconds", 5, "--seed", 1, check=True)
    run_cli("capture", "import", root / "sim", "-o", root / "takes", check=True)
    assert len(find_takes([root / "takes"])) == 6
    return root / "takes"


def _copy_takes(raw_takes: Path, dest: Path, names: list[str] | None = None) -> Path:
    dest.mkdir(parents=True)
    for take in sorted(p for p in raw_takes.iterdir() if p.is_dir()):
        if names is None or take.name in names:
            shutil.copytree(take, dest / take.name)
    return dest


def _start_align(*args) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "align", *map(str, args)]
    return subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _holder_pid(proc: subprocess.Popen, out: Path) -> int:
    """The pid the running ``proc`` wrote into its lock file, once it holds it."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            text = (out / LOCK).read_text().strip()
        except OSError:
            text = ""
        if text.isdigit():
            return int(text)
        if proc.poll() is not None:
            raise AssertionError(f"s2a-align ended without ever locking {out}:\n{proc.stderr.read()}")
        time.sleep(0.01)
    raise AssertionError("s2a-align took no lock in 2 minutes")


def _stopped(pid: int) -> bool:
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0] == "T"


def _aligned(out: Path) -> dict[str, dict]:
    """Aligned take name -> its ``meta.extra["align"]``."""
    return {p.name: read_meta(p).extra["align"] for p in find_takes([out])}


def _warnings(stderr: str) -> list[str]:
    """The warning lines about aligned takes whose raw take is gone (a take's own warnings left out)."""
    return [line for line in stderr.splitlines() if "warning:" in line and "that are gone" in line]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SIGSTOP and /proc")
def test_a_second_align_into_the_same_folder_is_refused_at_once(raw_takes, tmp_path):
    raw = _copy_takes(raw_takes, tmp_path / "raw")
    out = tmp_path / "aligned"
    takes = sorted(p for p in raw.iterdir() if p.is_dir())
    first = _start_align(*takes, "-o", out, "--max-gap-ms", 250, "--jobs", 1, *FAST)
    try:
        pid = _holder_pid(first, out)
        assert pid == first.pid
        os.kill(pid, signal.SIGSTOP)  # the first run is held in the middle of its writing
        while not _stopped(pid):
            time.sleep(0.01)
        assert held_elsewhere(out / LOCK), "the first run ended before it could be held"
        # the lock is a hidden file: no take to anything that scans the folder
        assert all(not p.name.startswith(".") for p in find_takes([out]))
        began = time.monotonic()
        second = run_here("align", *reversed(takes), "-o", out, "--max-gap-ms", 1000, *FAST)
        assert time.monotonic() - began < 60
        assert second.returncode == 1 and second.stdout == ""
        assert second.stderr.splitlines() == [
            f"s2a-align: error: another s2a-align (pid {pid}) is writing into {out}: wait for it or choose "
            "another -o"
        ]
    finally:
        if first.poll() is None:
            os.kill(first.pid, signal.SIGCONT)
        _, err = first.communicate(timeout=240)
    assert first.returncode == 0, err
    aligned = _aligned(out)
    assert len(aligned) == 8  # six takes, two of them in two segments
    assert {a["options"]["max_gap_s"] for a in aligned.values()} == {0.25}  # one run's outputs only
    assert not (out / LOCK).exists()  # the run removed its lock when it ended


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="flock")
def test_a_killed_align_leaves_no_lock_in_the_way(raw_takes, tmp_path):
    raw = _copy_takes(raw_takes, tmp_path / "raw")
    out = tmp_path / "aligned"
    first = _start_align(raw, "-o", out, *FAST)
    try:
        _holder_pid(first, out)
    finally:
        first.kill()
        first.communicate(timeout=60)
    assert (out / LOCK).is_file() and not held_elsewhere(out / LOCK)  # its file stays, its lock went
    proc = run_here("align", raw, "-o", out, *FAST)
    assert proc.returncode == 0 and "another s2a-align" not in proc.stderr, proc.stderr
    assert len(_aligned(out)) == 8 and not (out / LOCK).exists()
    # a lock file a kill left behind is no take to the dataset stage
    (out / LOCK).write_text("12345\n")
    build = run_here("dataset", "build", out, "-o", tmp_path / "ds")
    assert build.returncode == 0 and LOCK not in build.stdout + build.stderr, build.stderr
    assert find_takes([out]) and all(p.is_dir() for p in find_takes([out]))


def test_outputs_of_a_deleted_raw_take_are_named_in_one_warning(raw_takes, tmp_path):
    raw = _copy_takes(raw_takes, tmp_path / "raw")
    other = _copy_takes(raw_takes, tmp_path / "other", names=[])
    shutil.copytree(raw / "20250107_SimSpk01_5", other / "elsewhere")
    meta = json.loads((other / "elsewhere" / "meta.json").read_text())
    (other / "elsewhere" / "meta.json").write_text(json.dumps(meta | {"id": "elsewhere"}))
    shutil.rmtree(raw / "20250107_SimSpk01_5")
    out = tmp_path / "aligned"
    run_here("align", raw, "-o", out, *FAST, check=True)
    run_here("align", other, "-o", out, *FAST, check=True)  # a second input folder into the same output
    assert {f"{TWO_SEGMENTS}.seg01", f"{TWO_SEGMENTS}.seg02", "elsewhere"} <= set(_aligned(out))

    # a take left out of a run but still on disk, and the other folder's take: no warning
    proc = run_here("align", raw / "20250107_SimSpk01_1", "-o", out, *FAST, check=True)
    assert _warnings(proc.stderr) == []

    shutil.rmtree(raw / TWO_SEGMENTS)
    proc = run_here("align", raw, "-o", out, *FAST, "--json", check=True)
    assert len(proc.stdout.splitlines()) == 4  # the JSON lines stay one report per take
    (warning,) = _warnings(proc.stderr)
    assert warning.startswith(
        f"s2a-align: warning: 2 aligned takes in {out} come from raw takes that are gone"
    )
    assert f"{TWO_SEGMENTS}.seg01, {TWO_SEGMENTS}.seg02 (from {(raw / TWO_SEGMENTS).resolve()})" in warning
    assert "--prune" in warning and "elsewhere" not in warning
    assert {f"{TWO_SEGMENTS}.seg01", f"{TWO_SEGMENTS}.seg02", "elsewhere"} <= set(_aligned(out))  # kept

    # the other folder's run sees the same orphans, and never the first folder's takes still on disk
    (warning,) = _warnings(run_here("align", other, "-o", out, *FAST, check=True).stderr)
    assert TWO_SEGMENTS in warning and "20250107_SimSpk01_1" not in warning


def test_prune_removes_only_aligned_takes_whose_raw_take_is_gone(raw_takes, tmp_path):
    raw = _copy_takes(raw_takes, tmp_path / "raw", names=["20250107_SimSpk01_1", TWO_SEGMENTS])
    other = _copy_takes(raw_takes, tmp_path / "other", names=["20250107_SimSpk01_3", "20250107_SimSpk01_4"])
    out = tmp_path / "aligned"
    run_here("align", raw, "-o", out, *FAST, check=True)
    run_here("align", other, "-o", out, *FAST, check=True)
    # what else a user keeps there: a note, a folder, a raw take, an aligned take renamed by hand
    (out / "README.txt").write_text("takes of May\n")
    (out / "notes").mkdir()
    shutil.copytree(raw_takes / "20250107_SimSpk01_6", out / "raw_copy")
    shutil.copytree(out / f"{TWO_SEGMENTS}.seg01", out / "my_favourite")
    shutil.rmtree(raw / TWO_SEGMENTS)
    shutil.rmtree(other / "20250107_SimSpk01_4")

    proc = run_here("align", raw, "-o", out, *FAST, "--prune")
    assert proc.returncode == 0, proc.stderr
    removed = [line for line in proc.stderr.splitlines() if "removed" in line]
    assert len(removed) == 1 and _warnings(proc.stderr) == []
    assert removed[0].startswith(f"s2a-align: removed 3 aligned takes from {out} whose raw take is gone")
    left = sorted(p.name for p in out.iterdir())
    assert left == [
        "20250107_SimSpk01_1",
        "20250107_SimSpk01_3",
        "README.txt",
        "my_favourite",
        "notes",
        "raw_copy",
    ]
    assert (out / "README.txt").read_text() == "takes of May\n"
    # nothing left to warn of or to prune
    proc = run_here("align", raw, "-o", out, *FAST, "--prune", check=True)
    assert "removed" not in proc.stderr and _warnings(proc.stderr) == []
    assert sorted(p.name for p in out.iterdir()) == left


def test_a_renamed_raw_take_folder_is_no_orphan(raw_takes, tmp_path):
    raw = _copy_takes(raw_takes, tmp_path / "raw", names=["20250107_SimSpk01_1", "20250107_SimSpk01_3"])
    other = _copy_takes(raw_takes, tmp_path / "other", names=["20250107_SimSpk01_4"])
    out = tmp_path / "aligned"
    run_here("align", raw, "-o", out, *FAST, check=True)
    (raw / "20250107_SimSpk01_1").rename(raw / "renamed_by_hand")
    proc = run_here("align", raw, "-o", out, *FAST, "--json", check=True)
    assert _warnings(proc.stderr) == []
    reports = {r["id"]: r for r in map(json.loads, proc.stdout.splitlines())}
    # the take keeps its id; aligned again once, its output records where it is now
    assert reports["20250107_SimSpk01_1"]["skipped"] is False and reports["20250107_SimSpk01_3"]["skipped"]
    parent = _aligned(out)["20250107_SimSpk01_1"]["parent"]
    assert parent["path"] == str((raw / "renamed_by_hand").resolve())
    # another run into the same output: the renamed take is still on disk, nothing to warn of or prune
    proc = run_here("align", other, "-o", out, *FAST, "--prune", check=True)
    assert _warnings(proc.stderr) == [] and "removed" not in proc.stderr
    assert len(_aligned(out)) == 3


def _unreachable(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "warning:" in line and "not reachable" in line]


def test_outputs_of_a_raw_take_on_a_folder_not_there_are_never_pruned(raw_takes, tmp_path):
    """A drive not mounted (or a share mounted at another path): the folder that held the raw take is not
    there, so the take is not known to be gone: said apart, kept also with --prune."""
    drive = _copy_takes(raw_takes, tmp_path / "drive" / "takes", names=[TWO_SEGMENTS])
    local = _copy_takes(raw_takes, tmp_path / "local", names=["20250107_SimSpk01_1", "20250107_SimSpk01_3"])
    out = tmp_path / "aligned"
    run_here("align", drive, "-o", out, *FAST, check=True)
    run_here("align", local, "-o", out, *FAST, check=True)
    (tmp_path / "drive").rename(tmp_path / "unmounted")  # the drive's takes are no longer where they were
    shutil.rmtree(local / "20250107_SimSpk01_3")  # gone from a folder that is there
    proc = run_here("align", local, "-o", out, *FAST, "--prune")
    assert proc.returncode == 0, proc.stderr
    (away,) = _unreachable(proc.stderr)
    assert away.startswith(f"s2a-align: warning: 2 aligned takes in {out} come from raw takes that are not")
    assert f"{TWO_SEGMENTS}.seg01, {TWO_SEGMENTS}.seg02 (from {(drive / TWO_SEGMENTS).resolve()})" in away
    assert "kept, also with --prune" in away and "20250107_SimSpk01_3" not in away
    (removed,) = [line for line in proc.stderr.splitlines() if "removed" in line]
    assert "removed 1 aligned take " in removed and "20250107_SimSpk01_3" in removed
    assert TWO_SEGMENTS not in removed and _warnings(proc.stderr) == []
    assert set(_aligned(out)) == {"20250107_SimSpk01_1", f"{TWO_SEGMENTS}.seg01", f"{TWO_SEGMENTS}.seg02"}
    # mounted again where it was: nothing to say
    (tmp_path / "unmounted").rename(tmp_path / "drive")
    proc = run_here("align", local, "-o", out, *FAST, "--prune", check=True)
    assert _unreachable(proc.stderr) == [] and _warnings(proc.stderr) == [] and "removed" not in proc.stderr


def test_a_take_of_a_hundred_segments_or_more_is_not_aligned_again(raw_takes, tmp_path):
    """The aligner names the 100th segment ``X.seg100``: its outputs are found as those of seg01 to seg99."""
    from align.batch import orphans

    raw = _copy_takes(raw_takes, tmp_path / "raw", names=[TWO_SEGMENTS])
    out = tmp_path / "aligned"
    run_here("align", raw, "-o", out, *FAST, check=True)
    # the take's second segment as the aligner would name a take's 100th
    seg = out / f"{TWO_SEGMENTS}.seg100"
    (out / f"{TWO_SEGMENTS}.seg02").rename(seg)
    meta = json.loads((seg / "meta.json").read_text())
    (seg / "meta.json").write_text(json.dumps(meta | {"id": seg.name}))
    proc = run_here("align", raw, "-o", out, *FAST, "--json", check=True)
    (report,) = map(json.loads, proc.stdout.splitlines())
    assert report["skipped"] is True, report
    assert [Path(p).name for p in report["outputs"]] == [f"{TWO_SEGMENTS}.seg01", seg.name]
    assert sorted(_aligned(out)) == [f"{TWO_SEGMENTS}.seg01", seg.name]
    shutil.rmtree(raw / TWO_SEGMENTS)
    assert sorted(p.name for p, _ in orphans(out, [])) == [f"{TWO_SEGMENTS}.seg01", seg.name]
