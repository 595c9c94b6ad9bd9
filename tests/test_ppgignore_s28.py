"""``s2a-train ppg``: speech the aligner did not place (words Gentle did not find in the audio, phones
two MFA speakers say at once, MFA's ``spn``, labels outside the phone set) is UNKNOWN, left out of the
loss, the held-out accuracy and the chance level; never taught as silence. True silences stay silence,
and a fully aligned corpus trains as before."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import soundfile as sf
import torch
from conftest import run_here
from dataset_helpers import speech_like

from capture.textgrid import TextGrid, interval_tier, write_textgrid
from dataset.phones import ARPABET
from train.alignments import UNKNOWN, find_alignments, frame_labels

LIBRIVOX = "speech/pocketsphinx-testdata-librivox"


def _wav(path: Path, seconds: float = 2.0) -> None:
    sf.write(path, speech_like(seconds, np.random.default_rng(0))[0], 16000)


def _names(folder: Path, frames: list[int]) -> list[str]:
    [(_, segs)] = find_alignments([folder])
    labels = frame_labels(segs, 100, 0.02)
    return ["?" if labels[k] == UNKNOWN else ARPABET[labels[k]] for k in frames]


def _word(start: float, phones: list[tuple[str, float]]) -> dict:
    return {"case": "success", "start": start, "phones": [{"phone": p, "duration": d} for p, d in phones]}


def test_words_gentle_did_not_find_are_unknown_not_silence(tmp_path):
    """The stretch between the found words around a word Gentle did not find (from the start, or to the
    end, when it is first or last) is unknown; ``oov`` is a word heard but not phoned: unknown; a pause
    between found words stays silence."""
    _wav(tmp_path / "talk.wav")
    words = [
        {"case": "not-found-in-audio", "word": "so"},
        _word(0.2, [("dh_B", 0.1), ("ah_E", 0.2)]),
        {"case": "not-found-in-audio", "word": "quick"},
        _word(0.6, [("oov_S", 0.3)]),
        _word(1.0, [("ah_S", 0.2)]),
        _word(1.4, [("s_S", 0.2)]),
        {"case": "not-found-in-audio", "word": "now"},
    ]
    (tmp_path / "talk.json").write_text(
        json.dumps({"transcript": "so the quick fox a s now", "words": words})
    )
    frames = [5, 12, 20, 27, 35, 52, 65, 75, 90]
    assert _names(tmp_path, frames) == ["?", "DH", "AH", "?", "?", "AH", "SIL", "S", "?"]
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2", "--json")
    assert proc.returncode == 0, proc.stderr
    assert "3 of 7 words have no time" in proc.stderr and "unknown, left out of training" in proc.stderr
    assert "outside ARPAbet" not in proc.stderr


def test_crosstalk_and_spoken_noise_are_unknown(tmp_path):
    """MFA speaker tiers talking over each other: those phones are unknown; ``spn`` (spoken noise: a word
    outside MFA's dictionary) is speech, unknown; ``sil``, ``sp`` and empty intervals stay silence."""
    _wav(tmp_path / "talk.wav")
    tiers = [
        interval_tier("anna - phones", [(0.2, 0.4, "h"), (0.4, 0.6, "aj"), (0.6, 0.8, "n")], 0.0, 2.0),
        interval_tier(
            "ben - phones", [(0.7, 0.9, "j"), (0.9, 1.1, "sp"), (1.1, 1.3, "spn"), (1.3, 1.5, "s")], 0.0, 2.0
        ),
    ]
    write_textgrid(TextGrid(0.0, 2.0, tiers), tmp_path / "talk.TextGrid")
    frames = [5, 15, 25, 35, 40, 45, 50, 60, 70, 90]
    assert _names(tmp_path, frames) == ["SIL", "HH", "AY", "?", "?", "SIL", "SIL", "?", "S", "SIL"]


def _unknown_heavy_corpus(folder: Path) -> None:
    """12 s utterances: 10 s of unknown speech (a label outside the phone set), 1.2 s of one phone, then
    silence: many 4 s training crops hold unknown frames alone."""
    folder.mkdir()
    for k in range(3):
        _wav(folder / f"u{k}.wav", 12.0)
        tier = interval_tier("phones", [(0.0, 10.0, "xx"), (10.0, 11.2, "AA")], 0.0, 12.0)
        write_textgrid(TextGrid(0.0, 12.0, [tier]), folder / f"u{k}.TextGrid")


def test_unknown_frames_are_left_out_of_loss_and_accuracies(tmp_path):
    """A corpus mostly of labels outside the phone set: the chance level and accuracy count the phone
    frames alone (the old code counted the unknown ones as silence: chance 0.9, not 0.6), and crops of unknown
    frames alone teach nothing (no NaN weights)."""
    _unknown_heavy_corpus(tmp_path / "c")
    proc = run_here(
        "train", "ppg", "--data", tmp_path / "c", "-o", tmp_path / "p.pt", "--steps", "40", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.splitlines()[-1])
    assert abs(summary["majority_accuracy"] - 0.6) < 0.02  # AA: 60 of the 100 frames with a label
    assert any("outside ARPAbet: unknown, left out of training" in w for w in summary["warnings"])
    state = torch.load(tmp_path / "p.pt", weights_only=True)["state_dict"]
    assert all(bool(torch.isfinite(v).all()) for v in state.values() if v.is_floating_point())


def test_a_fully_aligned_corpus_has_no_unknown_frames(samples):
    """The LibriVox sample's alignment places every frame: no unknown label, so it trains as before (the
    loss, accuracies and chance level are those of every frame)."""
    for _, segs in find_alignments([samples / LIBRIVOX]):
        assert (frame_labels(segs, 400, 0.02) >= 0).all()
