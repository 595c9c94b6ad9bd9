"""s2a-dataset under adversity: builds interrupted between configurations, two builds into one folder,
signals, shards damaged in place, persistent DataLoader workers, datasets that grow, manifests whose
fields contradict each other, readers given wrong arguments, splits with nothing in them, and inputs
given in another order."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from conftest import ROOT, run_cli
from dataset_helpers import make_aligned_take, write_aligned_set

import dataset.build as build_module
from capture import read_meta, write_take
from capture.atomic import write_json_atomic
from capture.errors import InputError
from dataset import read_manifest
from dataset.build import BuildOptions, build_dataset
from dataset.qa import validate
from dataset.splits import SplitRule
from dataset.stats import dataset_stats
from dataset.torch_dataset import ShardDataset

# several samples and shards from short takes; on the command line: SMALL_CLI
SMALL = {"max_sample_s": 0.5, "shard_bytes": int(0.06 * 1024 * 1024)}
SMALL_CLI = ("--max-sample-s", "0.5", "--shard-mb", "0.06")


def _opts(**kw) -> BuildOptions:
    return BuildOptions(**(SMALL | kw))


def _shards(ds: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(ds.glob("*.tar"))}


def _problems(ds: Path, deep: bool = False) -> set[tuple[str, str]]:
    return {(p.code, p.severity) for p in validate(ds, deep=deep).problems}


def _save(ds: Path, m: dict) -> None:
    (ds / "manifest.json").write_text(json.dumps(m, indent=1))


def _no_traceback(proc) -> None:
    assert "Traceback" not in proc.stderr, proc.stderr


@pytest.fixture(scope="module")
def takes(tmp_path_factory) -> Path:
    return write_aligned_set(tmp_path_factory.mktemp("adv") / "takes", count=4, speakers=2, seconds=1.5)


@pytest.fixture(scope="module")
def built(takes, tmp_path_factory) -> Path:
    ds = tmp_path_factory.mktemp("adv_ds") / "ds"
    build_dataset([takes], ds, _opts())
    return ds


def _copy(ds: Path, tmp_path: Path) -> Path:
    out = tmp_path / "copy"
    shutil.copytree(ds, out)
    return out


# ------------------------------------------------------------------------------ 1. cache of another build


class _Stop(Exception):
    pass


def test_rerun_never_reuses_samples_another_configuration_wrote(takes, tmp_path, monkeypatch):
    x = {"channels": "jawOpen,mouthClose"}
    ref = tmp_path / "ref"
    build_dataset([takes], ref, _opts(**x))
    out = tmp_path / "ds"

    def stop(*a, **k):
        raise _Stop()

    # build X stopped once every take is done (records written, no shard yet)
    with monkeypatch.context() as m:
        m.setattr(build_module, "plan_shards", stop)
        with pytest.raises(_Stop):
            build_dataset([takes], out, _opts(**x))
    records = out / ".work" / "takes"
    assert len(list(records.glob("*.json"))) == 4

    # build Y (the two channels swapped: same keys and sizes) stopped right after rewriting one sample
    real = build_module.ShardWriter

    class OneSampleThenStop(real):
        def close(self):
            super().close()
            raise _Stop()

    with monkeypatch.context() as m:
        m.setattr(build_module, "ShardWriter", OneSampleThenStop)
        with pytest.raises(_Stop):
            build_dataset([takes], out, _opts(channels="mouthClose,jawOpen"))
    # the take whose sample Y rewrote no longer has X's record vouching for it; the others keep theirs
    assert not (records / "take00.json").exists()
    assert len(list(records.glob("*.json"))) == 3

    build_dataset([takes], out, _opts(**x))  # X again, to completion
    assert _shards(out) == _shards(ref)
    assert (out / "manifest.json").read_bytes() == (ref / "manifest.json").read_bytes()


def test_cached_sample_changed_after_its_record_is_redone(takes, tmp_path, monkeypatch):
    out = tmp_path / "ds"
    with monkeypatch.context() as m:
        m.setattr(build_module, "plan_shards", lambda *a, **k: (_ for _ in ()).throw(_Stop()))
        with pytest.raises(_Stop):
            build_dataset([takes], out, _opts())
    sample = out / ".work" / "samples" / "take01_c000.tar"
    before = sample.read_bytes()
    data = bytearray(before)
    data[len(data) // 2] ^= 0x10  # same size, other bytes
    sample.write_bytes(bytes(data))
    build_dataset([takes], out, _opts())
    assert _problems(out, deep=True) == set()
    ref = tmp_path / "ref"
    build_dataset([takes], ref, _opts())
    assert _shards(out) == _shards(ref)


# ------------------------------------------------------------------------------ 2. one build per folder


def test_second_build_into_a_locked_folder_is_refused_at_once(takes, built, tmp_path):
    ds = _copy(built, tmp_path)
    partial = ds / ".train-000000.tar.partial"  # what the running build is writing
    partial.write_bytes(b"in progress")
    with build_module.output_lock(ds):
        proc = run_cli("dataset", "build", takes, "-o", ds, *SMALL_CLI)
        assert proc.returncode == 1, proc.stderr
        _no_traceback(proc)
        assert "another build (pid " in proc.stderr and "is writing into this folder" in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
        assert partial.exists()  # the refused build touched nothing
        leftover = [p for p in validate(ds).problems if p.code == "build_leftover"]
        assert leftover and "right now" in leftover[0].message and leftover[0].severity == "warning"
    assert not (ds / ".build.lock").exists()  # the holder removes it


def test_a_killed_builds_lock_does_not_block_the_next_build(takes, tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from pathlib import Path; from dataset.build import output_lock\n"
            "with output_lock(Path(sys.argv[1])):\n    print('locked', flush=True); sys.stdin.read()",
            str(ds),
        ],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        holder.kill()  # SIGKILL: no cleanup ran, the lock file stays
    finally:
        holder.wait()
    assert (ds / ".build.lock").exists()
    summary = build_dataset([takes], ds, _opts())
    assert not summary["up_to_date"] and not (ds / ".build.lock").exists()


# ------------------------------------------------------------------------------ 3. damaged shard repaired


def test_rebuild_repairs_a_shard_damaged_in_place(takes, built, tmp_path):
    ds = _copy(built, tmp_path)
    name = read_manifest(ds)["shards"][1]["name"]
    good = (ds / name).read_bytes()
    data = bytearray(good)
    data[len(data) // 3] ^= 0x40  # a flipped byte: the size stays
    (ds / name).write_bytes(bytes(data))
    assert ("shard_checksum", "error") in _problems(ds, deep=True)
    summary = build_dataset([takes], ds, _opts())
    assert summary["up_to_date"] is False and summary["repaired"] == [name]
    assert (ds / name).read_bytes() == good
    assert _problems(ds, deep=True) == set() and {p.name for p in (ds / ".work").iterdir()} == {
        "takes"
    }  # the take records only
    assert build_dataset([takes], ds, _opts())["up_to_date"] is True


# ------------------------------------------------------------------------------ 4. persistent workers


def _epochs(data: ShardDataset, persistent: bool) -> list[tuple[tuple[str, ...], str]]:
    loader = torch.utils.data.DataLoader(data, batch_size=2, num_workers=2, persistent_workers=persistent)
    out = []
    for epoch in range(2):
        data.set_epoch(epoch)
        keys, h = [], hashlib.sha256()
        for batch in loader:
            keys += batch["key"]
            h.update(batch["anim"].numpy().tobytes())
        out.append((tuple(keys), h.hexdigest()))
    return out


def test_set_epoch_reaches_persistent_dataloader_workers(built):
    args = dict(window=12, shuffle_buffer=4, seed=0)
    fresh = _epochs(ShardDataset(built, "train", **args), persistent=False)
    kept = _epochs(ShardDataset(built, "train", **args), persistent=True)
    assert fresh[0] != fresh[1]  # each epoch reshuffles and crops anew
    assert kept == fresh  # persistent workers see each epoch too


# ------------------------------------------------------------------------------ 5. signals


def _session(sid: int) -> list[int]:
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[3]) == sid:
                pids.append(int(d.name))
    return pids


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc, FIFOs")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["TERM", "KILL"])
def test_signalled_parallel_build_leaves_no_process_behind(takes, tmp_path, sig):
    ds = tmp_path / "ds"
    (ds / ".work" / "takes").mkdir(parents=True)
    # take00's cached record is a FIFO: the worker that opens it blocks there, mid-take, until we say
    fifo = ds / ".work" / "takes" / "take00.json"
    os.mkfifo(fifo)
    proc = subprocess.Popen(
        [sys.executable, "-m", "dataset", "build", str(takes), "-o", str(ds), "--jobs", "2"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    writer = None
    try:
        deadline = time.monotonic() + 60
        while writer is None:
            try:
                writer = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # succeeds once a worker reads it
            except OSError:
                assert proc.poll() is None and time.monotonic() < deadline, "no worker reached the take"
                time.sleep(0.02)
        proc.send_signal(sig)
        try:
            _, err = proc.communicate(timeout=30)  # returns once nothing holds stdout/stderr open
        except subprocess.TimeoutExpired:
            pytest.fail(f"processes of the build outlived it: {_session(proc.pid)}")
        if sig == signal.SIGTERM:
            assert proc.returncode == 143 and "terminated" in err and "Traceback" not in err, err
        else:
            assert proc.returncode == -signal.SIGKILL
        deadline = time.monotonic() + 10
        while _session(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _session(proc.pid) == []
    finally:
        if writer is not None:
            os.close(writer)
        for pid in _session(proc.pid):  # only what this test started (its own session)
            os.kill(pid, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
            proc.wait()


# ------------------------------------------------------------------------------ 6. takes that move split


def test_rebuild_names_the_takes_that_changed_split(takes, tmp_path):
    first = build_dataset([takes], tmp_path / "ds", _opts())
    assert first["split_changes"] == {}
    before = {src["take"]: src["split"] for src in read_manifest(tmp_path / "ds")["sources"]}
    more = tmp_path / "more"
    for i in range(4, 7):
        write_take(make_aligned_take(f"take{i:02d}", 1.5, subject="spk2", seed=i), more)
    moved_take = next(t for t, s in before.items() if s == "train")
    rule = SplitRule(val=(moved_take,))  # pinned elsewhere: at least this one moves
    second = build_dataset([takes, more], tmp_path / "ds", _opts(split=rule))
    after = {src["take"]: src["split"] for src in read_manifest(tmp_path / "ds")["sources"]}
    expected = {t: {"from": s, "to": after[t]} for t, s in before.items() if after[t] != s}
    assert moved_take in expected and second["split_changes"] == expected
    said = [w for w in second["warnings"] if "changed split" in w]
    assert len(said) == 1 and all(t in said[0] for t in expected) and "--val/--test" in said[0]
    assert not any("changed split" in w for w in read_manifest(tmp_path / "ds")["warnings"])


# ------------------------------------------------------------------------------ 7, 8. manifest cross-checks


def _edited(built: Path, tmp_path: Path, edit) -> Path:
    ds = _copy(built, tmp_path)
    m = json.loads((ds / "manifest.json").read_text())
    edit(m)
    _save(ds, m)
    return ds


def _move_test_take_to_train(m: dict) -> None:
    m["splits"]["train"]["takes"].append(m["splits"]["test"]["takes"].pop())


def _source_in_another_split(m: dict) -> None:
    src = m["sources"][0]
    src["split"] = "test" if src["split"] != "test" else "val"


@pytest.mark.parametrize(
    "edit, code",
    [
        (lambda m: m["stats"]["train"].update(samples=999), "stats_mismatch"),
        (lambda m: m["stats"]["train"].update(hours=5.0), "stats_mismatch"),
        (lambda m: m["stats"]["val"].update(usable_frames=1), "stats_mismatch"),
        (lambda m: m["shards"][0].update(duration_s=m["shards"][0]["duration_s"] + 100), "stats_mismatch"),
        (_move_test_take_to_train, "split_listing"),
        (_source_in_another_split, "split_listing"),
        (lambda m: m["features"]["names"].remove("fbank"), "feature_names"),
        (lambda m: m["splits"].pop("test"), "manifest_schema"),
    ],
    ids=["samples", "hours", "usable", "shard_duration", "listed", "source_split", "feature", "no_test"],
)
def test_validate_cross_checks_what_stats_shows(built, tmp_path, edit, code):
    ds = _edited(built, tmp_path, edit)
    found = validate(ds).problems
    assert code in {p.code for p in found} and not validate(ds).valid, found
    assert all(p.location for p in found)


def test_manifest_without_a_split_is_refused_and_rebuilt_without_traceback(takes, built, tmp_path):
    ds = _edited(built, tmp_path, lambda m: m["splits"].pop("test"))
    with pytest.raises(InputError, match="splits.test"):
        read_manifest(ds)
    proc = run_cli("dataset", "build", takes, "-o", ds, *SMALL_CLI, "--json")
    assert proc.returncode == 0, proc.stderr
    _no_traceback(proc)
    assert json.loads(proc.stdout)["up_to_date"] is False
    assert "test" in read_manifest(ds)["splits"] and _problems(ds) == set()


def test_validate_warns_about_a_builds_leftovers(built, tmp_path):
    ds = _copy(built, tmp_path)
    (ds / ".work" / "samples").mkdir(parents=True)  # beside the take records a build keeps: a stopped build's
    (ds / ".train-000009.tar.partial").write_bytes(b"x")
    report = validate(ds)
    assert report.valid and [(p.code, p.severity) for p in report.problems] == [("build_leftover", "warning")]
    assert ".work" in report.problems[0].location and "stopped" in report.problems[0].message


# ------------------------------------------------------------------------------ 9. reader arguments


@pytest.mark.parametrize(
    "kw, needle",
    [
        ({"split": "valid"}, "split must be one of train, val, test"),
        ({"features": ["mfcc"]}, "'mfcc' not in this dataset"),
        ({"window": 0}, "window must be a positive"),
        ({"window": -5}, "window must be a positive"),
        ({"window": 2.5}, "window must be a positive"),
    ],
)
def test_shard_dataset_refuses_wrong_arguments_when_made(built, kw, needle):
    with pytest.raises(InputError, match=needle):
        ShardDataset(built, **({"split": "train"} | kw))


# ------------------------------------------------------------------------------ 10. empty splits


def test_empty_splits_are_warned_about_and_unmeasured_stats_are_null(takes, tmp_path):
    one = tmp_path / "one"
    write_take(make_aligned_take("solo", 1.5, subject="spk0", seed=3), one)
    summary = build_dataset([one], tmp_path / "ds1", _opts())
    empty = [w for w in summary["warnings"] if "split is empty" in w]
    assert len(empty) == 2 and "--test-fraction 0.1" in empty[0] and "--val-fraction 0.1" in empty[1]
    assert {p.code for p in validate(tmp_path / "ds1").problems} == {"split_empty"}
    # split by speaker with one speaker: nothing to hold out either
    write_take(make_aligned_take("solo2", 1.5, subject="spk0", seed=4), one)
    summary = build_dataset([one], tmp_path / "ds2", _opts(split=SplitRule(by="speaker")))
    empty = [w for w in summary["warnings"] if "split is empty" in w]
    assert len(empty) == 2 and all("1 speaker(s)" in w and "by speaker" in w for w in empty)

    dead = tmp_path / "dead"
    write_take(make_aligned_take("lost", 1.5, subject="spk9", seed=5, gap=(0, 90)), dead)  # face lost
    ds = tmp_path / "ds3"
    summary = build_dataset([takes, dead], ds, _opts(split=SplitRule(val_fraction=0.0, test=("lost",))))
    assert any("test split has no usable frame" in w for w in summary["warnings"])
    stats = dataset_stats(ds)["channel_distributions"]["test"]
    jaw = stats["jawOpen"]
    assert jaw["frames"] == 0 and all(jaw[k] is None for k in ("mean", "std", "p05", "p50", "p95", "min"))
    assert ("split_empty", "warning") in _problems(ds)
    proc = run_cli("dataset", "stats", ds)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr


# ------------------------------------------------------------------------------ 11. input order


def test_inputs_in_another_order_give_the_same_dataset(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for folder, first in ((a, 0), (b, 3)):
        for i in range(first, first + 3):
            take = make_aligned_take(f"t{i}", 1.2, subject=f"s{i % 2}", seed=i)
            take.meta.extra["align"]["flags"] = ["low_confidence"]  # a warning per take
            write_take(take, folder)
    shutil.copytree(a / "t0", b / "a_copy_of_t0")  # t0's frames and audio under another id
    meta = read_meta(b / "a_copy_of_t0")
    meta.id = "a_copy_of_t0"
    write_json_atomic(b / "a_copy_of_t0" / "meta.json", meta.to_json())
    build_dataset([a, b], tmp_path / "ab", _opts())
    build_dataset([b, a], tmp_path / "ba", _opts())
    m = (tmp_path / "ab" / "manifest.json").read_bytes()
    assert m == (tmp_path / "ba" / "manifest.json").read_bytes()
    assert _shards(tmp_path / "ab") == _shards(tmp_path / "ba")
    kept = {src["take"] for src in json.loads(m)["sources"]}
    assert "a_copy_of_t0" in kept and "t0" not in kept  # the first id of the duplicates, either order
