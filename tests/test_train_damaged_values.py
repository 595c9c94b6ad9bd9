"""``s2a-train`` on shards and checkpoints damaged without changing their size: NaN or inf in a sample,
a sample's json made invalid, an animation reshaped (same bytes, other shape), weights made NaN or
huge, and an export path that is a checkpoint. Each is a one-line error, never a NaN score, a
traceback or an overwritten checkpoint.

The fit, eval and export commands run in-process (``train.cli.main``) on one tiny dataset and run; the
damaged copies rewrite single tar members in place, as a bit flip or a careless edit would (the shard
keeps its size; the readers' sha256 of the shard would notice first, so the manifest's is made to
match: each sample's own checks are tested, as for a build that wrote the damage)."""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import tarfile
from pathlib import Path

import numpy as np
import pytest
import torch
from dataset_helpers import make_aligned_take
from test_train_pipeline import TINY

from capture import write_take
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule
from train.cli import main
from train.export import largest_difference

SETS = [a for s in [*TINY, "eval_every=1"] for a in ("--set", s)]
TRAIN, VAL = "train-000000.tar", "val-000000.tar"
TRAIN_KEY, VAL_KEY = "t0_c000", "t1_c000"  # the first training sample, the validation sample


def _train(capsys, *args) -> tuple[int, str, str]:
    """``s2a-train ARGS`` in-process: (exit code, stdout, stderr)."""
    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(result, *needles: str) -> str:
    code, out, err = result
    assert code == 1, out + err
    lines = [line for line in err.splitlines() if line.startswith("s2a-train: error: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert all(n in lines[0] for n in needles), lines[0]
    assert not out.strip(), out  # no JSON (nor anything else) on stdout
    return lines[0]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A tiny dataset (one take with a lost face, whose masked frames hold 0, one with a neutral pose)
    and an s2a run of 2 steps on it."""
    root = tmp_path_factory.mktemp("damaged")
    for i in range(4):
        take = make_aligned_take(
            f"t{i}", 2.0, subject="a", seed=i, gap=(20, 40) if i == 0 else None, neutral=i == 3
        )
        write_take(take, root / "takes")
    options = BuildOptions(
        channels="pronunciation32",
        features=("pitch", "energy", "fbank"),
        split=SplitRule("take", 0.1, 0.1, 0, ("t1",), ("t2",)),
    )
    build_dataset([root / "takes"], root / "ds", options, say=lambda _m: None)
    args = ["fit", "--data", root / "ds", "--model", "s2a", "-o", root / "run", "--max-steps", 2, *SETS]
    assert main([str(a) for a in args]) == 0
    assert (root / "run" / "best.pt").is_file()
    return {"root": root, "ds": root / "ds", "run": root / "run"}


# ------------------------------------------------------------------------------ damaging shards


def _npy_header_length(data: bytes) -> int:
    if data[6] == 1:
        return 10 + int.from_bytes(data[8:10], "little")
    return 12 + int.from_bytes(data[8:12], "little")


def _last_value(data: bytes, value: float) -> bytes:
    """The .npy bytes of a float32 array with its last element set to ``value``."""
    return data[:-4] + np.float32(value).tobytes()


def _reshaped(data: bytes, shape: tuple[int, ...]) -> bytes:
    """The .npy bytes with the header giving ``shape`` (same dtype, same data, same length)."""
    end = _npy_header_length(data)
    start = 10 if data[6] == 1 else 12
    dtype = np.load(io.BytesIO(data)).dtype
    header = f"{{'descr': '{dtype.str}', 'fortran_order': False, 'shape': {shape!r}, }}"
    return data[:start] + (header.ljust(end - start - 1) + "\n").encode() + data[end:]


def _damaged(base, tmp_path: Path, shard: str, member: str, change) -> Path:
    """A copy of the dataset with ``member`` of ``shard`` rewritten in place by ``change`` (bytes →
    bytes of the same length), the manifest's sha256 of the shard made to match (as a build that wrote
    the damage would have: the checks of each sample, not the shard's checksum, are what is tested)."""
    ds = tmp_path / "ds"
    shutil.copytree(base["ds"], ds)
    path = ds / shard
    with tarfile.open(path) as tar:
        info = tar.getmember(member)
    size = path.stat().st_size
    with open(path, "r+b") as f:
        f.seek(info.offset_data)
        new = change(f.read(info.size))
        assert len(new) == info.size
        f.seek(info.offset_data)
        f.write(new)
    assert path.stat().st_size == size
    manifest = json.loads((ds / "manifest.json").read_text())
    (entry,) = [s for s in manifest["shards"] if s["name"] == shard]
    entry["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    (ds / "manifest.json").write_text(json.dumps(manifest))
    return ds


def _fit(capsys, ds: Path, run: Path):
    return _train(capsys, "fit", "--data", ds, "--model", "s2a", "-o", run, "--max-steps", 1, *SETS)


def test_nan_or_inf_in_a_shard_is_refused_by_fit_and_eval(base, tmp_path, capsys):
    # NaN in the validation sample's animation: was "val mse nan (best inf)", early stopping, exit 0
    ds = _damaged(base, tmp_path / "val", VAL, f"{VAL_KEY}.anim.npy", lambda d: _last_value(d, np.nan))
    line = _one_line_error(
        _fit(capsys, ds, tmp_path / "run-val"), VAL, VAL_KEY, "anim.npy", "NaN", f"s2a-dataset validate {ds}"
    )
    assert "val mse" not in line
    assert not (tmp_path / "run-val" / "best.pt").exists()
    _one_line_error(_train(capsys, "eval", base["run"], "--data", ds, "--split", "val"), VAL, VAL_KEY)

    # inf in a training sample's features: was "training diverged at step 1 ... (lower lr?)"
    ds = _damaged(base, tmp_path / "train", TRAIN, f"{TRAIN_KEY}.fbank.npy", lambda d: _last_value(d, np.inf))
    line = _one_line_error(_fit(capsys, ds, tmp_path / "run-train"), TRAIN, TRAIN_KEY, "fbank.npy")
    assert "diverged" not in line and "lower lr" not in line
    # was "rmse entire nan ± nan" (exit 0), and with --json a ValueError traceback
    for extra in ([], ["--json"]):
        _one_line_error(
            _train(capsys, "eval", base["run"], "--data", ds, "--split", "train", *extra),
            TRAIN,
            TRAIN_KEY,
            "s2a-dataset validate",
        )


def test_a_sample_json_made_invalid_is_refused_by_fit_and_eval(base, tmp_path, capsys):
    ds = _damaged(base, tmp_path, TRAIN, f"{TRAIN_KEY}.json", lambda d: b"{" * len(d))  # was JSONDecodeError
    _one_line_error(_fit(capsys, ds, tmp_path / "run"), TRAIN, TRAIN_KEY, "not valid JSON", "validate")
    _one_line_error(
        _train(capsys, "eval", base["run"], "--data", ds, "--split", "train"), TRAIN, TRAIN_KEY, "JSON"
    )


def test_an_animation_reshaped_in_place_is_refused_by_fit_and_eval(base, tmp_path, capsys):
    member = f"{TRAIN_KEY}.anim.npy"
    with tarfile.open(base["ds"] / TRAIN) as tar:
        frames, channels = np.load(io.BytesIO(tar.extractfile(member).read())).shape
    shape = (frames * 2, channels // 2)  # the same values, other rows
    ds = _damaged(base, tmp_path, TRAIN, member, lambda d: _reshaped(d, shape))
    want = f"shape ({frames}, {channels})"
    # fit: was "ValueError: operands could not be broadcast"; eval: "IndexError: boolean index"
    _one_line_error(_fit(capsys, ds, tmp_path / "run"), TRAIN, TRAIN_KEY, "anim.npy", want)
    _one_line_error(_train(capsys, "eval", base["run"], "--data", ds, "--split", "train"), TRAIN_KEY, want)


# ------------------------------------------------------------------------------ damaged checkpoints


def _damaged_checkpoint(base, path: Path, damage) -> Path:
    payload = torch.load(base["run"] / "best.pt", weights_only=True)
    damage(payload["state_dict"])
    torch.save(payload, path)
    return path


def _all_nan(state: dict[str, torch.Tensor]) -> None:
    for k, v in state.items():
        if v.is_floating_point():
            state[k] = v * float("nan")


def _huge_first_bias(state: dict[str, torch.Tensor]) -> None:
    name = next(k for k, v in state.items() if k.endswith("bias") and v.is_floating_point())
    state[name] = state[name].clone()
    state[name][0] = 1e30


def test_a_checkpoint_with_nan_or_huge_weights_is_refused_by_eval_and_export(base, tmp_path, capsys):
    for damage in (_all_nan, _huge_first_bias):
        ckpt = _damaged_checkpoint(base, tmp_path / f"{damage.__name__}.pt", damage)
        # eval: was "rmse entire nan ± nan", exit 0 (and NaN in --json)
        for extra in ([], ["--json"]):
            _one_line_error(
                _train(capsys, "eval", ckpt, "--data", base["ds"], "--split", "test", *extra),
                str(ckpt),
                "not finite",
                "a damaged checkpoint?",
            )
        # export: was "onnxruntime matches PyTorch within 0.00e+00"
        onnx = tmp_path / f"{damage.__name__}.onnx"
        _one_line_error(_train(capsys, "export", ckpt, "-o", onnx), "not finite", "damaged checkpoint")
        assert not onnx.exists()
        assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no partial file left


def test_the_parity_check_fails_on_outputs_that_are_not_finite():
    a = np.zeros((1, 3, 2), np.float32)
    nan = np.full_like(a, np.nan)
    assert largest_difference(a, a + 1e-6) == pytest.approx(1e-6, rel=1e-3)
    for got, ref in ((nan, nan), (nan, a), (a, nan), (a + np.inf, a + np.inf)):
        assert not largest_difference(got, ref) <= 1e-4  # was 0.0: NaN compared with NaN passed


def test_export_refuses_to_write_over_a_checkpoint(base, tmp_path, capsys):
    run = base["run"]
    digests = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.glob("*.pt")}
    link = tmp_path / "link.onnx"
    link.symlink_to(run / "best.pt")
    for ckpt, out, needle in (
        (run / "best.pt", run / "best.pt", "is the checkpoint being exported"),  # was overwritten
        (run, run / "best.pt", "is the checkpoint being exported"),  # the run folder exports best.pt
        (run / "best.pt", link, "is the checkpoint being exported"),
        (run / "best.pt", run / "last.pt", "is a PyTorch checkpoint"),
    ):
        _one_line_error(_train(capsys, "export", ckpt, "-o", out), str(out), needle, "-o")
    assert {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in run.glob("*.pt")} == digests
    assert link.is_symlink() and link.resolve() == (run / "best.pt").resolve()
