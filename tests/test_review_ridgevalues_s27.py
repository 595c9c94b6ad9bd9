"""Review of the ridge fitting each usable value: a channel solved alone is solved on sums taken by
subtraction (every frame's, less its glitched frames'), and an input constant over the frames left (the
zero padding of a sample's first frames, whose left context lies before it) kept the subtraction's
rounding as its variance. Standardised by that rounding, it got weights in the thousands where a solve on
the frames left gives it none."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import run_cli
from dataset_helpers import build_take_split, make_aligned_take
from test_review_valuemask_s26 import _dataset

from capture import ARKIT61, write_take
from dataset.manifest import read_manifest
from train.checkpoint import load_checkpoint
from train.config import resolve_config
from train.data import present_frames, resolve_inputs, to_model_inputs, utterances
from train.ridge import NormalEquations, Ridge

YAW = ARKIT61.index("headYaw")
JAW = ARKIT61.index("jawOpen")
KEPT = 4  # headYaw usable in each sample's first frames only: past ±10 in the others


def _values_and_direct(x, y, usable, alpha):
    """(solution of the sums of ``usable`` values, solution of channel 1 solved on its usable frames)."""
    eq = NormalEquations(x.shape[1], y.shape[1])
    eq.add(x, y, usable)
    alone = NormalEquations(x.shape[1], 1)
    alone.add(x, y[:, 1:], usable[:, 1])
    return eq.solution(alpha), alone.solution(alpha)


@pytest.mark.parametrize("kept", [1, 30])
def test_a_channel_usable_in_a_few_frames_is_solved_as_on_those_frames_alone(kept):
    """4,000 frames; channel 1 usable in its first ``kept`` frames, whose first 15 inputs are 0 (padding).
    Before: weights off by 977 (kept 1, alpha 1e-4) and 44 (kept 30), predictions by 4,360 and 246."""
    gen = torch.Generator().manual_seed(1)
    x, y = torch.randn(4000, 45, generator=gen), torch.randn(4000, 2, generator=gen)
    x[:kept, :15] = 0.0
    usable = torch.ones(4000, 2, dtype=torch.bool)
    usable[kept:, 1] = False
    (w, bias), (w_alone, bias_alone) = _values_and_direct(x, y, usable, 1e-4)
    scale = max(float(w_alone.abs().max()), 1.0)
    torch.testing.assert_close(w[:, 1:], w_alone, rtol=0, atol=1e-4 * scale)
    torch.testing.assert_close(bias[1:], bias_alone, rtol=0, atol=1e-4 * scale)
    if kept == 1:  # one frame: every input constant, no weight; the bias is the frame's value
        assert not w[:, 1].any()
        assert float(bias[1]) == pytest.approx(float(y[0, 1]), abs=1e-9)


def test_leaving_a_take_out_keeps_its_constant_inputs_without_weight():
    """Agreement's leave-one-take-out subtracts a take's sums: a channel usable in the one frame left
    after it gets no weight either (its value as bias)."""
    gen = torch.Generator().manual_seed(2)
    x, y = torch.randn(2, 3000, 30, generator=gen), torch.randn(2, 3000, 2, generator=gen)
    usable = torch.ones(2, 3000, 2, dtype=torch.bool)
    usable[1, 1:, 1] = False  # the take kept has channel 1 usable in its first frame only
    parts = []
    for t in range(2):
        eq = NormalEquations(30, 2)
        eq.add(x[t], y[t], usable[t])
        parts.append(eq)
    w, bias = NormalEquations.total(parts).minus(parts[0]).solution(1e-4)
    assert not w[:, 1].any()
    assert float(bias[1]) == pytest.approx(float(y[1, 0, 1]), abs=1e-9)


@pytest.fixture(scope="module")
def late_glitch(tmp_path_factory):
    """``build_take_split``'s five ARKit61 takes (1 s samples) of an ``all`` dataset: headYaw past ±10
    after each sample's first ``KEPT`` frames in the training takes."""
    root = tmp_path_factory.mktemp("late_glitch")
    for i in range(5):
        take = make_aligned_take(f"take{i:02d}", 2.0, subject=f"spk{i % 2}", seed=i, channels=ARKIT61)
        if i < 3:
            for start in (0, 60):
                take.values[start + KEPT : start + 60, YAW] = 40.0
        write_take(take, root / "takes")
    return build_take_split(root / "takes", root / "ds", channels="all")


def _solved_alone(ds, cfg, channels):
    """(weight, bias) rows of ``channels``, each solved alone on the training frames it is usable in."""
    manifest = read_manifest(ds)
    spec = resolve_inputs(manifest, cfg)
    model = Ridge(spec.content_dim, spec.prosody_dim, spec.out_dim, cfg["ridge_context"])
    eqs = {c: NormalEquations(model.linear.in_features, 1) for c in channels}
    for item in utterances(ds, "train", spec, cfg, manifest, values=True):
        x = model.inputs(*to_model_inputs(item, spec), present_frames(item))
        for c, eq in eqs.items():
            eq.add(x, item["anim"][..., c : c + 1], item["values"][..., c])
    return {c: eq.solution(cfg["ridge_alpha"]) for c, eq in eqs.items()}


def test_fit_solves_a_channel_usable_at_sample_starts_as_alone(late_glitch, tmp_path):
    """The ridge ``s2a-train fit`` solves (alpha 1e-4) against each channel solved on its own usable frames.
    Before, headYaw's largest weight was 0.247 where alone it is 0.142."""
    sets = ["ridge_alpha=0.0001"]
    run = tmp_path / "run"
    proc = run_cli("train", "fit", "--data", late_glitch, "--model", "ridge", "-o", run, "--set", sets[0])
    assert proc.returncode == 0, proc.stderr
    state = load_checkpoint(run / "last.pt")["state_dict"]
    weight, bias = state["linear.weight"], state["linear.bias"]
    for c, (w, b) in _solved_alone(late_glitch, resolve_config(sets=sets), (JAW, YAW)).items():
        np.testing.assert_allclose(weight[c].numpy(), w[:, 0].float().numpy(), rtol=0, atol=1e-4)
        np.testing.assert_allclose(float(bias[c]), float(b[0]), rtol=0, atol=1e-4)


def test_a_manifest_counting_val_values_it_lacks_leaves_ridge_at_alpha_1(tmp_path):
    """A hand-edited manifest whose val samples count usable values the split does not hold (its face lost
    throughout): fit trusts the count (no val split read to tell), and the alpha grid scored nothing
    (NaN). Before, the ridge took the grid's first alpha (1e-4) silently; now it says so and uses alpha
    1, as with a manifest that tells the truth. ``s2a-dataset validate`` names the count."""
    ds = _dataset(tmp_path, lost=True)
    manifest = json.loads((ds / "manifest.json").read_text())
    for s in manifest["samples"]:
        if s["split"] == "val":
            s["usable_values"] = 100
    (ds / "manifest.json").write_text(json.dumps(manifest))
    proc = run_cli("train", "fit", "--data", ds, "--model", "ridge", "-o", tmp_path / "run")
    assert proc.returncode == 0, proc.stderr
    assert "val split has no usable value" in proc.stdout + proc.stderr
    assert load_checkpoint(tmp_path / "run" / "last.pt")["config"]["ridge_alpha"] == 1.0
    proc = run_cli("dataset", "validate", ds)
    assert proc.returncode == 1 and "usable_values: manifest says 100" in proc.stdout + proc.stderr
