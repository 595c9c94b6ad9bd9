"""Review mends: a checkpoint's declared sizes are those its system uses, takes below a hidden folder are
not found, .npy headers with negative dims or of version 3.0, CUDA's out-of-memory error, and the one
non-negative-integer test."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
from dataset_helpers import build_five_take_dataset, make_aligned_take
from test_train_pipeline import TINY

from capture import find_takes, write_take
from capture.command import out_of_memory
from capture.errors import InputError
from capture.numbers import is_count
from dataset.shards import decode_npy
from train.checkpoint import load_checkpoint, load_system
from train.config import resolve_config
from train.fit import fit


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    return build_five_take_dataset(tmp_path_factory.mktemp("mends"))


# 1a. only the sizes of the checkpoint's own system are compared with its weights

HUGE = 10**9  # more than any of these runs' weights


@pytest.mark.parametrize(
    "model, unrelated",
    [
        ("ridge", [f"arch.ff_dim={HUGE}", f"arch.blstm.hidden={HUGE}"]),
        ("nvp3", [f"arch.experts={HUGE}", f"arch.s2a.d_model={HUGE}", f"arch.nvp9.hidden={HUGE}"]),
    ],
)
def test_a_run_with_arch_keys_of_other_systems_loads(ds, tmp_path, model, unrelated):
    cfg = resolve_config(sets=[*TINY, f"model='{model}'", "max_steps=1", "eval_every=1", *unrelated])
    fit(ds, tmp_path / "run", cfg, say=lambda _m: None)
    _, payload = load_system(tmp_path / "run")
    assert payload["system"] == model


def test_a_size_the_system_uses_is_still_checked(ds, tmp_path):
    fit(
        ds, tmp_path / "run", resolve_config(sets=[*TINY, "model='nvp3'", "max_steps=1"]), say=lambda _m: None
    )
    payload = load_checkpoint(tmp_path / "run" / "last.pt")
    payload["config"]["arch"]["nvp3"] = {"hidden": HUGE}  # its own table
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(InputError, match=f"malformed arch.*hidden \\({HUGE}\\): more than the"):
        load_system(tmp_path / "bad.pt")


# 1b. a take under a hidden folder (align's .<id>.partial-XXXX/<id>/) is not a take of the search


def test_takes_below_a_hidden_folder_are_skipped_unless_it_is_named(tmp_path):
    take = make_aligned_take("t0", 0.5)
    shown = write_take(take, tmp_path / "aligned")
    write_take(take, tmp_path / "aligned" / ".t0.partial-abcd")  # killed before its rename
    hidden = write_take(take, tmp_path / ".hidden" / "deeper")
    assert find_takes([tmp_path]) == [shown]
    assert find_takes([tmp_path / ".hidden"]) == [hidden]


# 2a, 2d. .npy headers


def _header(shape: str) -> bytes:
    h = f"{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}"
    h += " " * ((64 - (10 + len(h) + 1) % 64) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(h).to_bytes(2, "little") + h.encode() + b"\0" * 64


@pytest.mark.parametrize("shape", ["(-1,)", "(-1, -1)", "(-2,)", "(2, -3)"])
def test_npy_negative_dims_are_refused(shape):
    with pytest.raises(InputError, match="a negative size"):
        decode_npy(_header(shape), "x.npy")


def test_npy_version_3_is_read():
    array = np.array([(1,), (2,)], dtype=[("α", "<i4")])
    buf = io.BytesIO()
    with pytest.warns(UserWarning, match="format 3.0"):
        np.save(buf, array)  # version 3.0: a UTF-8 header for the non-latin-1 field name
    assert buf.getvalue()[6:8] == b"\x03\x00"
    got = decode_npy(buf.getvalue())
    assert got.dtype == array.dtype and np.array_equal(got, array)


# 2c. CUDA's out-of-memory error


def test_cuda_out_of_memory_is_recognised():
    assert out_of_memory(torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB"))
    assert out_of_memory(RuntimeError("CUDA error: out of memory"))
    assert not out_of_memory(RuntimeError("another"))


# the one non-negative-integer test


def test_a_count_is_a_non_negative_integer_and_never_a_bool():
    assert [is_count(v) for v in (0, 3, -1, True, 1.0, None)] == [True, True, False, False, False, False]
