"""``s2a-train`` when the dataset changes under a run: a rebuild while ``fit`` reads it stops the run
with one line (a shard differing from an unchanged manifest keeps its own error), a resumed run whose
validation takes changed restarts ``best_val``, ``eval`` names the takes it trained or validated on,
``eval``/``predict`` on a run still training say so, and a resume refused on a rebuilt dataset says what
changed. A rebuild is simulated by swapping another build's files into the dataset folder (shards first,
manifest.json last and atomically, as a build replaces them) from inside the run (its progress lines)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch
from conftest import run_gloo_ranks, run_here
from dataset_helpers import SR, make_aligned_take, speech_like, write_aligned_set
from test_train_pipeline import TINY

from capture import write_take
from capture.errors import InputError
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule
from train.checkpoint import load_checkpoint, run_lock, save_checkpoint
from train.config import resolve_config
from train.evaluate import evaluate
from train.fit import fit
from train.predict import predict

QUIET = {"say": lambda _m: None}


def _build(takes: Path, out: Path, val: str = "take03", test: str = "take04") -> Path:
    options = BuildOptions(
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, (val,), (test,)),
        max_sample_s=1.0,
    )
    build_dataset([takes], out, options, say=lambda _m: None)
    return out


@pytest.fixture(scope="module")
def builds(tmp_path_factory):
    """Builds of one dataset folder's history: ``a`` (take00-02 train, take03 val, take04 test),
    ``fewer`` (take02 removed), ``val_edited`` (take03's values changed, nothing else), ``leak``
    (take00, a training take of ``a``, in the test split); and a run of 4 steps on ``a``."""
    root = tmp_path_factory.mktemp("changes")
    takes = write_aligned_set(root / "takes", count=5, speakers=2, seconds=2.0)
    a = _build(takes, root / "a")
    fewer_takes = root / "fewer_takes"
    shutil.copytree(takes, fewer_takes)
    shutil.rmtree(fewer_takes / "take02")
    edited = root / "edited_takes"
    shutil.copytree(takes, edited)
    shutil.rmtree(edited / "take03")
    write_take(make_aligned_take("take03", 2.0, subject="spk1", seed=99), edited)
    out = {
        "root": root,
        "a": a,
        "fewer": _build(fewer_takes, root / "fewer"),
        "val_edited": _build(edited, root / "val_edited"),
        "leak": _build(takes, root / "leak", val="take03", test="take00"),
    }
    out["run"] = root / "run"
    fit(a, out["run"], _cfg("max_steps=4", "eval_every=2"), **QUIET)
    return out


# the progress line of step 5 (log_every 5), after the checkpoint of step 4 (eval_every 2)
AFTER_CHECKPOINT = "step 5: mse"


def _cfg(*sets: str) -> dict:
    return resolve_config(sets=TINY + list(sets))


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _swap_in(src: Path, dst: Path) -> None:
    """Replace the build in ``dst`` by the one in ``src``: its shards, then its manifest.json (renamed
    into place), the old shards it does not have removed last."""
    names = {p.name for p in src.glob("*.tar")}
    for name in sorted(names):
        shutil.copyfile(src / name, dst / f".{name}.new")
        os.replace(dst / f".{name}.new", dst / name)
    shutil.copyfile(src / "manifest.json", dst / ".manifest.json.new")
    os.replace(dst / ".manifest.json.new", dst / "manifest.json")
    for old in dst.glob("*.tar"):
        if old.name not in names:
            old.unlink()


def _on_line(prefix: str, action, lines: list[str]):
    """A ``say`` that records the lines and runs ``action`` once, at the first line starting with
    ``prefix``."""
    done = []

    def say(line: str) -> None:
        lines.append(line)
        if line.startswith(prefix) and not done:
            done.append(line)
            action()

    return say


# 1. a dataset rebuilt while fit reads it


def test_a_training_take_removed_mid_run_stops_the_run_with_one_line(builds, tmp_path):
    """The rebuild removes take02: its new shards no longer match the manifest the run started on. The
    run used to stop with "shard size differs from the manifest: s2a-dataset validate DS" (which then
    said valid) or "not a dataset (no manifest.json)"."""
    ds, run, lines = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run", []
    say = _on_line(AFTER_CHECKPOINT, lambda: _swap_in(builds["fewer"], ds), lines)
    with pytest.raises(InputError) as info:
        fit(ds, run, _cfg("max_steps=8", "eval_every=2"), say=say)
    message = str(info.value)
    assert message.startswith(f"{ds} was rebuilt while this run was training (")
    assert "train take(s) take02 gone" in message and "its normalization differs" in message
    assert "validate" not in message  # not the damaged-shard advice
    # the new build changes the normalisation: --resume would refuse it, so the line does not offer it
    assert message.endswith("start a new run (--resume refuses the new build: its normalization differs)")
    assert load_checkpoint(run / "last.pt")["step"] == 4  # the checkpoints are kept


def test_a_rebuild_of_the_val_take_stops_the_run_and_resume_restarts_best_val(builds, tmp_path, capsys):
    """Only take03's values change: fit used to go on validating on the new build (val_mse 1.24 ->
    0.54, best.pt chosen across two validation sets). It stops; --resume continues on the new build
    with a warning, best_val starting again."""
    ds, run, lines = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run", []
    say = _on_line(AFTER_CHECKPOINT, lambda: _swap_in(builds["val_edited"], ds), lines)
    with pytest.raises(InputError, match="was rebuilt while this run was training") as info:
        fit(ds, run, _cfg("max_steps=8", "eval_every=2"), say=say)
    message = str(info.value)
    assert "val take(s) take03 changed" in message
    assert message.endswith("--resume continues on the new build, or start a new run")
    state = load_checkpoint(run / "last.pt")
    assert state["step"] == 4 and state["best_val"] is not None
    assert state["dataset"]["takes"]["val"] == ["take03"]
    before = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in before if "val_mse" in r] == [2, 4]  # no validation on the new build

    capsys.readouterr()
    fit(ds, run, _cfg("max_steps=6", "eval_every=2"), resume=True, say=lines.append)
    said = capsys.readouterr().err.splitlines()  # a library call's warnings are the toolkit's
    warning = [x for x in said if x.startswith("s2a: warning: the takes that validate this run changed")]
    assert len(warning) == 1 and "take03 changed" in warning[0] and "best_val restarts" in warning[0]
    vals = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    last = [r for r in vals if "val_mse" in r][-1]
    assert last["step"] == 6 and last["best_val_mse"] == last["val_mse"]  # not the old set's best
    assert load_checkpoint(run / "best.pt")["step"] == 6
    # the new checkpoint records the new build: resuming again warns no more
    fit(ds, run, _cfg("max_steps=8", "eval_every=2"), resume=True, say=lines.append)
    assert "warning:" not in capsys.readouterr().err


def test_a_shard_that_differs_from_an_unchanged_manifest_keeps_its_message(builds, tmp_path):
    ds, run = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run"

    def truncate() -> None:
        shard = ds / "train-000000.tar"
        shard.write_bytes(shard.read_bytes()[:10240])

    say = _on_line(AFTER_CHECKPOINT, truncate, [])
    with pytest.raises(InputError, match="shard size differs from the manifest: s2a-dataset validate"):
        fit(ds, run, _cfg("max_steps=8", "eval_every=2"), say=say)


def test_a_manifest_that_goes_away_mid_run_is_one_line(builds, tmp_path):
    ds, run = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run"
    say = _on_line(AFTER_CHECKPOINT, lambda: (ds / "manifest.json").unlink(), [])
    with pytest.raises(InputError, match="manifest.json went away while this run was training"):
        fit(ds, run, _cfg("max_steps=8", "eval_every=2"), say=say)
    assert load_checkpoint(run / "last.pt")["step"] == 4


def test_an_unchanged_rewrite_of_the_dataset_goes_on(builds, tmp_path):
    """The same build written again (manifest.json renamed over with the same bytes) is no rebuild."""
    ds, run = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run"
    say = _on_line(AFTER_CHECKPOINT, lambda: _swap_in(builds["a"], ds), [])
    assert fit(ds, run, _cfg("max_steps=8", "eval_every=2"), say=say)["steps"] == 8


# 2. the run records its takes; eval names leaked takes


def test_the_checkpoint_records_the_build_and_the_runs_takes(builds):
    info = load_checkpoint(builds["run"] / "last.pt")["dataset"]
    assert info["takes"]["train"] == ["take00", "take01", "take02"] and info["takes"]["val"] == ["take03"]
    assert set(info["takes"]["sha256"]) == {"take00", "take01", "take02", "take03"}
    import hashlib

    assert info["manifest_sha256"] == hashlib.sha256((builds["a"] / "manifest.json").read_bytes()).hexdigest()


def test_eval_on_a_dataset_whose_test_split_holds_a_training_take_warns(builds, capsys):
    lines: list[str] = []
    r = evaluate(builds["run"], builds["leak"], rtf_seconds=0.2, say=lines.append)
    assert r["leaked_takes"] == ["take00"]
    said = capsys.readouterr().err.splitlines()
    assert any(x.startswith("s2a: warning: 1 evaluated take(s) trained or validated this run") for x in said)
    clean = evaluate(builds["run"], builds["a"], rtf_seconds=0.2, say=lines.append)
    assert clean["leaked_takes"] == []
    # its own val split is no leak; the command line's JSON carries the field, stderr the warning
    assert evaluate(builds["run"], builds["a"], "val", rtf_seconds=0.2, **QUIET)["leaked_takes"] == []
    proc = run_here("train", "eval", builds["run"], "--data", builds["leak"], "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["leaked_takes"] == ["take00"]
    assert "warning: 1 evaluated take(s) trained or validated this run" in proc.stderr


def test_eval_of_a_checkpoint_without_recorded_takes_says_nothing(builds, tmp_path):
    state = load_checkpoint(builds["run"] / "last.pt")
    for key in ("takes", "manifest_sha256"):
        del state["dataset"][key]
    old = tmp_path / "old.pt"
    save_checkpoint({k: v for k, v in state.items() if k not in ("format", "version")}, old)
    lines: list[str] = []
    r = evaluate(old, builds["leak"], rtf_seconds=0.2, say=lines.append)
    assert r["leaked_takes"] is None and not [x for x in lines if "warning" in x]


# 3. eval and predict on a run still training


def test_eval_and_predict_note_a_run_still_training(builds, tmp_path):
    run = builds["run"]
    wav = tmp_path / "a.wav"
    sf.write(wav, speech_like(1.0, np.random.default_rng(0))[0], SR)
    lines: list[str] = []
    evaluate(run, builds["a"], rtf_seconds=0.2, say=lines.append)
    assert not [x for x in lines if "still training" in x]
    step = torch.load(run / "best.pt", weights_only=True)["step"]
    with run_lock(run):  # what a fit in progress holds
        evaluate(run, builds["a"], rtf_seconds=0.2, say=lines.append)
        predict(run, [wav], tmp_path / "out", say=lines.append)
    notes = [x for x in lines if "still training" in x]
    assert notes == [f"note: {run} is still training (pid {os.getpid()}): using best.pt of step {step}"] * 2


# 4. the resume refusal says what changed


def test_resume_on_the_rebuilt_dataset_says_what_changed(builds, tmp_path):
    ds, run = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run"
    fit(ds, run, _cfg("max_steps=4", "eval_every=2"), stop_after_steps=2, **QUIET)
    _swap_in(builds["fewer"], ds)
    with pytest.raises(InputError) as info:
        fit(ds, run, _cfg("max_steps=4"), resume=True, **QUIET)
    message = str(info.value)
    assert (
        f"the dataset at {ds} was rebuilt since this run trained on it: its normalization differs" in message
    )
    assert message.count(str(ds)) == 1


# 5. under DDP the ranks stop together


DDP_FIT = """
import datetime, json, os, sys
rank, rendezvous, ds, run = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
cfg = json.loads(sys.argv[5])
os.environ.update(WORLD_SIZE="2", RANK=str(rank), LOCAL_RANK=str(rank))  # as torchrun sets them
import torch.distributed as dist
dist.init_process_group(
    "gloo", init_method="file://" + rendezvous, rank=rank, world_size=2, timeout=datetime.timedelta(0, 30)
)
from train.fit import fit
from train.run_dataset import DatasetWatch

if rank == 1:  # this rank checks manifest.json just before each rewrite lands: it never sees one
    DatasetWatch.changed = lambda self: None


def rewrite():  # other bytes, the same build: a new sha256 for the watch, the shards untouched
    path = os.path.join(ds, "manifest.json")
    with open(path) as f:
        data = json.load(f)
    with open(path + ".new", "w") as f:
        json.dump(data, f, indent=1)
    os.replace(path + ".new", path)


def say(line):  # rank 0's lines only (fit silences the other ranks)
    if line.startswith("step 5: mse"):
        rewrite()


try:
    fit(ds, run, cfg, say=say)
    out = {"error": None}
except Exception as exc:
    out = {"error": type(exc).__name__ + ": " + str(exc)}
print(json.dumps(out), flush=True)
dist.barrier()  # both ranks done before the group goes: one leaving first can abort the other's exit
dist.destroy_process_group()
"""


def test_ddp_ranks_stop_together_when_only_one_sees_the_rebuild(builds, tmp_path):
    """Each rank checks manifest.json on its own: a rebuild landing between two ranks' checks is seen by
    one of them. That rank used to stop alone (at its epoch start or a validation) while the other waited
    at its next collective; now both stop with the line, at the validation after the rebuild."""
    ds, run = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run"
    cfg = _cfg("max_steps=12", "eval_every=2")
    args = [str(tmp_path / "rendezvous"), str(ds), str(run), json.dumps(cfg)]
    lines = run_gloo_ranks(DDP_FIT, args, timeout=240)
    errors = [json.loads(found[-1])["error"] for found in lines]
    seen = f"DatasetChanged: {ds} was rebuilt while this run was training ("
    assert errors[0].startswith(seen) and "(seen by another rank" not in errors[0], errors
    assert errors[1] == errors[0] + " (seen by another rank: rank 0)", errors
    assert "\n" not in errors[0]
    assert load_checkpoint(run / "last.pt")["step"] == 4  # the last checkpoint before the rebuild


DDP_START = """
import datetime, json, os, sys, time
rank, rendezvous, ds, run, flag = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[6]
cfg = json.loads(sys.argv[5])
os.environ.update(WORLD_SIZE="2", RANK=str(rank), LOCAL_RANK=str(rank))  # as torchrun sets them
import torch.distributed as dist
if rendezvous.isdigit():  # as under torchrun: fit makes the process group itself
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=rendezvous)
else:
    dist.init_process_group(
        "gloo", init_method="file://" + rendezvous, rank=rank, world_size=2, timeout=datetime.timedelta(0, 30)
    )
from train.fit import fit
from train.run_dataset import DatasetWatch

first_read = DatasetWatch.read.__func__


def read(cls, *args):  # rank 0 reads manifest.json; a rebuild lands; then rank 1 reads it
    watch = first_read(cls, *args)
    if rank == 0:
        open(flag, "w").close()
    return watch


DatasetWatch.read = classmethod(read)
if rank == 1:
    while not os.path.exists(flag):
        time.sleep(0.05)
    path = os.path.join(ds, "manifest.json")
    with open(path) as f:
        data = json.load(f)
    with open(path + ".new", "w") as f:
        json.dump(data, f, indent=1)  # other bytes: another build for the run's fingerprint
    os.replace(path + ".new", path)
try:
    fit(ds, run, cfg, say=lambda _line: None)
    out = {"error": None}
except Exception as exc:
    out = {"error": type(exc).__name__ + ": " + str(exc)}
print(json.dumps(out), flush=True)
if dist.is_initialized():
    dist.barrier()  # both ranks done before the group goes
    dist.destroy_process_group()
"""


@pytest.mark.parametrize("ensemble", [False, True])
def test_ddp_ranks_that_start_on_two_builds_stop_together(builds, tmp_path, ensemble):
    """Each rank reads manifest.json at start-up on its own: a rebuild landing between two ranks' reads
    started them on different builds (each then checked against its own). Both now stop before training,
    with one line naming each rank's build; also a cross-validation ensemble under torchrun, where fit
    makes the process group."""
    ds, run = _copy(builds["a"], tmp_path / "ds"), tmp_path / "run"
    if ensemble:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            rendezvous = str(s.getsockname()[1])
    args = [
        rendezvous if ensemble else str(tmp_path / "rendezvous"),
        str(ds),
        str(run),
        json.dumps(_cfg("max_steps=4", *(["cv_folds=2"] if ensemble else []))),
        str(tmp_path / "read"),
    ]
    lines = run_gloo_ranks(DDP_START, args, timeout=240)
    errors = [json.loads(found[-1])["error"] for found in lines]
    assert errors[0] == errors[1], errors
    assert errors[0].startswith(f"DatasetChanged: {ds} was rebuilt as this run started: its ranks read"), (
        errors
    )
    assert "rank 0: " in errors[0] and "rank 1: " in errors[0] and "start the run again" in errors[0]
    assert not (run / "last.pt").exists()


# 6. a checkpoint of an earlier version resumes in its own data order


def test_a_checkpoint_without_data_order_resumes_with_shards_in_storage_order(builds, tmp_path, monkeypatch):
    """Shard order became shuffled per epoch (shuffle_buffer > 1): a last.pt written before (no
    data_order) resumed at its (epoch, batch) but saw other batches. It resumes in storage order, and
    the checkpoints it writes keep that order; a checkpoint of this version keeps shuffling."""
    fit_module = sys.modules["train.fit"]  # the module (train.fit is also the function)
    built = []

    def recording(*args, **kwargs):
        data = train_dataset(*args, **kwargs)
        built.append(data.shuffle_shards)
        return data

    train_dataset = fit_module.train_dataset
    monkeypatch.setattr(fit_module, "train_dataset", recording)
    run = tmp_path / "run"
    fit(builds["a"], run, _cfg("max_steps=6", "eval_every=2"), stop_after_steps=2, **QUIET)
    state = load_checkpoint(run / "last.pt")
    assert built == [True] and state["data_order"] == 2
    fit(builds["a"], run, _cfg("max_steps=6", "eval_every=2"), resume=True, stop_after_steps=2, **QUIET)
    assert built == [True, True]

    state = load_checkpoint(run / "last.pt")
    del state["data_order"]  # as the previous version wrote it
    save_checkpoint({k: v for k, v in state.items() if k not in ("format", "version")}, run / "last.pt")
    fit(builds["a"], run, _cfg("max_steps=6", "eval_every=2"), resume=True, stop_after_steps=1, **QUIET)
    assert built == [True, True, False]
    assert load_checkpoint(run / "last.pt")["data_order"] == 1
    fit(builds["a"], run, _cfg("max_steps=6", "eval_every=2"), resume=True, **QUIET)
    assert built == [True, True, False, False]

    state = load_checkpoint(run / "last.pt")
    state["data_order"] = 3
    save_checkpoint({k: v for k, v in state.items() if k not in ("format", "version")}, run / "last.pt")
    with pytest.raises(InputError, match="checkpoint reads its data in order 3; this version knows 1 and 2"):
        fit(builds["a"], run, _cfg("max_steps=8"), resume=True, **QUIET)
