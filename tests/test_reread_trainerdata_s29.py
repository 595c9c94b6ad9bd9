"""Edge inputs of the Audio2Face-3D training data reader found by a maintainer's reread."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from capture.errors import InputError
from capture.trainer_data import read_a2f_shot


def _dataset(root: Path) -> Path:
    """An actor's folder with a blendshape setup of two poses, a second of audio and ``cache/skin/``."""
    for part in ("audio", "cache/skin", "bs_data"):
        (root / part).mkdir(parents=True)
    neutral = np.zeros((4, 3), np.float32)
    np.savez(
        root / "bs_data" / "bs_skin.npz",
        poseNames=np.array(["neutral", "jawOpen", "eyeBlinkLeft"]),
        neutral=neutral,
        jawOpen=np.eye(4, 3, dtype=np.float32),
        eyeBlinkLeft=np.eye(4, 3, k=1, dtype=np.float32),
    )
    sf.write(root / "audio" / "shot.wav", np.zeros(16000), 16000, subtype="PCM_16")
    return root


def test_a_npz_archive_named_npy_in_the_skin_cache_is_a_one_line_error(tmp_path):
    actor = _dataset(tmp_path / "mark")
    with open(actor / "cache" / "skin" / "shot.npy", "wb") as f:  # np.savez would add ".npz"
        np.savez(f, frames=np.zeros((30, 4, 3), np.float32))
    with pytest.raises(InputError, match="not a .npy array"):
        read_a2f_shot(actor / "cache" / "skin" / "shot.npy", fps=30.0)
