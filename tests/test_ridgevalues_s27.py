"""The ridge (the sanity floor) and the take agreement fit each usable value: in an ``all`` dataset whose
headYaw glitches (past ±10) in frames whose other channels are fine, each other channel is solved on those
frames too, and headYaw alone without them. Before, both left out every frame a single channel was
unusable in. The manifest counts each sample's usable values (``usable_values``), so that fit tells
whether the val split holds any without reading it; validate checks the count against the samples."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from conftest import run_cli
from dataset_helpers import build_take_split, make_aligned_take
from test_review_valuemask_s26 import _dataset
from test_train_pipeline import TINY

from capture import ARKIT61, write_take
from capture.errors import InputError
from dataset.manifest import read_manifest
from dataset.torch_dataset import ShardDataset
from train.agreement import take_agreement
from train.checkpoint import load_checkpoint
from train.cli import main
from train.config import resolve_config
from train.data import present_frames, resolve_inputs, to_model_inputs, utterances
from train.fit import _no_validation
from train.ridge import NormalEquations, Ridge

YAW = ARKIT61.index("headYaw")
JAW = ARKIT61.index("jawOpen")
GLITCH = slice(10, 100)  # of 120 frames: headYaw jumps to 40 in every take but the test take
GAP = (110, 115)  # a lost face: every channel unusable
ALPHA = 0.1


@pytest.fixture(scope="module")
def glitched(tmp_path_factory):
    """Five ARKit61 takes (2 s, ``build_take_split``: take03 validates, take04 tests) of an ``all``
    dataset; every take but take04 glitches in headYaw and loses the face in 5 frames."""
    root = tmp_path_factory.mktemp("ridgevalues")
    for i in range(5):
        take = make_aligned_take(f"take{i:02d}", 2.0, subject=f"spk{i % 2}", seed=i, channels=ARKIT61)
        if i != 4:
            take.values[GLITCH, YAW] = 40.0
            take.frame_status[GAP[0] : GAP[1]] = 1
        write_take(take, root / "takes")
    return build_take_split(root / "takes", root / "ds", channels="all")


def _fit(ds, out, sets=()):
    sets = [a for s in [*TINY, *sets] for a in ("--set", s)]
    args = ["fit", "--data", ds, "--model", "ridge", "-o", out, *sets]
    assert main([str(a) for a in args]) == 0
    state = load_checkpoint(out / "last.pt")["state_dict"]
    return state["linear.weight"], state["linear.bias"]


def _solved_per_channel(ds, cfg, usable):
    """(weight, bias) of a ridge solved channel by channel on the training frames ``usable(item)`` marks
    for that channel (item's values (1, T, channels) → (1, T, channels))."""
    manifest = read_manifest(ds)
    spec = resolve_inputs(manifest, cfg)
    model = Ridge(spec.content_dim, spec.prosody_dim, spec.out_dim, cfg["ridge_context"])
    eqs = [NormalEquations(model.linear.in_features, 1) for _ in range(spec.out_dim)]
    for item in utterances(ds, "train", spec, cfg, manifest, values=True):
        x = model.inputs(*to_model_inputs(item, spec), present_frames(item))
        frames = usable(item)
        for c, eq in enumerate(eqs):
            eq.add(x, item["anim"][..., c : c + 1], frames[..., c])
    one = Ridge(spec.content_dim, spec.prosody_dim, 1, cfg["ridge_context"])  # a channel's ridge
    solved = []
    for eq in eqs:
        eq.solve(one, ALPHA)
        solved.append((one.linear.weight.detach().clone(), one.linear.bias.detach().clone()))
    return torch.cat([w for w, _ in solved]), torch.cat([b for _, b in solved])


def _in_every_channel(item):
    """An item's frames usable in every channel, for each channel (what the ridge was solved on before)."""
    return item["mask"].unsqueeze(-1).expand_as(item["values"])


def test_the_ridge_solves_each_channel_on_its_usable_values(glitched, tmp_path):
    weight, bias = _fit(glitched, tmp_path / "run", [f"ridge_alpha={ALPHA}"])
    cfg = resolve_config(sets=[*TINY, f"ridge_alpha={ALPHA}"])
    own, own_bias = _solved_per_channel(glitched, cfg, lambda item: item["values"])
    before, _ = _solved_per_channel(glitched, cfg, _in_every_channel)
    for c in (JAW, YAW):  # jawOpen learns from the glitched frames too; headYaw never from its glitch
        torch.testing.assert_close(weight[c], own[c], rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(bias[c], own_bias[c], rtol=1e-4, atol=1e-5)
    # before: every channel solved on the frames usable in all of them (jawOpen lost 90 of 115)
    assert not torch.allclose(weight[JAW], before[JAW], rtol=1e-3, atol=1e-4)
    torch.testing.assert_close(weight[YAW], before[YAW], rtol=1e-4, atol=1e-5)  # the same frames


def test_a_frame_mask_and_its_values_solve_alike_bit_for_bit():
    """A dataset without channel_mask.npy: every channel's usable values are the mask's frames, and the
    sums and the solution are those of the frame mask, to the bit (its ridge weights as before)."""
    torch.manual_seed(0)
    x, y = torch.randn(2, 50, 9), torch.randn(2, 50, 4)
    mask = torch.rand(2, 50) > 0.3
    solved = []
    for usable in (mask, mask.unsqueeze(-1).expand(-1, -1, 4)):
        eq = NormalEquations(9, 4)
        eq.add(x, y, usable)
        assert not eq.gaps
        solved.append(eq.solution(ALPHA))
    assert all(torch.equal(a, b) for a, b in zip(*solved, strict=True))


def test_leaving_a_take_out_subtracts_its_glitched_values_too():
    torch.manual_seed(2)
    x, y = torch.randn(3, 40, 6), torch.randn(3, 40, 3)
    values = torch.rand(3, 40, 3) > 0.2
    values[0, :, 2] = False  # a channel unusable throughout the first take: its sums leave with it
    parts = []
    for t in range(3):
        eq = NormalEquations(6, 3)
        eq.add(x[t], y[t], values[t])
        parts.append(eq)
    rest = NormalEquations.total(parts).minus(parts[0])
    direct = NormalEquations.total(parts[1:])
    for got, want in zip(rest.solution(ALPHA), direct.solution(ALPHA), strict=True):
        torch.testing.assert_close(got, want, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(rest.means(), direct.means(), rtol=1e-9, atol=1e-12)


def test_agreement_scores_and_fits_each_usable_value(glitched):
    cfg = resolve_config(sets=[*TINY, f"ridge_alpha={ALPHA}"])
    result = take_agreement(glitched, cfg, say=lambda _m: None)
    usable_somewhere = 120 - (GAP[1] - GAP[0])  # before: 25, the frames usable in every channel
    assert result["frames"] == {f"take{i:02d}": usable_somewhere for i in range(4)}, result["frames"]
    assert all(np.isfinite(s["rmse"]) and s["rmse"] > 0 for s in result["leave_one_out"].values())


def test_the_manifest_counts_each_samples_usable_values(glitched, tmp_path):
    manifest = read_manifest(glitched)
    counted = {
        item["key"]: int(item["values"].sum())
        for split in ("train", "val", "test")
        for item in ShardDataset(glitched, split, window=None, features="energy", values=True)
    }
    assert {s["key"]: s.get("usable_values") for s in manifest["samples"]} == counted
    assert counted["take00_c000"] == 60 * 61 - 50  # 1 s: headYaw glitched in 50 of its 60 frames
    proc = run_cli("dataset", "validate", glitched, "--json")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # a count out of step with the samples is a finding
    copy = tmp_path / "ds"
    shutil.copytree(glitched, copy)
    manifest["samples"][0]["usable_values"] += 1
    (copy / "manifest.json").write_text(json.dumps(manifest))
    proc = run_cli("dataset", "validate", copy, "--json")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    problems = json.loads(proc.stdout)["problems"]
    assert [p["code"] for p in problems] == ["manifest_mismatch"], problems
    assert problems[0]["location"].endswith(f"samples[{manifest['samples'][0]['key']}].usable_values")


@pytest.mark.parametrize("lost", [False, True])
def test_fit_tells_from_the_manifest_whether_val_has_a_usable_value(tmp_path, lost):
    ds = _dataset(tmp_path, lost)
    manifest = read_manifest(ds)
    val = [s for s in manifest["samples"] if s["split"] == "val"]
    assert val and all(s["usable_frames"] == 0 for s in val)
    assert all(s["usable_values"] == (0 if lost else 60 * 60) for s in val)
    cfg = resolve_config(sets=TINY)
    for shard in manifest["shards"]:
        if shard["split"] == "val":
            (ds / shard["name"]).write_bytes(b"not a tar")  # never read: the manifest tells
    expected = "the val split has no usable frames (face lost throughout?)" if lost else None
    assert _no_validation(ds, manifest, cfg) == expected
    # a manifest of a build before the count: the samples are read, as before
    for s in val:
        del s["usable_values"]
    with pytest.raises(InputError, match="val-000000.tar: shard size differs"):
        _no_validation(ds, manifest, cfg)
