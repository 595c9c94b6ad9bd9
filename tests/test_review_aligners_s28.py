"""Review of ``s2a-train ppg`` reading the aligners people use: every phone of MFA's English IPA
dictionaries (v3.1.0: ``english_mfa``, ``english_uk_mfa``, ``english_india_mfa``, ``english_nigeria_mfa``)
maps onto the 39; MFA speaker tiers of a conversation where the speakers talk over each other train,
without those phones; JSON with a ``words`` list that is not Gentle's (a speech-to-text transcript beside
its audio) is passed over as before, never failing the corpus."""

from __future__ import annotations

import json
import unicodedata
from pathlib import Path

import numpy as np
import soundfile as sf
from conftest import run_here
from dataset_helpers import speech_like

from capture.textgrid import Interval, TextGrid, Tier, interval_tier, write_textgrid
from dataset.phones import ARPABET, phone_index
from train.alignments import UNKNOWN, find_alignments, frame_labels

# the phones each dictionary's meta.json lists (mfa-models, dictionary/english/*/v3.1.0/meta.json)
MFA_V3_PHONES = {
    "english_mfa": "a aj aw aː b bʲ c cʰ cʷ d dʒ dʲ d̪ e ej eː f fʲ h i iː j k kp kʰ kʷ l m mʲ m̩ n o ow oː p "
    "pʰ pʲ pʷ s t tʃ tʰ tʲ tʷ t̪ u uː v vʲ w z æ ç ð ŋ ɐ ɑ ɑː ɒ ɒː ɔ ɔj ɖ ə əw ɚ ɛ ɛː ɜ ɜː ɝ ɟ ɟʷ ɡ ɡʷ ɪ "
    "ɫ ɲ ɹ ɾ ʃ ʈ ʈʲ ʈʷ ʉ ʉː ʊ ʋ ʎ ʒ θ",
    "english_uk_mfa": "a aj aw b bʲ c cʰ cʷ d dʒ dʲ d̪ e ej f fʲ h i iː j k kʰ kʷ l m mʲ m̩ n n̩ p pʰ pʲ pʷ "
    "s t tʃ tʰ tʲ tʷ t̪ v vʲ vʷ w z ç ð ŋ ɐ ɑ ɑː ɒ ɒː ɔj ə əw ɛ ɛː ɜ ɜː ɟ ɟʷ ɡ ɡʷ ɪ ɫ ɫ̩ ɲ ɹ ʃ ʉ ʉː ʊ ʎ "
    "ʒ ʔ θ",
    "english_india_mfa": "a aj aw aː b bʲ c cʷ dʒ d̪ eː f fʲ h i iː j k kʷ l m mʲ n oː p pʲ pʷ s tʃ t̪ w z ç "
    "ŋ ɑ ɑː ɒ ɒː ɔj ɖ ə ɛ ɛː ɜ ɜː ɟ ɟʷ ɡ ɡʷ ɪ ɱ ɲ ɹ ɾ ʃ ʈ ʈʲ ʈʷ ʉ ʉː ʊ ʋ ʎ ʒ ʔ",
    "english_nigeria_mfa": "a aj aw aː b bʲ c cʰ cʷ d dʒ dʲ d̪ e f fʲ h i iː j k kp kʰ kʷ l m mʲ n o p pʰ "
    "pʲ s t tʃ tʰ tʲ tʷ t̪ u uː v vʲ w z ç ð ŋ ɔ ɔj ɛ ɛː ɜ ɜː ɟ ɟʷ ɡ ɡb ɡʷ ɫ ɱ ɲ ɹ ʃ ʊ ʎ θ",
}


def _wav(path: Path, seconds: float = 2.0) -> None:
    sf.write(path, speech_like(seconds, np.random.default_rng(0))[0], 16000)


def _train(folder: Path, out: Path):
    proc = run_here("train", "ppg", "--data", folder, "-o", out, "--steps", "1", "--json")
    return proc, (json.loads(proc.stdout.splitlines()[-1]) if proc.returncode == 0 else None)


def test_every_phone_of_mfas_english_dictionaries_maps_onto_the_39():
    """British GOAT ``əw`` (every "go", "no", "so" of english_uk_mfa), Indian retroflex ``ʈ ɖ`` and
    ``ʋ``, Nigerian labial-velar ``kp ɡb`` were outside the table: silence in training."""
    for name, phones in MFA_V3_PHONES.items():
        assert [p for p in phones.split() if phone_index(p) is None] == [], name
    mapped = {p: ARPABET[phone_index(p)] for p in "əw ʈ ʈʷ ɖ ʋ kp ɡb".split()}
    assert mapped == {"əw": "OW", "ʈ": "T", "ʈʷ": "T", "ɖ": "D", "ʋ": "V", "kp": "P", "ɡb": "B"}
    # a label as Praat or a script may write it, decomposed: ç (c + cedilla) stays HH, not K
    assert ARPABET[phone_index(unicodedata.normalize("NFD", "ç"))] == "HH"


def test_british_mfa_textgrid_trains_without_labels_outside_the_phone_set(tmp_path):
    _wav(tmp_path / "go.wav")
    tier = interval_tier(
        "phones", [(0.2, 0.4, "ɡ"), (0.4, 0.8, "əw"), (0.8, 1.0, "h"), (1.0, 1.4, "əw")], 0, 2
    )
    write_textgrid(TextGrid(0.0, 2.0, [tier]), tmp_path / "go.TextGrid")
    proc, summary = _train(tmp_path, tmp_path / "p.pt")
    assert proc.returncode == 0, proc.stderr
    assert not [w for w in summary["warnings"] if "outside" in w], summary["warnings"]
    [(_, segs)] = find_alignments([tmp_path])
    assert ARPABET[frame_labels(segs, 100, 0.02)[30]] == "OW"


def test_speakers_talking_over_each_other_leave_out_those_phones(tmp_path):
    """MFA aligns each speaker of a conversation alone: crosstalk gives overlapping phones on two
    speaker tiers. Those frames have no one phone: unknown, left out of training (not silence); the
    rest of the conversation (and the corpus) trains, said in one warning naming the file and the first
    overlapping phone."""
    _wav(tmp_path / "talk.wav")
    tiers = [
        interval_tier("anna - phones", [(0.2, 0.4, "h"), (0.4, 0.6, "aj"), (0.6, 0.8, "n")], 0.0, 2.0),
        interval_tier("ben - phones", [(0.7, 0.9, "j"), (1.1, 1.3, "ɛ"), (1.3, 1.5, "s")], 0.0, 2.0),
    ]
    write_textgrid(TextGrid(0.0, 2.0, tiers), tmp_path / "talk.TextGrid")
    proc, summary = _train(tmp_path, tmp_path / "p.pt")
    assert proc.returncode == 0, proc.stderr
    assert (
        f"{tmp_path / 'talk.TextGrid'}: 2 phones overlap another speaker's (the first: tier 'anna - phones' "
        "interval 4): their stretch of audio is unknown, left out of training"
    ) in summary["warnings"]
    [(_, segs)] = find_alignments([tmp_path])
    labels = ["?" if x == UNKNOWN else ARPABET[x] for x in frame_labels(segs, 100, 0.02)]
    assert [labels[k] for k in (15, 25, 35, 40, 45, 60, 70)] == ["HH", "AY", "?", "?", "SIL", "EH", "S"]


def test_an_overlap_inside_one_speakers_tier_is_still_refused(tmp_path):
    _wav(tmp_path / "talk.wav")
    ben = [Interval(0.0, 1.0, ""), Interval(1.0, 1.5, "S"), Interval(1.2, 1.6, "T"), Interval(1.6, 2.0, "")]
    tiers = [
        interval_tier("anna - phones", [(0.2, 0.6, "AA")], 0.0, 2.0),
        Tier("ben - phones", 0.0, 2.0, ben),
    ]
    write_textgrid(TextGrid(0.0, 2.0, tiers), tmp_path / "talk.TextGrid")
    proc, _ = _train(tmp_path, tmp_path / "p.pt")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "tier 'ben - phones' interval" in proc.stderr and "overlaps" in proc.stderr


def test_json_with_words_that_are_not_gentles_is_passed_over(tmp_path):
    """A speech-to-text transcript beside its audio (words with times in ms, no ``case``, no phones)
    and an empty ``words`` list without audio are no alignments: passed over, as before Gentle was
    read, while the corpus's TextGrid trains."""
    _wav(tmp_path / "good.wav")
    tier = interval_tier("phones", [(0.2, 0.6, "AA1"), (0.6, 0.9, "S")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), tmp_path / "good.TextGrid")
    _wav(tmp_path / "call.wav")
    transcript = {"text": "hello", "words": [{"text": "hello", "start": 120, "end": 480, "confidence": 0.9}]}
    (tmp_path / "call.json").write_text(json.dumps(transcript))
    (tmp_path / "notes.json").write_text(json.dumps({"title": "session", "words": []}))
    proc, summary = _train(tmp_path, tmp_path / "p.pt")
    assert proc.returncode == 0, proc.stderr
    assert summary["warnings"] == [], summary["warnings"]
    assert [a.name for a, _ in find_alignments([tmp_path])] == ["good.wav"]
