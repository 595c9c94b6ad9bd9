"""Reread of train/ridge.py, train/agreement.py and train/fit.py.

- An input constant over the frames summed directly (not by subtraction) kept the rounding of its float64
  sums as its variance: standardised by it, it got a weight (up to 2.3 in 5 frames, 0.02 in 997) where the
  ridge gives a constant input none, as it did for sums taken by subtraction.
- A ridge run made with ``ridge_alpha = 0`` (choose on val) could not be resumed with the command that
  made it: its checkpoint's config holds the alpha chosen, so ``compare`` run again (it resumes the runs
  it finds) failed the ridge row, and ``fit --resume --set ridge_alpha=0`` was refused.
"""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from conftest import run_cli

from train.ridge import NormalEquations


def _solutions(x, y, constant, alpha):
    """(solution of ``x``'s sums, solution of the sums without column ``constant``)."""
    every = torch.ones(x.shape[0], dtype=torch.bool)
    eq = NormalEquations(x.shape[1], y.shape[1])
    eq.add(x, y, every)
    rest = torch.cat([x[:, :constant], x[:, constant + 1 :]], dim=1)
    without = NormalEquations(rest.shape[1], y.shape[1])
    without.add(rest, y, every)
    return eq.solution(alpha), without.solution(alpha)


@pytest.mark.parametrize(("frames", "value"), [(5, -1.65), (997, 0.3), (997, -1.2345), (997, 33.3)])
def test_an_input_constant_over_the_frames_summed_gets_no_weight(frames, value):
    """Ten inputs, the fourth ``value`` in every frame. Before: its weight was 2.33 (5 frames, fewer than
    inputs) and 0.008, 0.019, 0.0005 (997 frames), from the rounding of Σx² less n·mean²."""
    gen = torch.Generator().manual_seed(frames)
    x, y = torch.randn(frames, 10, generator=gen), torch.randn(frames, 2, generator=gen)
    x[:, 3] = value
    for alpha in (1e-4, 1e-2, 1.0):
        (w, bias), (w_rest, bias_rest) = _solutions(x, y, 3, alpha)
        assert not w[3].any(), f"alpha {alpha}: weight {w[3].tolist()} on a constant input"
        torch.testing.assert_close(torch.cat([w[:3], w[4:]]), w_rest, rtol=0, atol=1e-9)
        torch.testing.assert_close(bias, bias_rest, rtol=0, atol=1e-9)


def test_an_input_varying_little_around_a_large_mean_keeps_its_weight():
    """The rounding share (1e-10 of the mean square) is far below a real variance: an input varying by
    1e-3 around 5 (a variance 4e-8 of its mean square) is not counted constant."""
    gen = torch.Generator().manual_seed(3)
    x, y = torch.randn(400, 6, generator=gen), torch.randn(400, 2, generator=gen)
    x[:, 2] = 5.0 + 1e-3 * x[:, 2]  # varies by 1e-3 around 5: a variance of 1e-6, far above rounding
    eq = NormalEquations(6, 2)
    eq.add(x, y, torch.ones(400, dtype=torch.bool))
    w, _ = eq.solution(1e-4)
    assert w[2].abs().max() > 1e-3


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    from dataset_helpers import build_five_take_dataset

    return build_five_take_dataset(tmp_path_factory.mktemp("reread_train"))


def test_compare_run_again_resumes_a_ridge_that_chose_its_alpha(small, tmp_path):
    """``compare`` resumes the runs it finds; run again with ``ridge_alpha=0``, its ridge row failed
    ("ridge_alpha differ(s) from it (the run's: ridge_alpha = 10.0)")."""
    args = ["compare", "--data", small, "-o", tmp_path / "cmp", "--models", "ridge", "--json"]
    args += ["--set", "ridge_alpha=0", "--set", "ridge_context=2"]
    first = run_cli("train", *args)
    assert first.returncode == 0, first.stderr
    again = run_cli("train", *args)
    assert again.returncode == 0, again.stderr
    rows = [json.loads(line) for line in again.stdout.splitlines() if line.startswith("{")]
    assert rows and all("error" not in r for r in rows), rows
    assert "already holds its solution" in again.stderr


def test_fit_resume_of_a_ridge_with_the_command_that_made_it(small, tmp_path):
    run = tmp_path / "ridge"
    args = ["fit", "--data", small, "--model", "ridge", "-o", run, "--json"]
    made = run_cli("train", *args, "--set", "ridge_alpha=0")
    assert made.returncode == 0, made.stderr
    before = (run / "last.pt").read_bytes()
    resumed = run_cli("train", *args, "--set", "ridge_alpha=0", "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(resumed.stdout.splitlines()[-1])["stopped"] == "closed_form"
    assert (run / "last.pt").read_bytes() == before  # nothing solved again
    # another alpha than the run's is still refused, in one line
    other = run_cli("train", *args, "--set", "ridge_alpha=0.5", "--resume")
    assert other.returncode != 0
    assert "ridge_alpha" in other.stderr and "Traceback" not in other.stderr


def test_agreement_on_a_split_the_dataset_lacks_names_it(small, tmp_path):
    """A dataset without a test split: ``agreement --splits test`` said "... with usable frames in " and
    nothing after it."""
    ds = tmp_path / "no_test"
    shutil.copytree(small, ds)
    manifest = json.loads((ds / "manifest.json").read_text())
    for key in ("shards", "samples"):
        manifest[key] = [entry for entry in manifest[key] if entry["split"] != "test"]
    (ds / "manifest.json").write_text(json.dumps(manifest))
    for shard in ds.glob("test-*.tar"):
        shard.unlink()
    proc = run_cli("train", "agreement", "--data", ds, "--splits", "test")
    assert proc.returncode == 1
    (line,) = proc.stderr.splitlines()
    assert line.endswith("usable frames in test (the dataset has no test split)"), line


def test_a_ridge_run_made_twice_is_the_same_checkpoint_byte_for_byte(small, tmp_path):
    """A ridge keeps the random state of its process in its checkpoint; PyTorch seeds a process's
    generator afresh, so two ridges solved alike differed in those bytes (a network run seeds it)."""
    saved = []
    for name in ("one", "two"):
        args = ["fit", "--data", small, "--model", "ridge", "-o", tmp_path / name, "--set", "ridge_alpha=0.5"]
        proc = run_cli("train", *args)
        assert proc.returncode == 0, proc.stderr
        saved.append((tmp_path / name / "last.pt").read_bytes())
    assert saved[0] == saved[1]
