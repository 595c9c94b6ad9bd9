"""``s2a-train`` on hand-written settings the earlier reviews did not try: an ``arch.max_frames`` whose
position table would not fit in memory (it was computed, 24 GB, until the kernel killed the process), a
seed past what PyTorch's generators take (a traceback), an ``aug_mixup`` where float32 Beta draws go
wrong (a traceback, or silently half-and-half mixing), a config key written below ``[arch]`` in TOML,
more SpecAugment masks than a window has frames or the input dims (out of memory once training had
started), a diverging run that has no checkpoint yet (its message promised ``last.pt``), ``compare``
with one system failing (``compare.json`` lost the rows of the systems already done), and ``export -o``
naming a file of the run or of a dataset (replaced by the graph). The command line runs in-process
(``train.cli.main``) on one tiny dataset."""

from __future__ import annotations

import json

import onnx
import pytest
from conftest import run_here
from dataset_helpers import build_five_take_dataset

from capture.errors import InputError
from train.config import resolve_config
from train.export import check_out

# a network that diverges at step 2, before its first checkpoint (its warm-up lr is still 5e27)
DIVERGING = ["lr=1e30", "arch.hidden=8", "window=60", "batch_size=4", "shuffle_buffer=4", "eval_every=2"]


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return build_five_take_dataset(tmp_path_factory.mktemp("configs"))


def _sets(*items):
    return [a for s in items for a in ("--set", s)]


def _one_line_error(proc, needle: str) -> None:
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and needle in proc.stderr, proc.stderr
    assert sum(": error: " in line for line in proc.stderr.splitlines()) == 1, proc.stderr


def test_a_max_frames_whose_table_would_not_fit_is_refused_before_it_is_computed(ds, tmp_path):
    # 3,000,000 x 32 floats: a 384 MB position table (the old code computed it, and 10**8 frames took
    # 24 GB until the process was killed); the default 8192 x 256 is 8 MB
    sets = _sets("arch.d_model=32", "arch.heads=2", "arch.max_frames=3000000", "window=60")
    proc = run_here(
        "train", "fit", "--data", ds, "--model", "s2a", "-o", tmp_path / "run", *sets, "--max-steps", 1
    )
    _one_line_error(proc, "max_frames (3000000) x d_model (32) makes the model compute 384000000 bytes")
    assert not (tmp_path / "run").exists()  # refused before anything is written


@pytest.mark.parametrize("seed", ["9223372036854775808", "99999999999999999999"])
def test_a_seed_past_2_63_is_a_config_error_not_a_traceback(ds, tmp_path, seed):
    sets = _sets("arch.hidden=8", "window=60", f"seed={seed}")
    proc = run_here(
        "train", "fit", "--data", ds, "--model", "nvp3", "-o", tmp_path / "run", *sets, "--max-steps", 1
    )
    _one_line_error(proc, f"config:seed: seed must be an integer in 0..2**63 - 1, got {seed}")
    assert not (tmp_path / "run").exists()
    assert resolve_config(sets=["seed=9223372036854775807"])["seed"] == 2**63 - 1  # the largest is fine


@pytest.mark.parametrize("value", ["1e-300", "0.001", "1e39"])
def test_aug_mixup_where_float32_beta_draws_go_wrong_is_refused(value):
    # 1e-300 failed in torch.distributions.Beta with a traceback; 0.001 drew exactly 0.5 a quarter of the
    # time (windows mixed half and half where almost none should be); 1e39 is inf in float32 (weight 1)
    with pytest.raises(
        InputError, match=r"^config:aug_mixup: aug_mixup must be 0 \(off\) or in \[0.01, 1000\]"
    ):
        resolve_config(sets=[f"aug_mixup={value}"])
    for fine in ("0", "0.01", "0.4", "1000"):
        assert resolve_config(sets=[f"aug_mixup={fine}"])["aug_mixup"] == float(fine)


@pytest.mark.parametrize(
    "sets, needle",
    [
        # 10**12 masks ran out of memory once training had started, its run folder written
        (
            ["aug_time_masks=1000000000000"],
            "config:aug_time_masks: aug_time_masks must be at most window (60)",
        ),
        # the dataset's filter banks have 40 dims: the old code drew the 41 masks and trained on
        (["aug_feature_masks=41"], "config:aug_feature_masks: aug_feature_masks must be at most the content"),
    ],
)
def test_more_masks_than_frames_or_dims_are_refused_before_writing(ds, tmp_path, sets, needle):
    widths = ["aug_time_mask_width=3", "aug_feature_mask_width=3", "arch.hidden=8", "window=60"]
    args = ["--data", ds, "--model", "nvp3", "-o", tmp_path / "run", *_sets(*widths, *sets), "--max-steps", 1]
    _one_line_error(run_here("train", "fit", *args), needle)
    assert not (tmp_path / "run").exists()


def test_a_config_key_below_the_arch_table_of_a_toml_file_is_said_so(tmp_path):
    # TOML puts every key after [arch] into the table: 'lr' here is arch.lr, not the learning rate
    path = tmp_path / "small.toml"
    path.write_text("window = 120\n[arch]\nd_model = 64\nlr = 1e-3\n")
    with pytest.raises(
        InputError, match=r"small.toml: \[arch\]: unknown arch keys \['lr'\] \('lr' is a config key"
    ):
        resolve_config(path)
    path.write_text("[arch.blstm]\nhidden = 64\npatience = 3\n")
    with pytest.raises(InputError, match="put it above the first table"):
        resolve_config(path)
    path.write_text("[arch]\nd_modle = 64\n")  # a typo still gets the closest arch key
    with pytest.raises(InputError, match="did you mean 'd_model'"):
        resolve_config(path)


@pytest.fixture(scope="module")
def compared(ds, tmp_path_factory):
    """``compare`` of ridge and a diverging NVP-3: (its folder, the command's result)."""
    out = tmp_path_factory.mktemp("compare") / "cmp"
    sets = _sets(*DIVERGING, "ridge_alpha=1")  # ridge ignores lr, and solves once with its alpha given
    return out, run_here(
        "train", "compare", "--data", ds, "-o", out, "--models", "ridge", "nvp3", *sets, "--max-steps", 4
    )


def test_compare_with_one_system_failing_keeps_the_others_results(compared):
    out, proc = compared
    _one_line_error(proc, "1 of 2 systems failed (compare.json holds the others' results)")
    # the diverged system had no checkpoint: its message no longer points to a last.pt that is not there
    assert "no checkpoint was written before it (the first comes at step 2)" in proc.stderr
    assert not (out / "nvp3" / "last.pt").exists()
    ridge, nvp3 = json.loads((out / "compare.json").read_text())
    assert ridge["model"] == "ridge" and ridge["rmse_entire"]["mean"] < ridge["floor"]["rmse_entire"]["mean"]
    assert nvp3["model"] == "nvp3" and "training diverged at step 2" in nvp3["error"]
    table = dict(line.split(None, 1) for line in proc.stdout.splitlines()[2:4])
    assert table["nvp3"].split() == ["failed", "failed"] and "±" in table["ridge"]


def test_export_never_replaces_a_file_of_the_run_or_of_a_dataset(compared, ds):
    run = compared[0] / "ridge"
    for path, owner in ((run / "config.json", "the run exported"), (ds / "manifest.json", "a dataset")):
        before = path.read_bytes()
        proc = run_here("train", "export", run, "-o", path)
        _one_line_error(proc, f"output path is a file of {owner}, not an ONNX model: it is never replaced")
        assert path.read_bytes() == before  # the graph used to be written over it
    # an ONNX model there is replaced (an earlier export's; here a one-node graph)
    x, y = (onnx.helper.make_tensor_value_info(n, onnx.TensorProto.FLOAT, [1]) for n in "xy")
    graph = onnx.helper.make_graph([onnx.helper.make_node("Identity", ["x"], ["y"])], "old", [x], [y])
    onnx.save(onnx.helper.make_model(graph), run / "model.onnx")
    check_out(run, run / "model.onnx")  # the export's own check of -o lets it through, as a new file
    check_out(run, run / "new.onnx")
