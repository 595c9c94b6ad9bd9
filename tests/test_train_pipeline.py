"""``s2a-train`` end to end on a tiny dataset built with the real pipeline (dataset.build_dataset on
aligned takes): fit (overfitting, exact resume, DDP), eval, predict, export, ablations, bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import ROOT, run_cli, run_here
from dataset_helpers import write_aligned_set

from capture import read_livelink_csv
from capture.errors import InputError
from dataset import BuildOptions, ShardReader, build_dataset, read_manifest
from dataset.splits import SplitRule
from train.checkpoint import load_checkpoint
from train.config import resolve_config
from train.fit import fit
from train.precision import bf16_is_native

TINY = [
    "arch.d_model=32",
    "arch.heads=2",
    "arch.encoder_layers=1",
    "arch.decoder_layers=1",
    "arch.ff_dim=64",
    "arch.experts=8",
    "arch.top_k=2",
    "arch.expert_hidden=16",
    "arch.dropout=0.0",
    "window=60",
    "batch_size=4",
    "warmup_steps=5",
    "lr=3e-3",
    "log_every=5",
    "shuffle_buffer=4",
]


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    takes = write_aligned_set(root / "takes", count=6, speakers=2, seconds=3.0)
    options = BuildOptions(
        features=("pitch", "energy", "fbank", "mfcc"),
        split=SplitRule("take", 0.1, 0.1, 0, ("take05",), ("take04",)),
        shard_bytes=200_000,
        max_sample_s=1.5,
    )
    build_dataset([takes], root / "ds", options, say=lambda _m: None)
    return root / "ds"


def _cli(*args):
    """``s2a-train ARGS`` as a subprocess: the command line as a user runs it."""
    return run_cli("train", *map(str, args))


def _here(*args):
    """``s2a-train ARGS`` in this process, for tests of what a command does (no PyTorch start-up)."""
    return run_here("train", *map(str, args))


def test_fit_cli_overfits_tiny_dataset_and_writes_the_run(ds, tmp_path):
    run = tmp_path / "run"
    sets = [a for s in TINY for a in ("--set", s)]
    proc = _cli(
        "fit",
        "--data",
        ds,
        "--model",
        "s2a",
        "-o",
        run,
        "--max-steps",
        150,
        *sets,
        "--set",
        "eval_every=50",
        "--set",
        "aux_weight=0.0",
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["steps"] == 150 and summary["stopped"] == "max_steps"
    assert "falls back to fbank" in proc.stderr
    for name in ("config.json", "metrics.jsonl", "last.pt", "best.pt"):
        assert (run / name).is_file()
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["arch"]["d_model"] == 32 and cfg["inputs"]["content"] == "fbank"
    losses = [
        r["mse"] for r in map(json.loads, (run / "metrics.jsonl").read_text().splitlines()) if "mse" in r
    ]
    assert len(losses) == 30
    assert np.mean(losses[-3:]) < 0.9 * np.mean(losses[:2])  # most channels are unpredictable noise
    # evaluated on the training split itself, the fit is well below the train-mean floor (in this
    # process: eval's command line runs as a subprocess in test_train_adversity.py)
    proc = _here("eval", run, "--data", ds, "--split", "train", "--json")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)
    assert r["rmse_entire"]["mean"] < 0.8 * r["floor"]["rmse_entire"]["mean"]
    assert r["rmse_crucial"]["mean"] < 0.5 * r["floor"]["rmse_crucial"]["mean"]
    assert r["rtf"] > 0 and r["device"].startswith("cpu") and r["precision"] == "fp32"
    if bf16_is_native():  # the same evaluation in bfloat16: the same errors to bfloat16's rounding
        proc = _here("eval", run, "--data", ds, "--split", "train", "--precision", "bf16", "--json")
        assert proc.returncode == 0, proc.stderr
        half = json.loads(proc.stdout)
        assert half["precision"] == "bf16" and half["rtf"] > 0
        for key in ("rmse_entire", "rmse_crucial"):
            assert abs(half[key]["mean"] - r[key]["mean"]) < 0.02 * r[key]["mean"]
    payload = load_checkpoint(run / "best.pt")
    assert payload["system"] == "s2a" and payload["inputs"]["out_dim"] == 32


def _train_cfg(**over):
    cfg = resolve_config(sets=TINY + ["arch.dropout=0.2", "eval_every=4", "max_steps=12"])
    cfg.update(over)
    return cfg


# Every random augmentation on, channel-weighted loss: resuming must redraw the same masks and noise.
AUGMENTED = dict(
    aug_noise=0.1,
    aug_time_masks=2,
    aug_time_mask_width=5,
    aug_feature_masks=1,
    aug_feature_mask_width=4,
    aug_mask_prosody=True,
    aug_mixup=0.4,
    loss_weights="raw",
)


def test_resume_reproduces_an_uninterrupted_run_exactly(ds, tmp_path):
    quiet = {"say": lambda _m: None}
    full = fit(ds, tmp_path / "full", _train_cfg(**AUGMENTED), **quiet)
    first = fit(ds, tmp_path / "split", _train_cfg(**AUGMENTED), stop_after_steps=6, **quiet)
    assert first["stopped"] == "stopped" and first["steps"] == 6
    second = fit(ds, tmp_path / "split", _train_cfg(), resume=True, **quiet)
    assert second["steps"] == full["steps"] == 12
    # the summary counts passes begun over the training split's samples, however the run was split
    samples = sum(1 for s in read_manifest(ds)["samples"] if s["split"] == "train")
    per_epoch = -(-samples // _train_cfg()["batch_size"])
    assert second["epochs"] == full["epochs"] == -(-12 // per_epoch) > 1
    assert second["best_val"] == full["best_val"]
    a, b = load_checkpoint(tmp_path / "full" / "last.pt"), load_checkpoint(tmp_path / "split" / "last.pt")
    assert a["state_dict"].keys() == b["state_dict"].keys()
    for k in a["state_dict"]:
        assert torch.equal(a["state_dict"][k], b["state_dict"][k]), k
    for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values()):
        assert torch.equal(sa["exp_avg_sq"], sb["exp_avg_sq"])
    assert (a["epoch"], a["batch"]) == (b["epoch"], b["batch"])

    def losses(run):
        rows = map(json.loads, (run / "metrics.jsonl").read_text().splitlines())
        return [(r["step"], r.get("mse"), r.get("val_mse")) for r in rows]

    assert losses(tmp_path / "full") == losses(tmp_path / "split")


def test_resume_refuses_to_overwrite_and_needs_a_checkpoint(ds, tmp_path):
    proc = _here("fit", "--data", ds, "-o", tmp_path / "none", "--resume")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "nothing to resume" in proc.stderr


def _torchrun(ds, run, *extra):
    sets = [a for s in TINY + ["warmup_steps=100", "eval_every=3"] for a in ("--set", s)]
    # --standalone: torchrun picks a free port for its rendezvous itself
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2"]
    cmd += ["-m", "train", "fit", "--data", str(ds)]
    cmd += ["--model", "s2a", "-o", str(run), *sets, *map(str, extra), "--json"]
    env = {"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    if sys.platform.startswith("linux"):  # gloo on loopback: no dependence on what the hostname resolves to
        env["GLOO_SOCKET_IFNAME"] = "lo"
    # generous: three of these start 2 processes each on a machine that may be busy with other work
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summaries = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert len(summaries) == 1  # rank 0 reports
    return summaries[0]


@pytest.fixture(scope="module")
def ddp_runs(tmp_path_factory):
    """A 2-process torchrun of 6 steps, and the same run stopped after 3 steps (still in warm-up, so the
    schedule does not depend on max_steps) and resumed to 6: the two DDP tests below both only read them
    (each torchrun is mostly 3 interpreters' start-up). 3 training samples: one rank's batches hold 2
    windows, the other's 1, so dropout and style dropout draw different amounts of random numbers per
    rank. Returns (whole summary, resumed summary, whole run folder, resumed run folder)."""
    root = tmp_path_factory.mktemp("ddp")
    takes = write_aligned_set(root / "takes", count=5, speakers=2, seconds=1.5)
    options = BuildOptions(
        features=("pitch", "energy", "fbank"), split=SplitRule("take", 0.1, 0.1, 0, ("take03",), ("take04",))
    )
    build_dataset([takes], root / "ds", options, say=lambda _m: None)
    drawing = ("--set", "arch.dropout=0.3", "--set", "speaker_style=true", "--set", "style_dropout=0.5")
    whole = _torchrun(root / "ds", root / "whole", "--max-steps", 6, *drawing)
    _torchrun(root / "ds", root / "cut", "--max-steps", 3, *drawing)
    resumed = _torchrun(root / "ds", root / "cut", "--max-steps", 6, "--resume", *drawing)
    return whole, resumed, root / "whole", root / "cut"


def test_ddp_two_cpu_processes_with_torchrun_and_exact_resume(ds, ddp_runs, tmp_path):
    s, resumed, whole_run, cut_run = ddp_runs
    assert s["world_size"] == 2 and s["steps"] == 6 and s["stopped"] == "max_steps"
    # both ranks stepped together: their parameters are bit-identical after training
    assert len(s["params_checksums"]) == 2 and s["ranks_in_sync"]
    assert json.loads((whole_run / "config.json").read_text())["world_size"] == 2
    # stopped after 3 steps and resumed: every rank continues from its own data position and the result
    # is the same
    assert resumed["world_size"] == 2 and resumed["steps"] == 6 and resumed["ranks_in_sync"]
    assert resumed["params_checksums"] == s["params_checksums"]
    a, b = load_checkpoint(whole_run / "last.pt"), load_checkpoint(cut_run / "last.pt")
    assert a["positions"] == b["positions"] and len(a["positions"]) == 2
    # a cross-validation ensemble under torchrun: each member trains on a subset of the takes, which
    # both ranks share sample by sample (shards divided between ranks could leave one with none)
    cv = _torchrun(ds, tmp_path / "cv", "--max-steps", 3, "--set", "cv_folds=2")
    assert len(cv["members"]) == 2 and all(m["ranks_in_sync"] for m in cv["members"])
    assert len(cv["params_checksums"]) == 4 and (tmp_path / "cv" / "ensemble.json").is_file()
    # resumed by one process, it is refused before anything is written, its own config.json included
    before = (tmp_path / "cv" / "config.json").read_bytes()
    proc = _here("fit", "--data", ds, "-o", tmp_path / "cv", "--resume", "--max-steps", 6)
    assert proc.returncode == 1 and "trained with 2 process(es)" in proc.stderr, proc.stderr
    assert (tmp_path / "cv" / "config.json").read_bytes() == before


def test_ddp_resume_restores_every_ranks_random_numbers(ddp_runs):
    """3 training samples: one rank's batches hold 2 windows, the other's 1, so dropout and style
    dropout draw different amounts of random numbers per rank; resuming must restore each rank's own
    generator for the result to equal an uninterrupted run."""
    whole, resumed, _whole_run, _cut_run = ddp_runs
    assert resumed["params_checksums"] == whole["params_checksums"]


def test_ridge_beats_the_floor_and_eval_matches_a_hand_computation(ds, tmp_path):
    run = tmp_path / "ridge"
    assert _here("fit", "--data", ds, "--model", "ridge", "-o", run).returncode == 0
    proc = _here("eval", run, "--data", ds, "--json")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)
    assert r["rmse_crucial"]["mean"] < r["floor"]["rmse_crucial"]["mean"]
    # the floor by hand: raw animation of the test shards against the training mean, × 100
    m = read_manifest(ds)
    mean = np.array([m["stats"]["train"]["channels"][c]["mean"] for c in m["channels"]])
    per_utt, se, n = [], np.zeros(len(mean)), 0
    jaw, close = m["channels"].index("jawOpen"), m["channels"].index("mouthClose")
    crucial = []
    for s in m["shards"]:
        if s["split"] != "test":
            continue
        for _key, members in ShardReader(ds / s["name"]):
            anim = np.load(__import__("io").BytesIO(members["anim.npy"])).astype(np.float64)
            mask = np.load(__import__("io").BytesIO(members["mask.npy"]))
            d = (anim[mask] - mean) * 100
            per_utt.append(np.sqrt((d**2).mean()))
            crucial.append(np.sqrt((d[:, [jaw, close]] ** 2).mean()))
            se += (d**2).sum(0)
            n += d.shape[0]
    assert r["utterances"] == len(per_utt) and r["frames"] == n
    assert r["floor"]["rmse_entire"]["mean"] == pytest.approx(np.mean(per_utt), rel=1e-9)
    assert r["floor"]["rmse_entire"]["std"] == pytest.approx(np.std(per_utt), rel=1e-9)
    assert r["floor"]["rmse_crucial"]["mean"] == pytest.approx(np.mean(crucial), rel=1e-9)
    assert r["floor"]["per_channel"]["jawOpen"] == pytest.approx(np.sqrt(se[jaw] / n), abs=1e-6)


def test_ablations_predict_and_export(ds, tmp_path):
    run = tmp_path / "mfcc"
    sets = [a for s in TINY for a in ("--set", s)]
    # every command in this process: fit's command line runs as a subprocess above, predict's and export's
    # in test_train_repairs.py; here the subject is what they do, without a PyTorch start-up per command
    proc = _here(
        "fit",
        "--data",
        ds,
        "--model",
        "s2a",
        "-o",
        run,
        "--max-steps",
        3,
        *sets,
        "--set",
        "input=mfcc",
        "--set",
        "prosody=false",
        "--set",
        "eval_every=3",
    )
    assert proc.returncode == 0, proc.stderr
    inputs = load_checkpoint(run / "last.pt")["inputs"]
    assert inputs["content"] == "mfcc" and inputs["content_dim"] == 13 and inputs["prosody_dim"] == 0

    # predict: a take's own audio → a Live Link Face CSV of 61 channels at the dataset's rate
    wav = next((ds.parent / "takes").rglob("audio.wav"))
    out = tmp_path / "pred.csv"
    proc = _here("predict", run, wav, "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    take = read_livelink_csv(out)
    assert len(take.meta.channels) == 61 and take.values.shape[0] == info["frames"] == 180
    lowered = [c.lower() for c in take.meta.channels]
    assert np.all(take.values[:, lowered.index("eyeblinkleft")] == 0)  # not a pronunciation channel
    assert np.ptp(take.values[:, lowered.index("jawopen")]) > 0

    # predict: 70 s of speech, longer than one 30 s window, is run in blended windows
    import soundfile as sf

    speech, sr = sf.read(wav, dtype="float32")
    long_wav = tmp_path / "long.wav"
    sf.write(long_wav, np.tile(speech, int(np.ceil(70 * sr / speech.size)))[: 70 * sr], sr)
    proc = _here("predict", run, long_wav, "-o", tmp_path / "long.csv", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["frames"] == 70 * 60
    jaw = read_livelink_csv(tmp_path / "long.csv").values[:, lowered.index("jawopen")]
    assert jaw.size == 70 * 60 and np.isfinite(jaw).all() and np.ptp(jaw) > 0

    # export: the ONNX graph reproduces the PyTorch model on inputs of another length
    onnx_path = tmp_path / "m.onnx"
    proc = _here("export", run, "-o", onnx_path, "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["max_abs_diff"] < 1e-4
    import onnxruntime as ort

    from train.checkpoint import load_system

    model, _ = load_system(run)
    x = torch.randn(1, 333, 13)
    mask = torch.ones(1, 333, dtype=torch.bool)
    with torch.no_grad():
        ref = model(x, None, mask).numpy()
    got = ort.InferenceSession(str(onnx_path)).run(None, {"content": x.numpy(), "mask": mask.numpy()})[0]
    np.testing.assert_allclose(got, ref, atol=1e-4)


@pytest.mark.parametrize(
    "args, needle",
    [
        (["fit", "--data", "{tmp}/missing", "-o", "{tmp}/r"], "manifest"),
        (["fit", "--data", "{ds}", "-o", "{tmp}/r", "--set", "colour=blue"], "unknown config key 'colour'"),
        (["fit", "--data", "{ds}", "-o", "{tmp}/r", "--set", "input=ppg"], "no ppg feature"),
        (["fit", "--data", "{ds}", "-o", "{tmp}/r", "--set", "arch.wings=2"], "unknown arch keys"),
        (["fit", "--data", "{ds}", "-o", "{tmp}/r", "--set", "arch.top_k=99"], "top_k must be in 1..48"),
        (["fit", "--data", "{ds}", "-o", "{tmp}/r", "--set", "arch.heads=3"], "must be a multiple of heads"),
        (["fit", "--data", "{ds}", "-o", "{tmp}/r", "--set", "arch.d_model=0"], "must be a positive"),
        (["fit", "--data", "{ds}", "-o", "{tmp}/r", "--set", "arch.dropout=1"], "must be in [0, 1)"),
        (["eval", "{tmp}/bad.pt", "--data", "{ds}"], "not a training checkpoint"),
        (["predict", "{tmp}/nothing", "{tmp}/a.wav", "-o", "{tmp}/o.csv"], "run folder not found"),
    ],
)
def test_cli_bad_input_is_one_line_and_exit_1(ds, tmp_path, args, needle):
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    proc = _here(*[a.format(tmp=tmp_path, ds=ds) for a in args])
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert needle in proc.stderr


def test_fit_without_a_val_split_trains_without_validation(ds, tmp_path):
    options = BuildOptions(split=SplitRule("take", 0.0, 0.1, 0, (), ("take04",)), max_sample_s=1.5)
    build_dataset([ds.parent / "takes"], tmp_path / "ds", options, say=lambda _m: None)
    assert "val" not in {s["split"] for s in read_manifest(tmp_path / "ds")["shards"]}
    s2a = fit(tmp_path / "ds", tmp_path / "s2a", _train_cfg(max_steps=4), say=lambda _m: None)
    assert s2a["steps"] == 4 and s2a["best_val"] is None
    assert (tmp_path / "s2a" / "last.pt").is_file() and not (tmp_path / "s2a" / "best.pt").exists()
    ridge = fit(tmp_path / "ds", tmp_path / "ridge", _train_cfg(model="ridge"), say=lambda _m: None)
    assert ridge["best_val"] is None
    proc = _here("eval", tmp_path / "s2a", "--data", tmp_path / "ds", "--json")
    assert proc.returncode == 0, proc.stderr


def test_val_takes_move_validation_to_chosen_training_takes(ds, tmp_path):
    from train.data import resolve_inputs, split_keys, train_dataset, utterances

    manifest = read_manifest(ds)
    take_of = {s["key"]: s["take"] for s in manifest["samples"]}
    cfg = resolve_config(sets=TINY + ['val_takes=["take01"]'])
    train_keys, val_keys = split_keys(manifest, cfg)
    assert {take_of[k] for k in val_keys} == {"take01"}
    # the dataset's own val take (take05) now trains; the test take never appears
    assert {take_of[k] for k in train_keys} == {"take00", "take02", "take03", "take05"}
    spec = resolve_inputs(manifest, cfg)
    seen = {item["key"] for item in train_dataset(ds, spec, cfg)}
    assert seen == train_keys
    assert {item["key"] for item in utterances(ds, "val", spec, cfg)} == val_keys
    assert {item["key"] for item in utterances(ds, "val", spec)} == {
        s["key"] for s in manifest["samples"] if s["split"] == "val"
    }
    assert split_keys(manifest, resolve_config(sets=TINY)) is None
    ridge = fit(ds, tmp_path / "ridge", {**cfg, "model": "ridge"}, say=lambda _m: None)
    plain = fit(ds, tmp_path / "ridge0", resolve_config(sets=TINY + ["model='ridge'"]), say=lambda _m: None)
    assert ridge["best_val"] is not None and ridge["best_val"] != plain["best_val"]
    for takes, needle in ((["take04"], "in the test split"), (["take99"], "no take 'take99'")):
        with pytest.raises(InputError, match=needle):
            split_keys(manifest, {**cfg, "val_takes": takes})


def test_drop_takes_leave_training_and_validation(ds, tmp_path):
    from train.data import resolve_inputs, split_keys, train_dataset, utterances

    manifest = read_manifest(ds)
    take_of = {s["key"]: s["take"] for s in manifest["samples"]}
    # alone: the dataset's own splits, less the dropped take
    cfg = resolve_config(sets=TINY + ['drop_takes=["take02"]'])
    train_keys, val_keys = split_keys(manifest, cfg)
    assert {take_of[k] for k in train_keys} == {"take00", "take01", "take03"}
    assert {take_of[k] for k in val_keys} == {"take05"}
    spec = resolve_inputs(manifest, cfg)
    assert {item["key"] for item in train_dataset(ds, spec, cfg)} == train_keys
    # with val_takes: the val split's take trains, the dropped take does neither
    both = {**cfg, "val_takes": ["take01"]}
    train_keys, val_keys = split_keys(manifest, both)
    assert {take_of[k] for k in train_keys} == {"take00", "take03", "take05"}
    assert {item["key"] for item in utterances(ds, "val", spec, both)} == val_keys
    # dropping the only val take leaves no validation: training runs without it
    s2a = fit(ds, tmp_path / "s2a", {**cfg, "drop_takes": ["take05"], "max_steps": 4}, say=lambda _m: None)
    assert s2a["steps"] == 4 and s2a["best_val"] is None
    # a cross-validation ensemble deals only the kept takes into folds
    proc = _here(
        "fit",
        "--data",
        ds,
        "-o",
        tmp_path / "cv",
        "--max-steps",
        2,
        *[a for x in TINY + ["cv_folds=2", 'drop_takes=["take00", "take05"]'] for a in ("--set", x)],
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    folds = [set(m["val_takes"]) for m in json.loads(proc.stdout)["members"]]
    assert folds[0] | folds[1] == {"take01", "take02", "take03"}
    for takes, needle in (
        (["take04"], "drop_takes: take 'take04' is in the test split"),
        (["take99"], "drop_takes: no take 'take99'"),
        (["take00", "take01", "take02", "take03", "take05"], "leave no training take"),
    ):
        with pytest.raises(InputError, match=needle):
            split_keys(manifest, {**cfg, "drop_takes": takes})
    with pytest.raises(InputError, match="both validate and are dropped"):
        split_keys(manifest, {**both, "drop_takes": ["take01"]})
    proc = _here("fit", "--data", ds, "-o", tmp_path / "bad", "--set", "drop_takes='take01'")
    assert proc.returncode == 1 and "drop_takes must be a list of take ids" in proc.stderr


def test_agreement_leave_one_take_out_is_the_ridge_fit_trains_without_that_take(ds, tmp_path):
    """s2a-train agreement's leave-one-take-out score of take01 equals, by hand, the RMSE on take01 of
    the ridge that fit trains with take01 held out (val_takes), at the same alpha."""
    from train.checkpoint import load_system
    from train.data import InputSpec, to_model_inputs, utterances

    proc = _here("agreement", "--data", ds, "--set", "ridge_alpha=0.5", "--json")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)
    takes = ["take00", "take01", "take02", "take03", "take05"]  # train and val; take04 is the test take
    assert r["takes"] == takes and r["alpha"] == 0.5 and r["splits"] == ["train", "val"]
    cfg = resolve_config(sets=["model='ridge'", "ridge_alpha=0.5", 'val_takes=["take01"]'])
    fit(ds, tmp_path / "ridge", cfg, say=lambda _m: None)
    model, payload = load_system(tmp_path / "ridge")
    spec = InputSpec.from_json(payload["inputs"])
    scale = np.asarray(read_manifest(ds)["normalization"]["animation"]["scale"])
    se, n = 0.0, 0
    for item in utterances(ds, "val", spec, cfg):
        content, prosody = to_model_inputs(item, spec)
        mask = item["mask"][0].numpy()
        with torch.no_grad():
            pred = model(content, prosody, item["mask"])[0].numpy()
        d = (pred - item["anim"][0].numpy())[mask] * scale
        se, n = se + float((d.astype(np.float64) ** 2).sum()), n + d.size
    assert r["leave_one_out"]["take01"]["rmse"] == pytest.approx(100 * (se / n) ** 0.5, rel=1e-4)
    # a take's own fit (the table's diagonal) beats its floor; every take is scored against every fit
    assert all(r["matrix"][t][t] < 1 for t in takes)
    assert all(set(row) == set(takes) for row in r["matrix"].values())
    human = _here("agreement", "--data", ds, "--splits", "train", "val", "test")
    assert human.returncode == 0 and "take04" in human.stdout and "leave one take out" in human.stdout
    bad = _here("agreement", "--data", ds, "--splits", "dev")
    assert bad.returncode == 1 and "unknown split(s) dev" in bad.stderr and "Traceback" not in bad.stderr


def test_cross_validation_ensemble_one_member_per_fold_averaged(ds, tmp_path):
    """cv_folds = 2: every train/val take validates exactly once; eval, predict and export use the mean
    of the members; resuming a finished ensemble retrains nothing; a second fit into it is refused."""
    from train.checkpoint import load_system
    from train.data import InputSpec, to_model_inputs, utterances

    run = tmp_path / "cv"
    sets = [a for s in TINY + ["cv_folds=2", "eval_every=4"] for a in ("--set", s)]
    proc = _here("fit", "--data", ds, "--model", "s2a", "-o", run, "--max-steps", 8, *sets, "--json")
    assert proc.returncode == 0, proc.stderr
    s = json.loads(proc.stdout)
    members = s["members"]
    assert len(members) == 2 and s["steps"] == 16 and s["stopped"] == "cv_folds"
    folds = [set(m["val_takes"]) for m in members]
    usable = {x["take"] for x in read_manifest(ds)["samples"] if x["split"] in ("train", "val")}
    assert folds[0].isdisjoint(folds[1]) and folds[0] | folds[1] == usable and len(usable) == 5
    for m, takes in zip(members, folds):
        assert set(json.loads((run / m["folder"] / "config.json").read_text())["val_takes"]) == takes
    assert s["cv_score"] == pytest.approx(np.mean([m["best_val"] for m in members]))
    assert (run / "ensemble.json").is_file() and not (run / "last.pt").exists()

    # the ensemble's output is the mean of its members' outputs, on a real test utterance
    ensemble, payload = load_system(run)
    singles = [load_system(run / m["folder"])[0] for m in members]
    spec = InputSpec.from_json(payload["inputs"])
    item = next(utterances(ds, "test", spec))
    content, prosody = to_model_inputs(item, spec)
    with torch.no_grad():
        mean = sum(m(content, prosody, item["mask"]) for m in singles) / 2
        got = ensemble(content, prosody, item["mask"])
    torch.testing.assert_close(got, mean)
    assert not torch.allclose(got, singles[0](content, prosody, item["mask"]))

    proc = _here("eval", run, "--data", ds, "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["rmse_entire"]["mean"] > 0
    wav = next((ds.parent / "takes").rglob("audio.wav"))
    assert _here("predict", run, wav, "-o", tmp_path / "p.csv").returncode == 0
    proc = _here("export", run, "-o", tmp_path / "e.onnx", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["max_abs_diff"] < 1e-4

    again = _here("fit", "--data", ds, "--model", "s2a", "-o", run, *sets)
    assert again.returncode == 1 and "already holds an ensemble" in again.stderr
    proc = _here("fit", "--data", ds, "-o", run, "--resume", "--max-steps", 8, "--json")
    assert proc.returncode == 0, proc.stderr
    assert [m["steps"] for m in json.loads(proc.stdout)["members"]] == [8, 8]


@pytest.mark.parametrize(
    "sets, needle",
    [
        (["cv_folds=6"], "cv_folds = 6 needs as many train/val recordings; the dataset has 5"),
        (["cv_folds=1"], "cv_folds must be 0 (off) or an integer >= 2"),
        (["cv_folds=2", 'val_takes=["take01"]'], "exclude each other"),
    ],
)
def test_cross_validation_ensemble_bad_settings(ds, tmp_path, sets, needle):
    proc = _here("fit", "--data", ds, "-o", tmp_path / "r", *[a for s in sets for a in ("--set", s)])
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert needle in proc.stderr
