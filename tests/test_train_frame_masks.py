"""The reader's two frame flags: ``mask`` (usable frames: the loss's and the metrics') and ``present``
(the sample's frames, False on padding only: the model's input). A face-lost stretch is not a target,
but its speech is real and the model hears it at inference: in training it must hear it too."""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest
import torch
from conftest import run_gloo_ranks
from dataset_helpers import build_five_take_dataset, make_aligned_take
from test_train_pipeline import TINY as PIPELINE_TINY
from torch.utils.data import DataLoader

from capture import write_take
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule
from dataset.torch_dataset import ShardDataset
from train.augment import augment, augment_frames
from train.checkpoint import load_system
from train.config import resolve_config
from train.data import present_frames, resolve_inputs, to_model_inputs, utterances
from train.evaluate import evaluate
from train.fit import _train_step, fit, validation_loss
from train.model import masked_mse
from train.ridge import NormalEquations
from train.systems import build_model

evaluate_module = importlib.import_module("train.evaluate")  # the package exports a function of that name
QUIET = {"say": lambda _m: None}
# the pipeline tests' tiny model sizes (their training settings left out), and the BLSTM's width
TINY = [*(s for s in PIPELINE_TINY if s.startswith("arch.")), "arch.hidden=32"]
GAP = (70, 90)  # face lost in each 2 s take: frames 10..29 of its second 1 s sample
SAMPLE = 60  # frames per sample (1 s at 60 fps)
WINDOW = 80  # a training window longer than a sample: 20 frames of padding


@pytest.fixture(scope="module")
def gappy(tmp_path_factory):
    return build_five_take_dataset(tmp_path_factory.mktemp("gappy"), GAP)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return build_five_take_dataset(tmp_path_factory.mktemp("clean"))


def _manifest(ds):
    return json.loads((ds / "manifest.json").read_text())


def _windows(ds, spec):
    data = ShardDataset(ds, "train", window=WINDOW, features=spec.features)
    return next(iter(DataLoader(data, batch_size=8)))


def _gappy_rows(batch):
    """Rows of the batch that hold the face-lost stretch (usable frames missing among present ones)."""
    return [i for i in range(batch["mask"].shape[0]) if bool((batch["present"][i] & ~batch["mask"][i]).any())]


# -- the reader ----------------------------------------------------------------------------------------
def test_reader_flags_padding_apart_from_unusable_frames(gappy, clean):
    for item in ShardDataset(gappy, "train", window=WINDOW):
        present, mask = item["present"].numpy(), item["mask"].numpy()
        assert present.dtype == bool and present.shape == (WINDOW,)
        assert present[:SAMPLE].all() and not present[SAMPLE:].any()  # False on padding only
        assert not (mask & ~present).any()  # a usable frame is always a present one
        if item["key"].endswith("c001"):  # the sample holding the face-lost stretch
            lost = np.zeros(WINDOW, bool)
            lost[GAP[0] - SAMPLE : GAP[1] - SAMPLE] = True
            np.testing.assert_array_equal(mask, present & ~lost)
        else:
            np.testing.assert_array_equal(mask, present)
    for item in ShardDataset(gappy, "train"):  # whole samples: every frame is there
        assert item["present"].all() and item["present"].shape == item["mask"].shape
    for item in ShardDataset(clean, "train", window=WINDOW):  # nothing unusable: the two agree
        np.testing.assert_array_equal(item["present"].numpy(), item["mask"].numpy())


# -- training: the model hears the face-lost stretch, the loss ignores it ----------------------------
class Spy(torch.nn.Module):
    """The model as ``_train_step``'s ``net``, recording what it was given and what it gave."""

    def __init__(self, model):
        super().__init__()
        self.model = model
        self.calls = []

    def forward(self, content, prosody, mask):
        out = self.model(content, prosody, mask)
        self.calls.append((mask.clone(), out.detach().clone()))
        return out


@pytest.mark.parametrize("system", ["s2a", "s2a-nomoe", "blstm", "nvp3", "nvp9"])
def test_training_step_feeds_the_model_every_frame_of_the_sample(gappy, system):
    cfg = resolve_config(sets=[*TINY, f"model={system}", f"window={WINDOW}"])
    spec = resolve_inputs(_manifest(gappy), cfg)
    torch.manual_seed(0)
    model, _ = build_model(system, spec, cfg)
    batch = _windows(gappy, spec)
    rows = _gappy_rows(batch)
    assert rows, "the batch should hold a face-lost stretch"
    spy = Spy(model)
    mse, _, _, mask = _train_step(spy, model, batch, spec, cfg, None, torch.device("cpu"))
    given, pred = spy.calls[-1]
    # the model got the frames of the samples (False on padding only), the loss the usable ones
    np.testing.assert_array_equal(given.numpy(), batch["present"].numpy())
    np.testing.assert_array_equal(mask.numpy(), batch["mask"].numpy())
    assert float(mse.detach()) == pytest.approx(
        float(masked_mse(pred, batch["anim"], batch["mask"])), rel=1e-5
    )

    # at every real frame, next to the face-lost stretch too, training's output is inference's: the
    # sample alone, every frame real (as s2a-train predict runs it), in eval mode
    model.eval()
    content, prosody = to_model_inputs(batch, spec)
    with torch.no_grad():
        for i in rows:
            alone = model(
                content[i : i + 1, :SAMPLE], prosody[i : i + 1, :SAMPLE], torch.ones(1, SAMPLE, dtype=bool)
            )
            np.testing.assert_allclose(pred[i, :SAMPLE].numpy(), alone[0].numpy(), atol=2e-4, rtol=1e-4)
            # whereas treating the stretch as padding changes the frames next to it (the test can tell)
            as_padding = model(content[i : i + 1], prosody[i : i + 1], batch["mask"][i : i + 1])
            edge = [GAP[0] - SAMPLE - 1, GAP[1] - SAMPLE]
            assert not torch.allclose(as_padding[0, edge], alone[0, edge], atol=1e-3)


def test_training_loss_ignores_the_targets_of_unusable_frames(gappy):
    cfg = resolve_config(sets=[*TINY, f"window={WINDOW}"])
    spec = resolve_inputs(_manifest(gappy), cfg)
    batch = _windows(gappy, spec)
    losses = []
    for garbage in (0.0, 1e3):
        torch.manual_seed(0)
        model, _ = build_model("s2a", spec, cfg)
        b = dict(batch)
        b["anim"] = torch.where(b["mask"].unsqueeze(-1), b["anim"], garbage)
        losses.append(float(_train_step(model, model, b, spec, cfg, None, torch.device("cpu"))[0]))
    assert losses[0] == losses[1]


def test_augmentation_keeps_the_two_flags_consistent(gappy):
    cfg = resolve_config(
        sets=[
            "aug_noise=0.1",
            "aug_time_masks=2",
            "aug_time_mask_width=10",
            "aug_feature_masks=1",
            "aug_feature_mask_width=4",
            "aug_mixup=0.4",
        ]
    )
    spec = resolve_inputs(_manifest(gappy), cfg)
    batch = _windows(gappy, spec)
    content, prosody = to_model_inputs(batch, spec)
    torch.manual_seed(3)
    out = augment_frames(content, prosody, batch["anim"], batch["mask"], batch["present"], cfg)
    _, _, _, mask, present = out
    assert not (mask & ~present).any()
    # mixup: a frame is an input when both windows have it, a target when both have it usable
    torch.manual_seed(3)
    old = augment(content, prosody, batch["anim"], batch["mask"], cfg)  # one flag for both (as before)
    np.testing.assert_array_equal(old[3].numpy(), mask.numpy())
    assert bool((present & ~mask).any())  # the face-lost frames are still heard
    assert not bool((~batch["present"] & present).any())  # padding never becomes an input


# -- validation and evaluation --------------------------------------------------------------------------
def test_validation_loss_scores_usable_frames_of_whole_samples_seen_whole(gappy):
    cfg = resolve_config(sets=TINY)
    manifest = _manifest(gappy)
    spec = resolve_inputs(manifest, cfg)
    torch.manual_seed(0)
    model, _ = build_model("s2a", spec, cfg)
    got = validation_loss(model, gappy, spec, torch.device("cpu"), None, cfg, manifest)
    model.eval()
    se, n = 0.0, 0
    with torch.no_grad():
        for item in utterances(gappy, "val", spec, cfg, manifest):
            content, prosody = to_model_inputs(item, spec)
            pred = model(content, prosody, torch.ones(item["mask"].shape, dtype=bool))  # as at inference
            usable = item["mask"][0]
            se += float(((pred[0] - item["anim"][0])[usable] ** 2).sum())
            n += int(usable.sum()) * pred.shape[-1]
    assert n < sum(s["frames"] for s in manifest["samples"] if s["split"] == "val") * pred.shape[-1]
    assert got == pytest.approx(se / n, rel=1e-5)


def test_eval_feeds_every_frame_and_scores_usable_ones(gappy, tmp_path, monkeypatch):
    cfg = resolve_config(sets=[*TINY, "max_steps=2", "eval_every=2", f"window={WINDOW}"])
    fit(gappy, tmp_path / "run", cfg, **QUIET)
    given = []
    real = evaluate_module.infer

    def spy(model, content, prosody, mask):
        given.append(mask.clone())
        return real(model, content, prosody, mask)

    monkeypatch.setattr(evaluate_module, "infer", spy)
    result = evaluate(tmp_path / "run", gappy, "test", **QUIET)
    test = [s for s in _manifest(gappy)["samples"] if s["split"] == "test"]
    assert result["frames"] == sum(s["usable_frames"] for s in test) < sum(s["frames"] for s in test)
    assert given and all(bool(m.all()) for m in given)  # the model heard the face-lost stretch


def test_ridge_fits_on_inputs_that_include_unusable_frames(gappy, tmp_path):
    cfg = resolve_config(sets=["model=ridge", "ridge_alpha=0.1", "ridge_context=3"])
    fit(gappy, tmp_path / "run", cfg, **QUIET)
    model, _ = load_system(tmp_path / "run")
    manifest = _manifest(gappy)
    spec = resolve_inputs(manifest, cfg)
    eq = NormalEquations(model.linear.in_features, spec.out_dim)
    for item in utterances(gappy, "train", spec, cfg, manifest):
        content, prosody = to_model_inputs(item, spec)
        everything = torch.ones(item["mask"].shape, dtype=bool)  # inputs as at inference
        eq.add(model.inputs(content, prosody, everything), item["anim"], item["mask"])
    expected, _ = build_model("ridge", spec, cfg)
    eq.solve(expected, 0.1)
    np.testing.assert_allclose(
        model.linear.weight.detach().numpy(), expected.linear.weight.detach().numpy(), atol=1e-5
    )
    assert present_frames({"mask": torch.zeros(2, dtype=bool)}).tolist() == [False, False]


# -- DDP: a failed read is every rank's decision -------------------------------------------------------
DDP_FIT = """
import datetime, json, os, sys
rank, rendezvous, cases = int(sys.argv[1]), sys.argv[2], json.loads(sys.argv[3])
os.environ.update(WORLD_SIZE="2", RANK=str(rank), LOCAL_RANK=str(rank))  # as torchrun sets them
import torch.distributed as dist
dist.init_process_group(
    "gloo", init_method="file://" + rendezvous, rank=rank, world_size=2, timeout=datetime.timedelta(0, 60)
)
from train.fit import fit

for ds, run, cfg in cases:  # one fit after the other in the same group: the interpreters start once
    try:
        fit(ds, run, cfg, say=lambda _m: None)
        out = {"run": run, "error": None}
    except Exception as exc:
        out = {"run": run, "error": type(exc).__name__ + ": " + str(exc)}
    print(json.dumps(out), flush=True)
    dist.barrier()  # both ranks done before the next fit, or before the group goes
dist.destroy_process_group()
"""


def _damage_in_place(shard):
    """The first .npy member of ``shard`` made unreadable, the file's size unchanged (what only reading
    the sample finds)."""
    data = bytearray(shard.read_bytes())
    at = data.index(b"\x93NUMPY")
    data[at : at + 6] = b"XXXXXX"
    shard.write_bytes(bytes(data))


def _damaged_dataset(root, split):
    """Five takes of two speakers; the first shard of ``split`` damaged in place."""
    for i, seconds in enumerate([2.0, 1.6, 0.8, 1.2, 1.0]):
        take = make_aligned_take(f"take{i:02d}", seconds, subject=f"spk{i % 2}", seed=i)
        write_take(take, root / "takes")
    options = BuildOptions(
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, ("take03",), ("take04",)),
        max_sample_s=0.4,
        shard_bytes=100_000,
    )
    ds = root / "ds"
    build_dataset([root / "takes"], ds, options, say=lambda _m: None)
    shards = [s["name"] for s in _manifest(ds)["shards"] if s["split"] == split]
    assert len(shards) >= (2 if split == "train" else 1)
    _damage_in_place(ds / shards[0])
    return ds


@pytest.fixture(scope="module")
def ddp_damaged_fits(tmp_path_factory):
    """{split: (dataset, each rank's error)} of a 2-rank fit on a dataset whose first shard of that split
    is damaged; both fits run in one pair of rank processes (their start-up, PyTorch's import, is most of
    each)."""
    root = tmp_path_factory.mktemp("ddp-damaged")
    cfg = resolve_config(sets=[*TINY, "max_steps=40", "eval_every=2", "batch_size=2", "window=24"])
    splits = ("train", "val")
    cases = [[str(_damaged_dataset(root / split, split)), str(root / split / "run"), cfg] for split in splits]
    lines = run_gloo_ranks(DDP_FIT, [str(root / "rendezvous"), json.dumps(cases)], timeout=240)
    found = [[r for r in map(json.loads, rank_lines) if "run" in r] for rank_lines in lines]
    assert all([r["run"] for r in rank] == [c[1] for c in cases] for rank in found), found
    return {split: (cases[k][0], [rank[k]["error"] for rank in found]) for k, split in enumerate(splits)}


@pytest.mark.parametrize("split", ["train", "val"])
def test_ddp_ranks_stop_together_when_one_meets_a_damaged_sample(ddp_damaged_fits, split):
    """Each rank reads its own shards (or its own samples of a shared one): the rank that met the
    damaged sample used to stop alone while the other waited at the gradients' all-reduce (or the
    validation's sum) until the process group timed out. Now both stop at once with its line."""
    ds, errors = ddp_damaged_fits[split]
    met = [e for e in errors if "(met by another rank" not in e]
    assert len(met) == 1 and met[0].startswith("InputError: ") and "damaged shard" in met[0], errors
    assert f"s2a-dataset validate {ds})" in met[0], errors  # this fit's dataset, not the other's
    first = errors.index(met[0])
    assert errors[1 - first] == f"{met[0]} (met by another rank: rank {first})", errors
