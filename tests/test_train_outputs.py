"""``s2a-train``'s output and dataset paths: a single run and an ensemble never share a run folder, a fit
refused for a dataset problem leaves no run folder, ``-o`` never lies inside the dataset, ``--data`` is
the dataset folder (or its manifest.json) and never a file in it, ``compare``'s ``-o`` and ``--models``,
and an empty ``-o``. The command line runs in-process (``train.cli.main``) on one tiny dataset."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from dataset_helpers import build_five_take_dataset
from test_train_pipeline import TINY

from train.cli import main
from train.config import resolve_config
from train.fit import fit

QUIET = {"say": lambda _m: None}
SETS = [a for s in [*TINY, "eval_every=1"] for a in ("--set", s)]


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    """Five 2 s takes of two speakers: take03 validates, take04 tests, take00-02 train."""
    return build_five_take_dataset(tmp_path_factory.mktemp("outputs"))


@pytest.fixture(scope="module")
def runs(ds, tmp_path_factory):
    """A single run (ridge: solved in closed form) and a two-member ensemble of one step each."""
    root = tmp_path_factory.mktemp("runs")
    fit(ds, root / "single", resolve_config(sets=TINY + ["model='ridge'"]), **QUIET)
    ensemble = resolve_config(sets=TINY + ["cv_folds=2", "max_steps=1", "eval_every=1"])
    fit(ds, root / "ensemble", ensemble, **QUIET)
    return root / "single", root / "ensemble"


def _cli(capsys, *args) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of ``s2a-train ARGS`` run in-process."""
    try:
        code = main([str(a) for a in args])
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(result, needle: str) -> str:
    code, _out, err = result
    assert code == 1, err
    assert "Traceback" not in err and needle in err, err
    assert [line for line in err.splitlines() if ": error: " in line] == [err.strip()], err
    return err.strip()


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _copy(folder: Path, to: Path) -> Path:
    shutil.copytree(folder, to)
    return to


# 1. a single run and an ensemble never share a run folder


def test_a_single_fit_into_an_ensembles_folder_is_refused_and_the_reverse(ds, runs, tmp_path, capsys):
    single, ensemble = (_copy(r, tmp_path / r.name) for r in runs)
    before = _snapshot(ensemble)
    for extra in ([], ["--set", "cv_folds=0"], ["--model", "ridge"]):  # whatever the config
        result = _cli(capsys, "fit", "--data", ds, "-o", ensemble, *SETS, "--max-steps", 1, *extra)
        _one_line_error(
            result, f"{ensemble}: run folder already holds an ensemble (ensemble.json, fold-*): use --resume"
        )
    assert _snapshot(ensemble) == before  # no last.pt beside ensemble.json, its config.json kept
    assert json.loads((ensemble / "config.json").read_text())["cv_folds"] == 2
    before = _snapshot(single)
    result = _cli(capsys, "fit", "--data", ds, "-o", single, *SETS, "--set", "cv_folds=2", "--max-steps", 1)
    _one_line_error(result, f"{single}: run folder already holds a single run (last.pt), not an ensemble")
    # resumed, the single run keeps its own config: cv_folds is refused as any other changed key
    args = ("fit", "--data", ds, "-o", single, "--resume", "--set", "cv_folds=2")
    _one_line_error(_cli(capsys, *args), "--resume keeps the run's config, but cv_folds differ")
    assert _snapshot(single) == before  # no fold-*, no ensemble.json, its config.json kept


# 2. a dataset problem is refused before the run folder is written


def _missing(ds: Path) -> None:
    (ds / "train-000000.tar").unlink()


def _truncated(ds: Path) -> None:
    with open(ds / "train-000000.tar", "r+b") as f:
        f.truncate(20_000)


def _foreign(ds: Path) -> None:
    """The test shard copied over the val shard: the same size (tar pads to 10 KiB), other samples."""
    shutil.copy(ds / "test-000000.tar", ds / "val-000000.tar")


@pytest.mark.parametrize(
    "damage, shard, needle",
    [
        (_missing, "train-000000.tar", "shard listed in the manifest is missing"),
        (_truncated, "train-000000.tar", "shard size differs from the manifest"),
        (_foreign, "val-000000.tar", "sample take04_c000 is not listed in the manifest for this shard"),
    ],
)
def test_a_fit_refused_for_a_dataset_problem_leaves_no_run_folder(
    ds, tmp_path, capsys, damage, shard, needle
):
    bad = _copy(ds, tmp_path / "bad")
    damage(bad)
    for extra in ([], ["--set", "cv_folds=2"]):  # a single run and an ensemble alike
        run = tmp_path / "run"
        result = _cli(capsys, "fit", "--data", bad, "-o", run, *SETS, "--max-steps", 1, *extra)
        _one_line_error(result, f"{bad / shard}: {needle}")
        assert not run.exists()
    # a folder that existed before the fit keeps what it held, and gains nothing (not even a lock file)
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine\n")
    _one_line_error(_cli(capsys, "fit", "--data", bad, "-o", kept, *SETS, "--max-steps", 1), needle)
    assert sorted(p.name for p in kept.iterdir()) == ["notes.txt"]


# 3. -o is never the dataset folder or inside it


def test_fit_and_compare_refuse_an_output_in_the_dataset_folder(ds, tmp_path, capsys):
    data = _copy(ds, tmp_path / "ds")
    before = _snapshot(data)
    for out, data_arg in ((data, data), (data / "runs" / "a", data / "manifest.json")):
        result = _cli(capsys, "fit", "--data", data_arg, "-o", out, *SETS, "--max-steps", 1)
        _one_line_error(result, f"{out}: run folder is ")
    cmp = data / ".." / "ds" / "cmp"
    result = _cli(capsys, "compare", "--data", data, "-o", cmp, "--models", "ridge", *SETS, "--max-steps", 1)
    _one_line_error(result, f"output folder is inside the dataset folder {data}")
    top = {Path(name).parts[0] for name in before}  # the dataset's files and its build's .work/takes
    assert _snapshot(data) == before and {p.name for p in data.iterdir()} == top
    # the reverse, a dataset inside the run folder, is no problem
    outer = tmp_path / "outer"
    _copy(ds, outer / "ds")
    code, _out, err = _cli(capsys, "fit", "--data", outer / "ds", "-o", outer, "--model", "ridge", *SETS)
    assert code == 0 and (outer / "last.pt").is_file(), err


# 4. --data is the dataset folder (or its manifest.json), never a file in it


def test_data_naming_a_file_is_refused_naming_the_file(ds, runs, tmp_path, capsys, monkeypatch):
    single, _ensemble = runs
    shard = ds / "train-000000.tar"
    hint = f"{shard}: --data takes the dataset folder, not a file in it: give the dataset folder {ds}"
    _one_line_error(_cli(capsys, "eval", single, "--data", shard), hint)
    _one_line_error(_cli(capsys, "agreement", "--data", shard), hint)
    run = tmp_path / "run"
    _one_line_error(_cli(capsys, "fit", "--data", shard, "-o", run, *SETS, "--max-steps", 1), hint)
    args = ("compare", "--data", shard, "-o", run, "--models", "ridge", *SETS, "--max-steps", 1)
    _one_line_error(_cli(capsys, *args), hint)
    assert not run.exists()
    # a file outside any dataset is named as given, not as its folder ('.')
    monkeypatch.chdir(tmp_path)
    Path("notes.txt").write_text("not a dataset\n")
    err = _one_line_error(_cli(capsys, "eval", single, "--data", "notes.txt"), "notes.txt: --data takes")
    assert "error: notes.txt: --data takes a dataset folder" in err and "error: .:" not in err
    # the manifest itself is the dataset, as documented
    code, out, err = _cli(capsys, "eval", single, "--data", ds / "manifest.json", "--json")
    assert code == 0 and json.loads(out)["split"] == "test", err


# 5. compare's -o and --models


def test_compare_refuses_a_file_as_output_and_a_repeated_model(ds, tmp_path, capsys):
    out = tmp_path / "results"
    out.write_text("keep me\n")
    result = _cli(capsys, "compare", "--data", ds, "-o", out, "--models", "ridge", *SETS, "--max-steps", 1)
    _one_line_error(result, f"{out}: output folder path is a file: give a folder with -o")
    assert out.read_text() == "keep me\n"
    folder = tmp_path / "cmp"
    models = ("--models", "ridge", "blstm", "ridge")
    result = _cli(capsys, "compare", "--data", ds, "-o", folder, *models, *SETS, "--max-steps", 1)
    _one_line_error(result, "--models names ridge more than once")
    assert not folder.exists()  # refused before anything trains


# 6. an empty -o is a usage error


@pytest.mark.parametrize(
    "command",
    [
        ["fit", "--data", "DS", *SETS, "--max-steps", "1"],
        ["compare", "--data", "DS", "--models", "ridge", *SETS],
        ["predict", "RUN", "a.wav"],
        ["export", "RUN"],
        ["ppg", "--data", "takes", "--steps", "1"],
    ],
)
@pytest.mark.parametrize("blank", ["", "  "])
def test_an_empty_output_path_is_a_usage_error(ds, runs, tmp_path, capsys, monkeypatch, command, blank):
    single, _ensemble = runs
    monkeypatch.chdir(tmp_path)
    shutil.copy(next((ds.parent / "takes").rglob("audio.wav")), "a.wav")
    args = [{"DS": ds, "RUN": single, "takes": ds.parent / "takes"}.get(a, a) for a in command]
    code, _out, err = _cli(capsys, *args, "-o", blank)
    assert code == 2 and "argument -o/--out: an empty path" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.wav"]  # nothing written here (./a.csv)
