"""Clipped audio is the recording's: the build says it once, with its first segment, not once per segment
align cut from it (a session of 3 recordings in 7 segments said it 7 times)."""

from __future__ import annotations

import json

from conftest import run_here
from dataset_helpers import make_aligned_take

from capture import write_take


def test_clipped_audio_is_said_once_per_recording(tmp_path):
    for n in range(1, 4):
        take = make_aligned_take(f"rec1_seg{n}", 2.0, subject="a", seed=n)
        take.meta.extra["align"] |= {
            "flags": ["clipped_audio"],
            "clipped_audio": 0.0162,
            "parent": {"id": "rec1"},
            "segment": n,
            "segment_count": 3,
        }
        write_take(take, tmp_path / "takes")
    proc = run_here("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds")
    assert proc.returncode == 0, proc.stderr
    warnings = json.loads((tmp_path / "ds" / "manifest.json").read_text())["warnings"]
    said = [w for w in warnings if "clipped at full scale" in w]
    assert said == [
        "take rec1_seg1: align found 1.62% of its audio samples clipped at full scale (its loudest "
        "sounds are distorted)"
    ], warnings
