"""Second review of the reread of train/ridge.py, train/fit.py and train/agreement.py.

- A ridge run resumes with ``ridge_alpha = 0`` given again when it chose its alpha (``compare`` run
  again gives it); one made with an alpha of the user's (``ridge_alpha = 0.5``) was resumed as well by
  ``fit --resume --set ridge_alpha=0``, answering "nothing to do (alpha 0.5)" to a command that asks for
  the alpha val chooses (before the reread: refused, as every other key given another value).
- ``agreement --splits`` naming a split twice read its takes twice.
"""

from __future__ import annotations

import json

import pytest
from conftest import run_cli


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    from dataset_helpers import build_five_take_dataset

    return build_five_take_dataset(tmp_path_factory.mktemp("review_retrain"))


def _fit_ridge(small, run, *args: str):
    return run_cli("train", "fit", "--data", small, "--model", "ridge", "-o", run, "--json", *args)


def test_a_ridge_given_its_alpha_is_not_resumed_by_a_command_asking_val_to_choose(small, tmp_path):
    run = tmp_path / "given"
    made = _fit_ridge(small, run, "--set", "ridge_alpha=0.5", "--set", "ridge_context=2")
    assert made.returncode == 0, made.stderr
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and p.name != ".lock"}
    resumed = _fit_ridge(small, run, "--set", "ridge_alpha=0", "--set", "ridge_context=2", "--resume")
    assert resumed.returncode == 1, resumed.stdout
    (line,) = resumed.stderr.splitlines()
    assert "ridge_alpha differ(s) from it (the run's: ridge_alpha = 0.5)" in line, line
    after = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file() and p.name != ".lock"}
    assert after == before
    # the command that made it resumes it
    again = _fit_ridge(small, run, "--set", "ridge_alpha=0.5", "--set", "ridge_context=2", "--resume")
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout.splitlines()[-1])["stopped"] == "closed_form"


def test_a_ridge_that_chose_its_alpha_resumes_with_ridge_alpha_0_given_again(small, tmp_path):
    """The reread's fix, kept: config.json holds the 0 asked for, the checkpoint the alpha chosen."""
    run = tmp_path / "chose"
    made = _fit_ridge(small, run, "--set", "ridge_alpha=0", "--set", "ridge_context=2")
    assert made.returncode == 0, made.stderr
    assert json.loads((run / "config.json").read_text())["ridge_alpha"] == 0
    resumed = _fit_ridge(small, run, "--set", "ridge_alpha=0", "--set", "ridge_context=2", "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert "already holds its solution" in resumed.stderr


def test_agreement_reads_a_split_named_twice_once(small):
    """``--splits train val train`` read the train takes twice: their frames counted twice (240 for 120)
    and the leave-one-take-out scores those of train weighted double (1.700 for 1.673)."""
    args = ["agreement", "--data", small, "--set", "ridge_context=1", "--json", "--splits"]
    once = run_cli("train", *args, "train", "val")
    twice = run_cli("train", *args, "train", "val", "train")
    assert once.returncode == 0 and twice.returncode == 0, (once.stderr, twice.stderr)
    assert json.loads(twice.stdout) == json.loads(once.stdout)
