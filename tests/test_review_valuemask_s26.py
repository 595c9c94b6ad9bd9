"""Review of 4055f69 (training scores each usable value): a val take whose headYaw is NaN in every frame
has no frame usable in every channel (the manifest's ``usable_frames`` 0), yet its other 60 channels are
usable values the validation loss scores. The run validates on them (before: "the val split has no usable
frames", no validation, no early stopping, no best.pt); a val take that lost the face throughout still
has nothing to validate on."""

from __future__ import annotations

import json

import pytest
from conftest import run_here
from dataset_helpers import build_take_split, make_aligned_take
from test_train_pipeline import TINY

from capture import ARKIT61, write_take
from dataset.manifest import read_manifest

YAW = ARKIT61.index("headYaw")


def _dataset(root, lost):
    """Five ARKit61 takes (2 s): take03 validates, with headYaw NaN in every frame, and every frame
    lost as well when ``lost``."""
    for i in range(5):
        take = make_aligned_take(f"take{i:02d}", 2.0, subject=f"spk{i % 2}", seed=i, channels=ARKIT61)
        if i == 3:
            take.values[:, YAW] = float("nan")
            if lost:
                take.frame_status[:] = 1
        write_take(take, root / "takes")
    return build_take_split(root / "takes", root / "ds", channels="all")


@pytest.mark.parametrize("model", ["s2a", "ridge"])
def test_a_val_split_usable_in_some_channels_only_validates(tmp_path, model):
    ds = _dataset(tmp_path, lost=False)
    val = [s for s in read_manifest(ds)["samples"] if s["key"].startswith("take03")]
    assert val and all(s["usable_frames"] == 0 for s in val)
    sets = [a for s in TINY for a in ("--set", s)]
    proc = run_here(
        "train", "fit", "--data", ds, "--model", model, "-o", tmp_path / "run", "--max-steps", 10, *sets,
        "--set", "eval_every=5", "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "no usable frames" not in proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["best_val"] is not None and summary["best_val"] > 0
    assert (tmp_path / "run" / ("last.pt" if model == "ridge" else "best.pt")).is_file()


def test_a_val_split_without_a_usable_value_still_has_no_validation(tmp_path):
    ds = _dataset(tmp_path, lost=True)
    sets = [a for s in TINY for a in ("--set", s)]
    proc = run_here(
        "train", "fit", "--data", ds, "--model", "s2a", "-o", tmp_path / "run", "--max-steps", 5, *sets,
        "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "the val split has no usable frames" in proc.stderr
    assert json.loads(proc.stdout)["best_val"] is None
