"""A damaged ``.npz`` (a take's frames.npz, a paired weights file) is one error and leaves no file open:
NumPy's own open of a path kept the file when the archive started like a zip and was cut (a batch of
thousands of such takes ran out of descriptors, and each leak was a ResourceWarning on the user's stderr)."""

from __future__ import annotations

import gc
import shutil
import warnings

import numpy as np
import pytest
from dataset_helpers import make_aligned_take

from capture import InputError, read_take, write_take
from capture.paired import read_matrix


def _unclosed(call) -> list[str]:
    """The ResourceWarnings for files ``call`` left open (it must raise InputError)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(InputError):
            call()
        gc.collect()
    return [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)]


@pytest.mark.parametrize("damage", [b"PK\x03\x04cut short", b"PK\x05\x06" + bytes(18)])
def test_a_damaged_frames_npz_leaves_no_file_open(tmp_path, damage):
    take = write_take(make_aligned_take("t", 1.0), tmp_path)
    (take / "frames.npz").write_bytes(damage)
    assert _unclosed(lambda: read_take(take)) == []


def test_a_damaged_weights_npz_leaves_no_file_open(tmp_path):
    good = tmp_path / "good.npz"
    np.savez(good, weights=np.zeros((10, 3), np.float32))
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:60])
    assert _unclosed(lambda: read_matrix(cut)) == []
    shutil.copy(good, tmp_path / "again.npz")
    assert read_matrix(tmp_path / "again.npz")[0].shape == (10, 3)
