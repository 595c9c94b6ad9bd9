"""``s2a-train`` on what a careful user still gets wrong: resuming a finished run without new limits,
predicting with a rig's own controls, weights outside 0..1, a model that outputs NaN, checkpoints that
are malformed in ways torch happily loads, typos in another system's arch table, several audio files
of which one is bad, and an export path that cannot be written."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import scipy.signal
import soundfile as sf
import torch
from conftest import run_cli, run_here
from dataset_helpers import make_aligned_take
from test_train_pipeline import TINY

from capture import read_livelink_csv, read_take, write_take
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule

SETS = [a for s in [*TINY, "eval_every=5"] for a in ("--set", s)]


def _cli(*args):
    return run_here("train", *map(str, args))


def _one_line_error(proc, needle: str) -> None:
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and needle in proc.stderr, proc.stderr
    assert sum(": error: " in line for line in proc.stderr.splitlines()) == 1, proc.stderr


def _dataset(root, channels=None):
    kw = {} if channels is None else {"channels": channels}
    for i in range(4):
        write_take(make_aligned_take(f"t{i}", 2.0, subject="a", seed=i, **kw), root / "takes")
    options = BuildOptions(
        channels="pronunciation32" if channels is None else "all",
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, ("t1",), ("t2",)),
    )
    build_dataset([root / "takes"], root / "ds", options, say=lambda _m: None)
    return root / "ds"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("repairs")
    ds = _dataset(root)
    rig_ds = _dataset(root / "rig", channels=("jaw_ctl", "lip_ctl", "funnel_ctl"))
    out = {"ds": ds, "rig_ds": rig_ds, "wav": next((root / "takes").rglob("audio.wav"))}
    for name, data in (("ridge", ds), ("rig", rig_ds)):
        proc = _cli("fit", "--data", data, "--model", "ridge", "-o", root / name)
        assert proc.returncode == 0, proc.stderr
        out[name] = root / name
    proc = _cli("fit", "--data", ds, "--model", "s2a", "-o", root / "s2a", "--max-steps", 6, *SETS)
    assert proc.returncode == 0, proc.stderr
    out["s2a"] = root / "s2a"
    return out


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_resuming_a_finished_run_without_new_limits_trains_nothing(runs):
    run = runs["s2a"]
    before = {p.name: _digest(p) for p in run.glob("*.pt")}
    proc = _cli("fit", "--data", runs["ds"], "-o", run, "--resume", "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["steps"] == 6 and summary["stopped"] == "max_steps"
    assert "run already finished at step 6" in proc.stderr
    assert {p.name: _digest(p) for p in run.glob("*.pt")} == before
    assert json.loads((run / "config.json").read_text())["max_steps"] == 6
    proc = _cli("fit", "--data", runs["ds"], "-o", run, "--resume", "--max-minutes", "0.001")
    assert proc.returncode == 0 and {p.name: _digest(p) for p in run.glob("*.pt")} == before


def test_predict_with_a_rigs_own_controls_writes_a_rig_csv(runs, tmp_path):
    out = tmp_path / "rig.csv"
    proc = _cli("predict", runs["rig"], runs["wav"], "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)
    assert r["format"] == "rig"
    lines = out.read_text().splitlines()
    assert lines[0] == "time,jaw_ctl,lip_ctl,funnel_ctl" and len(lines) == r["frames"] + 1
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert np.allclose(table[:, 0], np.arange(r["frames"]) / r["fps"], atol=1e-6)
    assert np.ptp(table[:, 1:], axis=0).max() > 0  # the controls move; not a column of zeros
    # the file is paired data for the importer: time column, rig controls
    proc = run_cli("capture", "import", "--matrix", out, "--audio", runs["wav"], "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr


def test_predict_clips_weights_and_notes_narrowband_audio(runs, tmp_path):
    """Weights outside 0..1 are clipped and counted; audio without its upper bands (8 kHz telephone
    speech resampled to 16 kHz) is predicted with a note."""
    audio, rate = sf.read(runs["wav"])
    narrow = tmp_path / "phone.wav"
    sf.write(narrow, scipy.signal.resample_poly(scipy.signal.resample_poly(audio, 1, 2), 2, 1), rate)
    proc = _cli("predict", runs["ridge"], runs["wav"], narrow, "-o", tmp_path / "out", "--json")
    assert proc.returncode == 0, proc.stderr
    wide, phone = map(json.loads, proc.stdout.splitlines())
    assert (wide["narrowband"], phone["narrowband"]) == (False, True)
    assert sum("no energy above 4.5 kHz" in line for line in proc.stderr.splitlines()) == 1
    for r in (wide, phone):
        assert r["format"] == "livelinkface" and r["clipped_values"] >= 0
        take = read_livelink_csv(r["csv"])
        assert take.values.min() >= 0.0 and take.values.max() <= 1.0
    clipped = [r["clipped_values"] for r in (wide, phone) if r["clipped_values"]]
    assert sum("outside 0..1 clipped" in line for line in proc.stderr.splitlines()) == len(clipped)


def _damaged(run, tmp_path, edit, name="last.pt"):
    payload = torch.load(run / name, weights_only=True)
    edit(payload)
    target = tmp_path / "damaged"
    target.mkdir()
    torch.save(payload, target / "best.pt")
    return target


def _nan_weights(p):
    for v in p["state_dict"].values():
        v.fill_(float("nan"))


@pytest.mark.parametrize(
    "edit, needle",
    [
        (_nan_weights, "the model's output is not finite"),
        (lambda p: p.update(version=9), "checkpoint version 9"),
        (lambda p: p["dataset"].update(fps=1e9), "malformed dataset 'fps'"),
        (
            lambda p: p["dataset"].update(channels=p["dataset"]["channels"][:3]),
            "3 listed, the model outputs 32",
        ),
        (lambda p: p["dataset"]["features"]["settings"].update(sample_rate=8000), "computed at 8000 Hz"),
    ],
    ids=["nan-output", "version", "fps", "channels", "sample-rate"],
)
def test_malformed_checkpoints_are_refused_by_predict(runs, tmp_path, edit, needle):
    run = _damaged(runs["ridge"], tmp_path, edit)
    out = tmp_path / "x.csv"
    _one_line_error(_cli("predict", run, runs["wav"], "-o", out), needle)
    assert not out.exists()


def test_several_audio_files_one_bad_the_others_written(runs, tmp_path):
    bad = tmp_path / "bad.wav"
    sf.write(bad, np.full(16000, np.nan, np.float32), 16000, subtype="FLOAT")
    out = tmp_path / "out"
    proc = _cli("predict", runs["ridge"], runs["wav"], bad, runs["wav"], "-o", out, "--json")
    _one_line_error(proc, "1 of 3 audio files failed")
    lines = [json.loads(line) for line in proc.stdout.splitlines()]
    assert ["error" in line for line in lines] == [False, True, False]
    assert sorted(p.name for p in out.iterdir()) == ["audio-2.csv", "audio.csv"]


def test_arch_tables_of_other_systems_are_checked_and_compare_checks_first(runs, tmp_path):
    proc = _cli(
        "fit", "--data", runs["ds"], "--model", "ridge", "-o", tmp_path / "r", "--set", "arch.nvp3.bogus=1"
    )
    _one_line_error(proc, "unknown arch keys ['bogus'] for nvp3")
    out = tmp_path / "cmp"
    proc = _cli(
        "compare",
        "--data",
        runs["ds"],
        "-o",
        out,
        "--models",
        "ridge",
        "blstm",
        "--set",
        "arch.blstm.hidden=0",
    )
    _one_line_error(proc, "arch.hidden must be a positive integer")
    assert not (out / "ridge").exists()  # nothing trained before the bad setting was found


def test_export_to_a_path_that_cannot_be_written_is_one_line(runs, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    _one_line_error(_cli("export", runs["ridge"], "-o", blocker / "m.onnx"), str(blocker))


def test_a_neutral_normalised_run_predicts_on_the_speakers_neutral_pose(tmp_path):
    """A run built with --normalization neutral learns offsets from each take's calibrated rest pose:
    predict adds them to --neutral (the speaker's pose), and says what it does without one."""
    for i in range(4):
        take = make_aligned_take(f"t{i}", 2.0, subject=f"s{i % 2}", seed=i, neutral=True)
        rest = 0.15 * (i % 2)  # speaker s1 rests with the mouth a little open
        take.values += rest
        take.neutral[:] = rest
        write_take(take, tmp_path / "takes")
    options = BuildOptions(
        features=("pitch", "energy", "fbank"),
        normalization="neutral",
        split=SplitRule("take", 0, 0, 0, ("t1",), ("t3",)),
    )
    build_dataset([tmp_path / "takes"], tmp_path / "ds", options, say=lambda _m: None)
    assert _cli("fit", "--data", tmp_path / "ds", "--model", "ridge", "-o", tmp_path / "run").returncode == 0
    truth = read_take(tmp_path / "takes" / "t3")
    errors = {}
    for name, extra in (("without", []), ("with", ["--neutral", tmp_path / "takes" / "t3"])):
        out = tmp_path / f"{name}.csv"
        proc = _cli("predict", tmp_path / "run", tmp_path / "takes" / "t3" / "audio.wav", "-o", out, *extra)
        assert proc.returncode == 0, proc.stderr
        assert ("without --neutral" in proc.stderr) == (name == "without")
        pred = read_livelink_csv(out)
        cols = [pred.channel_index(c) for c in ("jawOpen", "mouthClose", "mouthFunnel")]
        want = truth.values[:, [truth.channel_index(c) for c in ("jawOpen", "mouthClose", "mouthFunnel")]]
        errors[name] = float(np.sqrt(np.mean((pred.values[: len(want), cols] - want) ** 2)))
    assert errors["with"] < 0.5 * errors["without"], errors  # measured: 0.050 against 0.151
    _one_line_error(
        _cli("predict", tmp_path / "run", tmp_path / "takes" / "t3" / "audio.wav", "-o", tmp_path / "x.csv",
             "--neutral", tmp_path / "nowhere.csv"),
        "nowhere.csv",
    )  # fmt: skip
