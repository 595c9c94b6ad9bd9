"""A TextGrid of two speakers (MFA's ``<speaker> - phones`` tiers) whose last phone ends long before the
audio: the tiers' trailing silence, which each speaker's own silences are left out with, says where the
alignment ends. It warned "the alignment ends at 1.50 s but the audio is 4.00 s long" for every such file."""

from __future__ import annotations

import json

import numpy as np
import soundfile as sf
from conftest import run_here
from dataset_helpers import speech_like

from capture.textgrid import TextGrid, interval_tier, write_textgrid


def test_two_speakers_whose_phones_end_early_are_no_mismatched_audio(tmp_path):
    sf.write(tmp_path / "talk.wav", speech_like(4.0, np.random.default_rng(0))[0], 16000)
    tiers = [
        interval_tier("anna - phones", [(0.2, 0.4, "h"), (0.4, 0.6, "aj")], 0.0, 4.0),
        interval_tier("ben - phones", [(1.0, 1.1, "j"), (1.1, 1.3, "ɛ"), (1.3, 1.5, "s")], 0.0, 4.0),
    ]
    write_textgrid(TextGrid(0.0, 4.0, tiers), tmp_path / "talk.TextGrid")
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2", "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.splitlines()[-1])
    assert not any("the alignment ends at" in w for w in summary["warnings"]), summary["warnings"]
    assert "the alignment ends at" not in proc.stderr
