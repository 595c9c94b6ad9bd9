"""``s2a-train`` on bad input: config values out of range, diverging training, torn metrics, resuming on
another dataset or config, evaluation with the run's own normalisation, malformed checkpoints, output
paths and messages. Every case is a one-line error naming the file or config key, or a documented
behaviour."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import soundfile as sf
import torch
from conftest import run_cli, run_here
from dataset_helpers import write_aligned_set
from test_train_pipeline import TINY

from capture import read_take
from capture.errors import InputError
from dataset import BuildOptions, build_dataset, read_manifest
from dataset.splits import SplitRule
from dataset.torch_dataset import ShardDataset
from train.checkpoint import load_checkpoint, load_system
from train.config import resolve_config
from train.data import InputSpec, to_model_inputs
from train.evaluate import evaluate
from train.fit import fit
from train.predict import predict
from train.systems import build_model

QUIET = {"say": lambda _m: None}


def _build(takes, out, val, normalization="zscore"):
    options = BuildOptions(
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, (val,), ("take04",)),
        normalization=normalization,
        max_sample_s=1.5,
    )
    build_dataset([takes], out, options, say=lambda _m: None)
    return out


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """The run's dataset, the same takes built with another val take and neutral normalisation (other
    statistics, the same test take), and a run of a few steps on the first."""
    root = tmp_path_factory.mktemp("robust")
    takes = write_aligned_set(root / "takes", count=6, speakers=2, seconds=3.0)
    ds = _build(takes, root / "ds", "take05")
    other = _build(takes, root / "other", "take03", "neutral")
    run = root / "run"
    fit(ds, run, resolve_config(sets=TINY + ["max_steps=4", "eval_every=2"]), **QUIET)
    return {"root": root, "takes": takes, "ds": ds, "other": other, "run": run}


def _cfg(*sets):
    return resolve_config(sets=TINY + list(sets))


# 1. config values


@pytest.mark.parametrize(
    "item, key",
    [
        ("lr=nan", "lr"),
        ("lr=inf", "lr"),
        ("lr=0", "lr"),
        ("seed=1.5", "seed"),
        ("betas=[0.9]", "betas"),
        ("betas=x", "betas"),
        ("betas=[2, 3]", "betas"),
        ("betas=[0.9, 1.0]", "betas"),
        ("ridge_context=-1", "ridge_context"),
        ("ridge_context=100000", "ridge_context"),
        ("patience=-1", "patience"),
        ("min_lr_ratio=2", "min_lr_ratio"),
        ("warmup_steps=-3", "warmup_steps"),
        ("max_minutes=nan", "max_minutes"),
        ("shuffle_buffer=1.5", "shuffle_buffer"),
        ("weight_decay=inf", "weight_decay"),
    ],
)
def test_config_values_out_of_range_name_the_key(item, key):
    with pytest.raises(InputError, match=f"^config:{key}: "):
        resolve_config(sets=[item])


def test_config_toml_betas_of_mixed_types_and_a_folder(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('betas = [0.9, "a"]\n')
    with pytest.raises(InputError, match="config:betas"):
        resolve_config(f)
    with pytest.raises(InputError, match="config path is a folder"):
        resolve_config(tmp_path)


@pytest.mark.parametrize(
    "sets, needle",
    [
        (["arch.content_dim=7"], "arch.content_dim is set from the dataset"),
        (["arch.s2a.out_dim=3"], "arch.out_dim is set from the dataset"),
        (["window=100000"], "config:window: window (100000 frames) exceeds arch.max_frames (8192)"),
        (["arch.max_frames=10"], "exceeds arch.max_frames (10)"),
    ],
)
def test_arch_sizes_from_the_dataset_and_window_are_refused_up_front(sets, needle):
    spec = InputSpec("fbank", 40, ("pitch", "energy"), 3, 32)
    with pytest.raises(InputError) as err:
        build_model("s2a", spec, _cfg(*sets))
    assert needle in str(err.value)


def test_max_frames_below_the_longest_validation_sample_is_refused(data, tmp_path):
    with pytest.raises(InputError, match="more than max_frames"):
        fit(data["ds"], tmp_path / "r", _cfg("arch.max_frames=60", "max_steps=1"), **QUIET)


def test_diverging_training_stops_with_the_step_and_keeps_a_finite_checkpoint(data, tmp_path):
    run = tmp_path / "r"
    cfg = _cfg("lr=1e30", "warmup_steps=0", "grad_clip=0", "max_steps=20", "eval_every=1")
    with pytest.raises(InputError, match=r"training diverged at step \d+"):
        fit(data["ds"], run, cfg, **QUIET)
    state = load_checkpoint(run / "last.pt")
    assert all(torch.isfinite(v).all() for v in state["state_dict"].values())
    assert not state["finished"]


# 3. torn metrics and a corrupt run config


def test_resume_drops_a_torn_last_metrics_line_and_refuses_corruption_elsewhere(data, tmp_path):
    run = tmp_path / "r"
    fit(data["ds"], run, _cfg("max_steps=4", "eval_every=2"), stop_after_steps=2, **QUIET)
    metrics = run / "metrics.jsonl"
    good = metrics.read_text()
    metrics.write_text(good + '{"step": 3, "ms')  # a crash while writing a line
    assert fit(data["ds"], run, _cfg("max_steps=4"), resume=True, **QUIET)["steps"] == 4
    rows = [json.loads(line) for line in metrics.read_text().splitlines()]
    assert rows[-1]["step"] == 4
    run2 = tmp_path / "r2"
    fit(data["ds"], run2, _cfg("max_steps=4", "eval_every=2"), stop_after_steps=2, **QUIET)
    (run2 / "metrics.jsonl").write_text("garbage\n" + (run2 / "metrics.jsonl").read_text())
    with pytest.raises(InputError, match="metrics.jsonl:1: not a metrics record"):
        fit(data["ds"], run2, _cfg("max_steps=4"), resume=True, **QUIET)


@pytest.mark.parametrize("text", ["{", "[1, 2]"])
def test_resume_with_a_corrupt_config_json_is_an_error(data, tmp_path, text):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "config.json").write_text(text)
    with pytest.raises(InputError, match="config.json: "):
        fit(data["ds"], tmp_path / "r", _cfg(), resume=True, **QUIET)


# 4. resuming keeps the run's dataset and config


def test_resume_refuses_another_dataset_and_changed_config_keys(data, tmp_path):
    run = tmp_path / "r"
    fit(data["ds"], run, _cfg("max_steps=4", "eval_every=2"), stop_after_steps=2, **QUIET)
    with pytest.raises(InputError, match="trained on another dataset .*normalization"):
        fit(data["other"], run, _cfg("max_steps=4"), resume=True, **QUIET)
    with pytest.raises(InputError, match="keeps the run's config, but lr, arch.d_model differ"):
        fit(data["ds"], run, _cfg(), resume=True, given={"lr": 0.1, "arch": {"d_model": 64}}, **QUIET)
    # keys given with the run's own values, and the limits, may be given again; a copy of the dataset
    copy = tmp_path / "copy"
    shutil.copytree(data["ds"], copy)
    given = {"lr": 3e-3, "max_steps": 4, "arch": {"d_model": 32}}
    assert (
        fit(copy / "manifest.json", run, _cfg("max_steps=4"), resume=True, given=given, **QUIET)["steps"] == 4
    )


# 6. evaluation uses the run's normalisation


def test_eval_on_the_runs_dataset_matches_the_normalised_reader(data):
    """On the run's own dataset: the reader's normalised items, de-normalised by the reader's affine map."""
    model, payload = load_system(data["run"])
    spec = InputSpec.from_json(payload["inputs"])
    scale = np.asarray(read_manifest(data["ds"])["normalization"]["animation"]["scale"])
    normed = ShardDataset(data["ds"], "test", features=spec.features)
    per_utt = []
    for item in normed:
        batch = {k: v.unsqueeze(0) for k, v in item.items() if isinstance(v, torch.Tensor)}
        with torch.no_grad():
            pred = model(*to_model_inputs(batch, spec), batch["mask"])[0].double().numpy()
        mask = item["mask"].numpy()
        d = (pred - item["anim"].numpy())[mask] * scale * 100
        per_utt.append(np.sqrt((d**2).mean()))
    r = evaluate(data["run"], data["ds"], rtf_seconds=0.5, **QUIET)
    assert r["rmse_entire"]["mean"] == pytest.approx(np.mean(per_utt), rel=1e-6)


def test_eval_on_a_dataset_with_other_normalisation_gives_the_same_errors(data):
    """The other build holds the same test take (same raw features and animation) under other feature
    and animation statistics: evaluated with the run's statistics, the errors are the same."""
    other_norm = read_manifest(data["other"])["normalization"]
    assert other_norm != read_manifest(data["ds"])["normalization"]
    a = evaluate(data["run"], data["ds"], rtf_seconds=0.5, **QUIET)
    b = evaluate(data["run"], data["other"], rtf_seconds=0.5, **QUIET)
    assert b["rmse_entire"]["mean"] == pytest.approx(a["rmse_entire"]["mean"], rel=1e-6)
    assert b["rmse_crucial"]["mean"] == pytest.approx(a["rmse_crucial"]["mean"], rel=1e-6)
    assert b["frames"] == a["frames"]


def _edited_copy(ds, dest, edit):
    shutil.copytree(ds, dest)
    m = json.loads((dest / "manifest.json").read_text())
    edit(m)
    (dest / "manifest.json").write_text(json.dumps(m))
    return dest


def test_eval_on_a_dataset_without_the_runs_feature_is_one_line(data, tmp_path):
    def drop_fbank(m):
        m["features"]["names"].remove("fbank")
        del m["features"]["dims"]["fbank"]

    ds = _edited_copy(data["ds"], tmp_path / "ds", drop_fbank)
    proc = run_here("train", "eval", data["run"], "--data", ds)  # eval's command line: test_train_adversity
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "manifest.json: dataset has no fbank feature, the run needs it" in proc.stderr


# 7. and 9. checkpoints of the right format with wrong contents


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda p: p.pop("state_dict"), "checkpoint lacks 'state_dict'"),
        (lambda p: p.pop("inputs"), "checkpoint lacks 'inputs'"),
        (lambda p: p.update(dataset=None), "checkpoint has malformed 'dataset'"),
        (lambda p: p["state_dict"].pop(next(iter(p["state_dict"]))), "malformed state_dict"),
        (lambda p: p["dataset"].update(fps="sixty"), "malformed dataset 'fps'"),
        (lambda p: p["inputs"].update(colour=1), "malformed inputs"),
    ],
)
def test_checkpoint_with_wrong_contents_is_refused(data, tmp_path, edit, needle):
    payload = torch.load(data["run"] / "last.pt", weights_only=True)
    edit(payload)
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(InputError, match="bad.pt: ") as err:
        load_system(tmp_path / "bad.pt")
    assert needle in str(err.value)


def test_fit_refuses_a_manifest_fps_that_is_not_a_number(data, tmp_path):
    ds = _edited_copy(data["ds"], tmp_path / "ds", lambda m: m.update(fps="sixty"))
    with pytest.raises(InputError, match="fps"):
        fit(ds, tmp_path / "r", _cfg("max_steps=1"), **QUIET)


def test_fit_names_the_manifest_of_malformed_normalization(data, tmp_path):
    ds = _edited_copy(
        data["ds"], tmp_path / "ds", lambda m: m["normalization"]["animation"].update(scale="x")
    )
    with pytest.raises(InputError, match="manifest.json: .*normalization"):
        fit(ds, tmp_path / "r", _cfg("max_steps=1"), **QUIET)


# 8. and 10. output paths and messages


def test_fit_into_a_file_is_refused(data, tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError, match="run folder path is a file"):
        fit(data["ds"], tmp_path / "f", _cfg(), **QUIET)


def test_predict_paths_and_messages(data, tmp_path):
    wav = next(data["takes"].rglob("audio.wav"))
    out = tmp_path / "no" / "such" / "x.csv"
    assert predict(data["run"], [wav], out, **QUIET)[0]["csv"] == str(out) and out.is_file()
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for d in ("a", "b"):
        shutil.copy(wav, tmp_path / d / "x.wav")
    rows = predict(data["run"], [tmp_path / "a" / "x.wav", tmp_path / "b" / "x.wav"], tmp_path / "o", **QUIET)
    assert [r["csv"] for r in rows] == [str(tmp_path / "o" / "x.csv"), str(tmp_path / "o" / "x-2.csv")]
    # a take's frame count comes back from its audio even when that ends inside the last frame
    frames = read_take(wav.parent).time.size
    audio, rate = sf.read(wav)
    sf.write(tmp_path / "trimmed.wav", audio[: int(round((frames - 0.4) * rate / 60.0))], rate)
    [trimmed] = predict(data["run"], [tmp_path / "trimmed.wav"], tmp_path / "t.csv", **QUIET)
    assert trimmed["frames"] == frames
    sf.write(tmp_path / "short.wav", np.zeros(10, np.float32), 16000)
    with pytest.raises(InputError, match="short.wav: audio is shorter than half an animation frame"):
        predict(data["run"], [tmp_path / "short.wav"], tmp_path / "s.csv", **QUIET)
    (tmp_path / "dir.wav").mkdir()
    with pytest.raises(InputError, match="dir.wav: is a folder"):
        predict(data["run"], [tmp_path / "dir.wav"], tmp_path / "d.csv", **QUIET)
    with pytest.raises(InputError, match="unknown speaker 'nobody' .*spk0, spk1"):
        predict(data["run"], [wav], tmp_path / "n.csv", speaker="nobody", **QUIET)


def test_export_into_a_folder_is_one_line(data, tmp_path):
    """export's command line as a user runs it (a subprocess); the other commands here run in this
    process (fit's and eval's command lines run as subprocesses in test_train_adversity.py)."""
    proc = run_cli("train", "export", data["run"], "-o", tmp_path)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "output path is a folder" in proc.stderr


def test_cli_resume_with_a_changed_set_is_one_line(data, tmp_path):
    run = tmp_path / "r"
    shutil.copytree(data["run"], run)
    proc = run_here("train", "fit", "--data", data["ds"], "-o", run, "--resume", "--set", "lr=0.1")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "--resume keeps the run's config, but lr differ" in proc.stderr
    proc = run_here("train", "fit", "--data", data["ds"], "-o", run, "--config", tmp_path)
    assert proc.returncode == 1 and "config path is a folder" in proc.stderr


def test_a_val_split_without_usable_frames_counts_as_none(tmp_path):
    """A val take whose face was lost throughout: fit validates nothing (and says why) instead of scoring
    NaN; eval of that split is an error, not a perfect score; compare checks its split before training."""
    from dataset_helpers import make_aligned_take

    from capture import write_take
    from train.compare import compare

    for i in range(4):
        write_take(
            make_aligned_take(f"t{i}", 2.0, subject="a", seed=i, gap=(0, 120) if i == 1 else None), tmp_path
        )
    options = BuildOptions(
        features=("pitch", "energy", "fbank"), split=SplitRule("take", 0, 0, 0, ("t1",), ())
    )
    build_dataset([tmp_path], tmp_path / "ds", options, **QUIET)
    said = []
    ridge = fit(tmp_path / "ds", tmp_path / "ridge", _cfg("model=ridge"), say=said.append)
    assert ridge["best_val"] is None and any("note: the val split has no usable frames" in x for x in said)
    assert "val mse" not in said[-1]
    tiny = fit(tmp_path / "ds", tmp_path / "s2a", _cfg("max_steps=4", "eval_every=2"), say=said.append)
    assert tiny["stopped"] == "max_steps" and tiny["best_val"] is None
    for line in (tmp_path / "s2a" / "metrics.jsonl").read_text().splitlines():
        json.loads(line, parse_constant=lambda c: pytest.fail(f"{c} in metrics.jsonl"))
    with pytest.raises(InputError, match="the val split has no usable frames"):
        evaluate(tmp_path / "ridge", tmp_path / "ds", "val", **QUIET)
    with pytest.raises(InputError, match="dataset has no 'test' split to compare on"):
        compare(tmp_path / "ds", tmp_path / "cmp", ["ridge"], lambda _name: _cfg("model=ridge"), **QUIET)
    assert not (tmp_path / "cmp").exists()
    with pytest.raises(InputError, match="no take 'nobody'"):  # a refused run leaves no folder
        fit(tmp_path / "ds", tmp_path / "refused", _cfg('val_takes=["nobody"]'), **QUIET)
    assert not (tmp_path / "refused").exists()
