"""Review of ``s2a-train eval`` scoring a run's channels picked by name from a dataset built with other
channels: calibrated takes (``--normalization neutral``) de-normalise each prediction on the take's own
neutral, which must be picked with the channels; and a run without jawOpen or mouthClose evaluated on a
dataset that has them says the run lacks them, not the dataset. Command lines run as subprocesses on
tiny ridge runs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli
from dataset_helpers import build_take_split, make_aligned_take

from capture import write_take


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """Five calibrated 2 s takes, each channel's neutral its own (so that a neutral taken from the wrong
    column moves the scores), datasets of them with other channel sets, and ridge runs on two of them."""
    root = tmp_path_factory.mktemp("review_trainuse")
    for i in range(5):
        take = make_aligned_take(f"take{i:02d}", 2.0, subject=f"spk{i % 2}", seed=i, neutral=True)
        take.neutral = (0.004 * (1 + np.arange(take.values.shape[1])) * (1 + 0.3 * i)).astype(np.float32)
        write_take(take, root / "takes")
    build_take_split(root / "takes", root / "jaw", channels="jawOpen,mouthClose", normalization="neutral")
    build_take_split(
        root / "takes",
        root / "wide",
        channels="mouthFunnel,mouthClose,jawOpen,mouthSmileLeft",
        normalization="neutral",
    )
    build_take_split(
        root / "takes", root / "funnel", channels="mouthFunnel,mouthSmileLeft", normalization="neutral"
    )
    for ds in ("jaw", "funnel"):
        run_cli("train", "fit", "--data", root / ds, "--model", "ridge", "-o", root / f"run_{ds}", check=True)
    return root


def _eval(work: Path, run: str, ds: str) -> dict:
    proc = run_cli("train", "eval", work / run, "--data", work / ds, "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_calibrated_takes_are_scored_on_the_neutral_of_the_runs_channels(work):
    """Each take's neutral is stored in the dataset's channel order: picked as the channels are, the
    scores on the wider, reordered dataset are the scores on the run's own."""
    own, wide = _eval(work, "run_jaw", "jaw"), _eval(work, "run_jaw", "wide")
    assert list(wide["per_channel"]) == ["jawOpen", "mouthClose"]
    assert wide["frames"] == own["frames"] and wide["utterances"] == own["utterances"]
    for key in ("rmse_entire", "rmse_crucial"):
        assert wide[key] == pytest.approx(own[key], rel=1e-9)
        assert wide["floor"][key] == pytest.approx(own["floor"][key], rel=1e-9)
    assert wide["per_channel"] == pytest.approx(own["per_channel"], rel=1e-9)


def test_a_run_without_jaw_open_on_a_dataset_with_it_says_the_run_lacks_it(work):
    """The note said "the dataset lacks jawOpen or mouthClose" of a dataset holding both."""
    wide = _eval(work, "run_funnel", "wide")
    assert list(wide["per_channel"]) == ["mouthFunnel", "mouthSmileLeft"]
    assert wide["rmse_crucial"] is None
    assert wide["note"] == "the run's channels lack jawOpen or mouthClose: no crucial RMSE"
