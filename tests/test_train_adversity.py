"""``s2a-train`` under adversity: a run trained in time-limited sessions, ``compare`` re-run into its own
folder with other settings, a restart after a first session that died before its first checkpoint, a
full disk under fit / ppg / export, a refused resume, ``eval --split val`` of a run with its own
validation takes, the RTF of a model whose max_frames is below 12 s, and the smaller repairs (arch keys a
system's name fixes, ridge resumed, summary keys, config hints and JSON configs, the run-folder lock)."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch
from conftest import ROOT, run_cli, run_here
from dataset_helpers import build_five_take_dataset, speech_like
from tensorboard.compat.proto.event_pb2 import Event
from tensorboard.summary.writer.record_writer import RecordWriter
from test_train_pipeline import TINY
from torch.utils.tensorboard.summary import scalar

from capture.errors import InputError
from capture.textgrid import TextGrid, interval_tier, write_textgrid
from dataset import read_manifest
from dataset.bottleneck import BottleneckConfig, BottleneckPPG, save_bottleneck
from train.checkpoint import load_checkpoint, run_lock, write_atomically, write_error
from train.config import DEFAULTS, resolve_config
from train.data import resolve_inputs
from train.evaluate import evaluate, run_split_keys
from train.export import ExportFailed, export_onnx
from train.fit import fit
from train.systems import build_model

QUIET = {"say": lambda _m: None}


def _cfg(*sets):
    return resolve_config(sets=TINY + list(sets))


def _sets(*extra):
    return [a for s in [*TINY, *extra] for a in ("--set", s)]


def _cli(*args, timeout=300):
    if timeout == 300:
        return run_cli("train", *map(str, args))
    return subprocess.run(
        [sys.executable, "-m", "train", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
    )


def _one_line_error(proc, needle: str) -> None:
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and needle in proc.stderr, proc.stderr
    assert sum(": error: " in line for line in proc.stderr.splitlines()) == 1, proc.stderr


def _metrics(run):
    """metrics.jsonl without the timings, which differ from session to session."""
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in ("frames_per_s", "time_s")} for r in rows]


def _curves(run):
    """{tag: [(step, value), ...]} of a run's TensorBoard events, as TensorBoard itself reads them."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run / "tensorboard"))
    events.Reload()
    tags = [t for t in events.Tags()["scalars"] if t not in ("frames_per_s", "time_s")]  # timings differ
    return {t: [(e.step, e.value) for e in events.Scalars(t)] for t in tags}


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    """Five 2 s takes of two speakers: take03 validates, take04 tests, take00-02 train."""
    return build_five_take_dataset(tmp_path_factory.mktemp("adversity"))


@pytest.fixture(scope="module")
def s2a(ds, tmp_path_factory):
    """A Transformer-S2A run of 4 steps whose max_frames (200) holds less than 12 s at 60 fps."""
    run = tmp_path_factory.mktemp("s2a") / "run"
    summary = fit(ds, run, _cfg("arch.max_frames=200", "max_steps=4", "eval_every=2"), **QUIET)
    return run, summary


# 1. sessions cut by --max-minutes reproduce the uninterrupted run


def test_time_limited_sessions_reproduce_an_uninterrupted_run(ds, tmp_path):
    cfg = _cfg("arch.dropout=0.2", "eval_every=4", "patience=1", "max_steps=12")
    full = fit(ds, tmp_path / "full", cfg, **QUIET)
    sliced, run = {**cfg, "max_minutes": 1e-9}, tmp_path / "sliced"  # every session ends after one step
    summary, sessions = fit(ds, run, sliced, **QUIET), 1
    while summary["stopped"] == "max_minutes":
        summary, sessions = fit(ds, run, sliced, resume=True, **QUIET), sessions + 1
    assert sessions == full["steps"] > 4
    assert (summary["steps"], summary["stopped"], summary["best_val"]) == (
        full["steps"],
        full["stopped"],
        full["best_val"],
    )
    for name in ("last.pt", "best.pt"):
        a, b = load_checkpoint(tmp_path / "full" / name), load_checkpoint(run / name)
        assert (a["step"], a["best_val"], a["bad_evals"], a["positions"]) == (
            b["step"],
            b["best_val"],
            b["bad_evals"],
            b["positions"],
        ), name
        for k in a["state_dict"]:
            assert torch.equal(a["state_dict"][k], b["state_dict"][k]), (name, k)
        for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values()):
            assert torch.equal(sa["exp_avg"], sb["exp_avg"]), name
    assert _metrics(tmp_path / "full") == _metrics(run)  # no validation lines at odd steps


def test_a_resumed_run_drops_the_tensorboard_events_logged_after_its_checkpoint(ds, tmp_path):
    """A session checkpointed at step 4, logged steps 5-12 and died: TensorBoard shows the resumed
    session's steps 5-12 once, not the dead session's beside them."""

    cfg = _cfg("eval_every=4", "max_steps=12")
    full = tmp_path / "full"
    fit(ds, full, cfg, **QUIET)
    cut = tmp_path / "cut"
    fit(ds, cut, cfg, stop_after_steps=4, **QUIET)
    (events,) = (cut / "tensorboard").iterdir()
    with open(events, "ab") as f:  # what the dead session logged after its checkpoint
        records = RecordWriter(f)
        for step in range(5, 13):
            records.write(
                Event(wall_time=time.time(), step=step, summary=scalar("mse", 99.0)).SerializeToString()
            )
    time.sleep(1.05)  # event files sort by their creation second: the resumed session's comes after
    fit(ds, cut, cfg, resume=True, **QUIET)
    assert _curves(cut) == _curves(full) and [s for s, _v in _curves(cut)["mse"]] == [5, 10]


# 2. compare re-run into its own folder


def test_compare_rerun_refuses_changed_settings_and_keeps_each_runs_limits(ds, tmp_path):
    out = tmp_path / "cmp"
    base = ["compare", "--data", ds, "-o", out, "--models", "blstm", *_sets("eval_every=2"), "--json"]
    proc = run_here("train", *base, "--set", "arch.hidden=8", "--max-steps", 4)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["steps"] == 4
    before = {p: (out / p).read_bytes() for p in ("compare.json", "blstm/config.json", "blstm/last.pt")}
    proc = run_here("train", *base, "--set", "arch.hidden=16", "--set", "lr=0.01", "--max-steps", 4)
    _one_line_error(proc, "keeps the run's config, but arch.hidden, lr differ")
    assert "blstm/config.json" in proc.stderr and "arch.hidden = 8" in proc.stderr
    assert {p: (out / p).read_bytes() for p in before} == before
    # the same settings again, without --max-steps: the run's own 4 steps hold (not the default 4000)
    proc = run_here("train", *base, "--set", "arch.hidden=8", "--max-minutes", 0.2)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["steps"] == 4 and "already finished at step 4" in proc.stderr


# 3. a restart after a first session that died before its first checkpoint


def test_a_fresh_run_starts_without_what_an_aborted_first_session_left(ds, tmp_path):
    run = tmp_path / "r"
    (run / "tensorboard").mkdir(parents=True)
    # the dead session's lines, the last one torn; a best.pt written just before a last.pt that never came
    (run / "metrics.jsonl").write_text('{"step": 5, "mse": 1.0}\n{"step": 10, "mse": 0.9}\n{"step": 1')
    (run / "best.pt").write_bytes(b"stale")
    (run / "tensorboard" / "events.out.tfevents.1.stale").write_bytes(b"stale")
    cfg = _cfg("eval_every=4", "max_steps=8")
    assert fit(ds, run, cfg, stop_after_steps=6, **QUIET)["stopped"] == "stopped"
    assert fit(ds, run, cfg, resume=True, **QUIET)["steps"] == 8  # no torn line mid-file
    rows = [(r["step"], "val_mse" in r) for r in _metrics(run)]
    assert rows == [(4, True), (5, False), (8, True)]
    assert load_checkpoint(run / "best.pt")["step"] in (4, 8)
    assert not (run / "tensorboard" / "events.out.tfevents.1.stale").exists()


# 4. a full disk


def test_write_failures_name_the_file_and_leave_the_old_one(tmp_path):
    target = tmp_path / "ppg.pt"
    target.write_bytes(b"old")
    full = OSError(28, "No space left on device")

    def fails(tmp):
        tmp.write_bytes(b"half")
        raise full

    with pytest.raises(InputError, match=r"ppg\.pt: cannot write the checkpoint: no space left on device"):
        write_atomically(target, fails, "the checkpoint")
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["ppg.pt"]
    write_atomically(target, lambda tmp: tmp.write_bytes(b"new"))
    assert target.read_bytes() == b"new" and sorted(p.name for p in tmp_path.iterdir()) == ["ppg.pt"]
    # torch's writer on a full disk: a RuntimeError; elsewhere its first line is the reason
    err = write_error(
        RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos\nmore"), target
    )
    reason = "[enforce fail at inline_container.cc:672] . unexpected pos"
    assert str(err) == f"{target}: cannot write ppg.pt: {reason}"
    # a file system with no free space that is not full: /proc (0 bytes free) names its own cause
    err = write_error(FileNotFoundError(2, "No such file or directory"), Path("/proc/m.onnx"))
    assert str(err) == "/proc/m.onnx: cannot write m.onnx: No such file or directory"


# The three commands run one after the other in one interpreter (PyTorch imported once, not three times),
# each with the process's stderr (file descriptor 2) in its own file; whatever the interpreter writes
# at exit lands in exit.err.
COMMANDS = r"""
import os, sys, traceback
from train.cli import main
small, out, ds, aligned, run = sys.argv[1:6]
for name, args in (
    ("fit", ["fit", "--data", ds, "-o", small + "/run", "--resume", "--max-steps", "8"]),
    ("ppg", ["ppg", "--data", aligned, "-o", small + "/ppg.pt", "--steps", "1"]),
    ("export", ["export", run, "-o", small + "/m.onnx"]),
    ("exit", None),
):
    sys.stderr.flush()
    with open(f"{out}/{name}.err", "w") as err:
        os.dup2(err.fileno(), 2)
    if args is None:
        break
    try:
        code = main(args)
    except SystemExit as exc:
        code = exc.code
    except BaseException:
        traceback.print_exc()
        code = "raised"
    sys.stderr.flush()
    print(f"{name}={code}", flush=True)
"""

FULL_DISK = r"""
set -u
mount -t tmpfs -o size=${SIZE_KB}k tmpfs "$SMALL" || exit 99
cp -r "$RUN" "$SMALL/run"
cp "$OLD_PPG" "$SMALL/ppg.pt"; printf old > "$SMALL/m.onnx"
digest() { sha256sum "$1" | cut -c1-16; }
before=$(digest "$SMALL/run/last.pt"); ppg_before=$(digest "$SMALL/ppg.pt")
avail=$(df -k --output=avail "$SMALL" | tail -1)
head -c $(( (avail - 48) * 1024 )) /dev/zero > "$SMALL/filler"
"$PY" -c "$COMMANDS" "$SMALL" "$OUT" "$DS" "$ALIGNED" "$RUN"; echo "driver=$?"
[ "$(digest "$SMALL/run/last.pt")" = "$before" ] && echo "last_kept=yes"
[ "$(digest "$SMALL/ppg.pt")" = "$ppg_before" ] && echo "ppg_kept=yes"
[ "$(head -c 4 "$SMALL/m.onnx")" = old ] && echo "onnx_kept=yes"
echo "files=$(ls -A "$SMALL" "$SMALL/run" | tr '\n' ' ')"
"""


def test_a_full_disk_is_one_line_naming_the_file_and_keeps_the_old_files(s2a, ds, tmp_path):
    if subprocess.run(["unshare", "-r", "-m", "true"], capture_output=True).returncode != 0:
        pytest.skip("needs unshare -r -m (user and mount namespaces) for a small tmpfs")
    run, _ = s2a
    aligned = tmp_path / "aligned"
    aligned.mkdir()
    audio, _ = speech_like(2.0, np.random.default_rng(0))
    sf.write(aligned / "utt.wav", audio, 16000)
    tier = interval_tier("phones", [(0.0, 0.5, ""), (0.5, 1.5, "aa"), (1.5, 2.0, "s")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), aligned / "utt.TextGrid")
    (tmp_path / "small").mkdir()
    old_ppg = tmp_path / "old-ppg.pt"  # an earlier PPG checkpoint: -o may replace only such a file
    save_bottleneck(BottleneckPPG(BottleneckConfig(hidden=8, layers=1)), old_ppg)
    size_kb = sum(p.stat().st_size for p in run.iterdir() if p.is_file()) // 1024 + 1024
    env = dict(
        os.environ,
        SIZE_KB=str(size_kb),
        SMALL=str(tmp_path / "small"),
        RUN=str(run),
        DS=str(ds),
        ALIGNED=str(aligned),
        OLD_PPG=str(old_ppg),
        OUT=str(tmp_path),
        PY=sys.executable,
        COMMANDS=COMMANDS,
    )
    proc = subprocess.run(
        ["unshare", "-r", "-m", "bash", "-c", FULL_DISK], capture_output=True, text=True, env=env, cwd=ROOT
    )
    if proc.returncode == 99:
        pytest.skip("cannot mount a tmpfs here")
    said = dict(w.split("=", 1) for w in proc.stdout.split() if "=" in w and not w.startswith("files"))
    assert (said["fit"], said["ppg"], said["export"], said["driver"]) == ("1", "1", "1", "0"), proc.stdout
    assert [said.get(k) for k in ("last_kept", "ppg_kept", "onnx_kept")] == ["yes"] * 3, proc.stdout
    assert ".partial" not in proc.stdout, proc.stdout  # no half-written file left behind
    for name, needle in (
        ("fit", ".pt: cannot write "),
        ("ppg", "ppg.pt: cannot write the checkpoint: "),
        ("export", "m.onnx: cannot write the ONNX file: "),
    ):
        err = (tmp_path / f"{name}.err").read_text()
        assert "Traceback" not in err and needle in err and "no space left on device" in err, (name, err)
        assert sum(": error: " in line for line in err.splitlines()) == 1, err
    at_exit = (tmp_path / "exit.err").read_text()
    assert "Traceback" not in at_exit and "Exception" not in at_exit, at_exit


def test_export_replaces_the_onnx_file_only_once_parity_holds(s2a, tmp_path):
    run, _ = s2a
    out = tmp_path / "m.onnx"
    out.write_bytes(b"old")
    with pytest.raises(ExportFailed, match="nothing written"):
        export_onnx(run, out, tolerance=-1.0, **QUIET)
    assert out.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.onnx"]
    summary = export_onnx(run, out, **QUIET)  # max_frames 200: checked within it, and said
    assert summary["max_frames"] == 200 and max(summary["checked_frames"]) == 200
    assert out.read_bytes()[:3] != b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.onnx"]


# 5. a refused resume leaves config.json alone


def test_a_refused_resume_leaves_the_runs_config_json(s2a, ds, tmp_path):
    run = tmp_path / "ddp"
    shutil.copytree(s2a[0], run)
    state = load_checkpoint(run / "last.pt")  # as if two DDP processes had trained it
    state["positions"] = [state["positions"][0]] * 2
    torch.save(state, run / "last.pt")
    record = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**record, "world_size": 2}, indent=2))
    before = (run / "config.json").read_bytes()
    with pytest.raises(InputError, match=r"trained with 2 process\(es\)"):
        fit(ds, run, _cfg(), resume=True, given={"max_steps": 8}, **QUIET)
    assert (run / "config.json").read_bytes() == before


# 7. eval --split val of a run with its own validation takes


def test_eval_val_of_a_run_with_val_takes_scores_its_own_validation_takes(ds, tmp_path):
    run = tmp_path / "ridge"
    fit(ds, run, _cfg("model='ridge'", 'val_takes=["take01"]', "ridge_alpha=0.01"), **QUIET)
    said = []
    r = evaluate(run, ds, "val", say=said.append)
    assert r["split"] == "val" and r["split_source"] == "run" and r["split_takes"] == ["take01"]
    assert "not the dataset's val split" in r["split_note"] and any("take01" in m for m in said)
    samples = read_manifest(ds)["samples"]
    assert r["utterances"] == sum(s["take"] == "take01" for s in samples)
    # the dataset's val take (take03) trained this run: its "train" includes it, its "val" never does
    assert "take03" in evaluate(run, ds, "train", **QUIET)["split_takes"]
    plain = tmp_path / "plain"
    fit(ds, plain, _cfg("model='ridge'", "ridge_alpha=0.01"), **QUIET)
    assert "split_takes" not in evaluate(plain, ds, "val", **QUIET)  # the dataset's own split
    with pytest.raises(InputError, match="cross-validation ensemble trained on every train and val take"):
        run_split_keys({"ensemble": {}, "config": {}}, read_manifest(ds), "val", ds / "manifest.json")


# 8. RTF of a model whose max_frames is below 12 s of frames


def test_eval_times_the_rtf_within_max_frames(s2a, ds):
    proc = _cli("eval", s2a[0], "--data", ds, "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    r = json.loads(proc.stdout)
    assert r["rtf"] > 0 and r["rtf_frames"] == 200 and r["rtf_seconds"] == pytest.approx(200 / 60)
    assert "max_frames" in r["rtf_note"] and "max_frames" in proc.stderr


# minor repairs


def test_arch_keys_a_systems_name_fixes_are_refused_not_ignored(ds):
    manifest = read_manifest(ds)
    spec = resolve_inputs(manifest, _cfg())
    for name, item, needle in (
        ("nvp3", "arch.window=5", "nvp3's window is fixed at 3 frames: train nvp9"),
        ("nvp9", "arch.nvp9.window=3", "nvp9's window is fixed at 9 frames"),
        ("s2a", "arch.moe=false", "train s2a-nomoe"),
        ("s2a-nomoe", "arch.moe=true", "s2a-nomoe never has MoE experts"),
    ):
        with pytest.raises(InputError, match="config:arch: arch.*" + needle):
            build_model(name, spec, _cfg(item))
    build_model("nvp3", spec, _cfg("arch.window=3"))  # the system's own value is harmless
    build_model("s2a-nomoe", spec, _cfg("arch.moe=false"))


def test_ridge_resumed_is_not_solved_again_and_summaries_share_their_keys(s2a, ds, tmp_path):
    run = tmp_path / "ridge"
    first = fit(ds, run, _cfg("model='ridge'", "ridge_alpha=0.01"), **QUIET)
    keys = set(s2a[1]) - {"train_frames_per_s"}
    assert keys <= set(first), keys - set(first)
    assert first["world_size"] == 1 and first["parameters"] > 0 and len(first["params_checksums"]) == 1
    before = (run / "last.pt").read_bytes(), (run / "metrics.jsonl").read_text()
    said = []
    again = fit(ds, run, _cfg("model='ridge'", "ridge_alpha=0.01"), resume=True, say=said.append)
    assert any("nothing to do" in m for m in said)
    assert ((run / "last.pt").read_bytes(), (run / "metrics.jsonl").read_text()) == before
    assert again["params_checksums"] == first["params_checksums"] and set(again) >= keys


def test_config_hints_toml_arch_errors_and_a_runs_config_json(s2a, tmp_path):
    with pytest.raises(InputError, match=r"unknown config key 'patiense' \(did you mean 'patience'\?\)"):
        resolve_config(sets=["patiense=3"])
    with pytest.raises(InputError, match=r"'d_model' \(did you mean 'arch.d_model'\?"):
        resolve_config(sets=["d_model=64"])
    toml = tmp_path / "small.toml"
    toml.write_text("lr = 1e-3\n[arch]\nd_modle = 64\n")
    needle = r"small\.toml: \[arch\]: unknown arch keys \['d_modle'\] \(did you mean 'd_model'"
    with pytest.raises(InputError, match=needle):
        resolve_config(toml)
    # a run's config.json is a config: its data, world_size and inputs records are not keys
    saved = json.loads((s2a[0] / "config.json").read_text())
    assert resolve_config(s2a[0] / "config.json") == {k: saved[k] for k in DEFAULTS}
    # and it records every size of the network, the defaults the run's arch left out filled in
    assert {"d_model", "experts", "top_k"} <= set(saved["model_config"])
    assert saved["model_config"] == torch.load(s2a[0] / "last.pt", weights_only=True)["model_config"]


def test_a_second_fit_into_a_run_folder_in_use_is_refused(s2a, ds, tmp_path):
    run = tmp_path / "busy"
    shutil.copytree(s2a[0], run)
    before = (run / "last.pt").read_bytes()
    with run_lock(run):  # a fit in progress (another process holds it)
        proc = _cli("fit", "--data", ds, "-o", run, "--resume", "--max-steps", 6, timeout=120)
    _one_line_error(proc, f"another s2a-train fit (pid {os.getpid()}) is writing this run folder")
    assert (run / "last.pt").read_bytes() == before
    fd = os.open(run / ".lock", os.O_RDWR)  # released when the holder ends
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        os.close(fd)


def test_ctrl_c_while_pytorch_loads_stops_without_a_traceback(tmp_path):
    """The first 2-3 s of every s2a-train command import PyTorch, numpy and scipy: Ctrl-C there used to
    print a KeyboardInterrupt traceback, or a RecursionError from a half-imported numpy. The delays count
    from when the interpreter has started (its own start-up, before any of the package's code, is
    Python's: on a busy machine it alone can take 0.2 s) and the command is run as its console script."""
    command = ["s2a-train", "fit", "--data", str(tmp_path / "none"), "-o", str(tmp_path / "run")]
    as_console_script = (
        f"import sys; sys.argv[:] = {command!r}; print('started', flush=True); "
        "from train.cli import main; sys.exit(main())"  # as pip's s2a-train script (runpy's alter_sys
        # renamed argv[0] to train/__main__.py: the command's own PyTorch import went unguarded)
    )
    for delay in (0.2, 0.5, 0.9):
        proc = subprocess.Popen(
            [sys.executable, "-c", as_console_script],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        assert proc.stdout.readline() == "started\n"
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
        assert proc.returncode in (130, -signal.SIGINT) and "Traceback" not in err, (delay, err)
    # a program that imports the package, directly or under `python -m`, keeps Python's own Ctrl-C
    check = (
        "import signal, train.cli; "
        "print(train.cli._guard, signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
    )
    (tmp_path / "usrpkg").mkdir()
    (tmp_path / "usrpkg" / "__init__.py").write_text(check + "\n")
    (tmp_path / "usrpkg" / "__main__.py").write_text("")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"}
    for args in (["-c", check], ["-m", "usrpkg"]):
        proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=ROOT, env=env)
        assert proc.stdout.split() == ["False", "True"], proc.stdout + proc.stderr


# From the crash probe: a kill while --resume trims metrics.jsonl, TensorBoard on a full disk, SIGTERM.
def test_trimming_the_metrics_on_resume_never_leaves_them_half_written(tmp_path, monkeypatch):
    fit_module = sys.modules["train.fit"]  # the package's `fit` is the function
    metrics = tmp_path / "metrics.jsonl"
    lines = "".join(json.dumps({"step": s, "mse": 1.0 / s}) + "\n" for s in (10, 20, 30, 40))
    metrics.write_text(lines)
    real_write_text = Path.write_text

    def disk_fills(self, text, *args, **kwargs):  # half the text lands, then the disk is full
        real_write_text(self, text[: len(text) // 2], *args, **kwargs)
        raise OSError(28, "No space left on device", str(self))

    monkeypatch.setattr(Path, "write_text", disk_fills)
    with pytest.raises(
        InputError, match="metrics.jsonl: cannot write metrics.jsonl: no space left on device"
    ):
        fit_module._trim_metrics(metrics, 20)
    monkeypatch.undo()
    assert metrics.read_text() == lines and [p.name for p in tmp_path.iterdir()] == ["metrics.jsonl"]
    fit_module._trim_metrics(metrics, 20)
    assert [json.loads(x)["step"] for x in metrics.read_text().splitlines()] == [10, 20]


def test_tensorboard_events_on_a_full_disk_are_one_line(ds, tmp_path, monkeypatch, capfd):
    def disk_full(self, data):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(RecordWriter, "write", disk_full)  # on TensorBoard's own writer thread
    with pytest.raises(InputError, match=r"tensorboard: cannot write TensorBoard events: no space left"):
        fit(ds, tmp_path / "run", _cfg("max_steps=40", "log_every=1", "eval_every=20"), **QUIET)
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Exception in thread" not in err, err
    assert (tmp_path / "run" / "last.pt").is_file() or not (tmp_path / "run" / "best.pt").exists()


def test_sigterm_stops_a_fit_as_ctrl_c_does(ds, tmp_path):
    run = tmp_path / "run"
    args = ["fit", "--data", ds, "--model", "s2a", "-o", run, "--max-steps", 100000]
    proc = subprocess.Popen(
        [sys.executable, "-m", "train", *map(str, args), *_sets("eval_every=5", "log_every=1")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    deadline = time.monotonic() + 120
    while not (run / "last.pt").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143 and "s2a-train: terminated (SIGTERM)" in err and "Traceback" not in err, err
    assert not list(run.glob(".*partial*"))
    # resumed in this process: fit --resume's command line runs as a subprocess in the test above
    resumed = run_here("train", "fit", "--data", ds, "-o", run, "--resume", "--max-steps", 3)
    assert resumed.returncode == 0, resumed.stderr


def test_ctrl_c_while_the_parser_is_built_is_one_line(capsys):
    """Ctrl-C after the command's imports but while its parser is built (reading the package's version
    from its metadata, a slow read on a busy machine) printed a KeyboardInterrupt traceback (CI, 0.2 s
    into s2a-train): the parser is built inside run's handling."""
    from capture.command import run

    def interrupted_parser():
        raise KeyboardInterrupt

    assert run("s2a-x", interrupted_parser, lambda _a: 0, []) == 130
    assert capsys.readouterr().err == "s2a-x: interrupted\n"


@pytest.mark.parametrize(
    "exc",
    [
        MemoryError(),
        RuntimeError("[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: can't allocate memory: 8 GB"),
    ],
)
def test_running_out_of_memory_is_one_line(exc, capsys):
    import argparse

    from capture.command import run

    def handler(_args):
        raise exc

    assert run("s2a-x", argparse.ArgumentParser, handler, []) == 1
    err = capsys.readouterr().err
    assert err.startswith("s2a-x: error: out of memory") and len(err.splitlines()) == 1, err
    with pytest.raises(RuntimeError, match="another"):  # any other RuntimeError stays a bug to report
        run("s2a-x", argparse.ArgumentParser, lambda _a: (_ for _ in ()).throw(RuntimeError("another")), [])
