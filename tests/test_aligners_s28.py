"""``s2a-train ppg`` on alignments written by the aligners people use: Montreal Forced Aligner's IPA
phone set (``english_mfa``) in the UTF-16 TextGrids Praat writes for non-ASCII labels, long and short
format; MFA 1.x's ``<speaker> - phones`` tiers; Gentle's JSON (word-position suffixes, phone durations
from each word's start, words not found in the audio). The real LibriVox sample's own alignment,
rewritten in each format, must give the frame labels the original gives."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here
from dataset_helpers import speech_like

from capture.errors import InputError
from capture.textgrid import TextGrid, Tier, format_textgrid, interval_tier, read_textgrid, write_textgrid
from dataset.phones import ARPABET, FOLDED, phone_index
from train.alignments import UNKNOWN, find_alignments, frame_labels

LIBRIVOX = "speech/pocketsphinx-testdata-librivox"

# english_mfa's phones (MFA's english-to-mandarin mapping and mfa_timit_mapping.yaml list them) and the
# ARPAbet phone of the same articulation
MFA_ENGLISH = {
    "R": "ɹ", "AE": "æ", "CH": "tʃ", "JH": "dʒ", "ER": "ɚ ɝ", "AH": "ə ɐ ʌ", "AA": "ɑ ɑː ɒ ɒː",
    "AO": "ɔ", "EH": "ɛ ɛː", "IH": "ɪ", "IY": "i iː", "UH": "ʊ", "UW": "u uː ʉ ʉː", "T": "t tʰ tʷ tʲ ɾ",
    "SIL": "ʔ", "L": "l ɫ ɫ̩ ʎ", "M": "m m̩ mʲ ɱ", "N": "n n̩ ɲ", "NG": "ŋ", "TH": "θ t̪", "DH": "ð d̪",
    "SH": "ʃ", "ZH": "ʒ", "Y": "j", "W": "w", "AY": "aj", "AW": "aw", "EY": "ej", "OW": "ow", "OY": "ɔj",
    "P": "p pʰ pʲ pʷ", "K": "k kʰ kʷ c cʰ cʷ", "G": "ɡ ɡʷ ɟ ɟʷ", "HH": "h ç", "B": "b bʲ", "D": "d dʲ",
    "F": "f fʲ", "V": "v vʲ", "S": "s", "Z": "z",
}  # fmt: skip

# an english_mfa transcription of each ARPAbet phone (palatal before front vowels, aspirated before a
# vowel), to rewrite an ARPAbet alignment as MFA would have written it
_IPA = dict(
    AA="ɑː", AE="æ", AH="ɐ", AO="ɔ", AW="aw", AY="aj", B="b", CH="tʃ", D="d", DH="ð", EH="ɛ", ER="ɚ",
    EY="ej", F="f", G="ɡ", HH="h", IH="ɪ", IY="iː", JH="dʒ", K="k", L="ɫ", M="m", N="n", NG="ŋ", OW="ow",
    OY="ɔj", P="p", R="ɹ", S="s", SH="ʃ", T="t", TH="θ", UH="ʊ", UW="ʉː", V="v", W="w", Y="j", Z="z",
    ZH="ʒ", SIL="",
)  # fmt: skip
_PALATAL = dict(K="c", G="ɟ", L="ʎ", N="ɲ", HH="ç")
_FRONT = {"IY", "IH", "EY", "EH", "AE"}


def _as_mfa(phones: list[str]) -> list[str]:
    out = []
    for p, after in zip(phones, [*phones[1:], "SIL"]):
        ipa = _PALATAL[p] if p in _PALATAL and after in _FRONT else _IPA[p]
        out.append(ipa + "ʰ" if p in ("P", "T", "K") and after in _FRONT | {"AA", "AH", "OW"} else ipa)
    return out


def _librivox(samples: Path, folder: Path, write) -> list[np.ndarray]:
    """The LibriVox sample's audio in ``folder`` with ``write(folder, stem, utterance)`` alignments;
    the frame labels of the original alignment JSON."""
    source = samples / LIBRIVOX
    data = json.loads((source / "alignments_pocketsphinx.json").read_text())
    folder.mkdir()
    expected = []
    for (wav, segs), (stem, utt) in zip(find_alignments([source]), data.items()):
        assert wav.stem == stem
        shutil.copy(wav, folder / wav.name)
        write(folder, stem, utt)
        expected.append(frame_labels(segs, 400, 0.02))
    return expected


def _labels(folder: Path) -> tuple[list[np.ndarray], list[str]]:
    warnings: list[str] = []
    return [frame_labels(segs, 400, 0.02) for _, segs in find_alignments([folder], warnings)], warnings


def _mfa_grid(utt: dict) -> TextGrid:
    phones = [p for w in utt["words"] for p in w["phones"]]
    labels = _as_mfa([p["phone"] for p in phones])
    tier = interval_tier("phones", [(p["start"], p["end"], x) for p, x in zip(phones, labels)], 0.0, 8.0)
    return TextGrid(0.0, 8.0, [tier])


def _short_format(tg: TextGrid) -> str:
    """Praat's short text format: the long format's values alone, one a line."""
    head = ['File type = "ooTextFile"', 'Object class = "TextGrid"', "", "0", str(tg.xmax), "<exists>", "1"]
    [tier] = tg.tiers
    body = ['"IntervalTier"', f'"{tier.name}"', "0", str(tier.xmax), str(len(tier.intervals))]
    for iv in tier.intervals:
        body += [repr(iv.xmin), repr(iv.xmax), f'"{iv.text}"']
    return "\n".join(head + body) + "\n"


def test_english_mfa_ipa_phones_map_onto_the_39_by_articulation():
    for arpa, ipa in MFA_ENGLISH.items():
        assert [ARPABET[phone_index(x)] for x in ipa.split()] == [arpa] * len(ipa.split()), arpa
    # combining marks written decomposed or composed alike; ARPAbet first where a label reads as both
    assert phone_index("ɫ\u0329") == phone_index("ɫ̩") == ARPABET.index("L")
    assert [ARPABET[phone_index(x)] for x in ("b", "aw", "y", "ow")] == ["B", "AW", "Y", "OW"]
    assert phone_index("ʘ") is None and phone_index("spn") is None


def test_arpabet_timit_labels_keep_their_phones():
    """Every label the ARPAbet reading knew keeps its phone: stress digits, any case, TIMIT folds."""
    for i, p in enumerate(ARPABET):
        for label in (p, p.lower(), p + "0", p.lower() + "1", f" {p}2 "):
            assert phone_index(label) == i, label
    for timit, p in FOLDED.items():
        assert phone_index(timit.lower()) == ARPABET.index(p)


@pytest.mark.parametrize("form", ["long UTF-16", "short UTF-16", "long UTF-8"])
def test_mfa_ipa_textgrids_label_real_speech_as_its_arpabet_alignment(samples, tmp_path, form):
    """The LibriVox alignment rewritten in english_mfa's phones, as Praat (UTF-16 big-endian with its
    byte-order mark, CRLF) or MFA (UTF-8) writes it: the same frame labels as the ARPAbet original,
    and no label outside the phone set (the old reader left 152 of 333 phones as silence)."""

    def write(folder, stem, utt):
        tg, path = _mfa_grid(utt), folder / f"{stem}.TextGrid"
        if form == "long UTF-8":
            write_textgrid(tg, path)
        else:
            text = format_textgrid(tg) if form == "long UTF-16" else _short_format(tg)
            path.write_bytes("\ufeff".encode("utf-16-be") + text.replace("\n", "\r\n").encode("utf-16-be"))

    expected = _librivox(samples, tmp_path / "mfa", write)
    labels, warnings = _labels(tmp_path / "mfa")
    assert len(labels) == 5 and all(np.array_equal(a, b) for a, b in zip(labels, expected))
    assert warnings == []
    proc = run_here("train", "ppg", "--data", tmp_path / "mfa", "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 0 and "outside ARPAbet" not in proc.stderr, proc.stderr


def _wav(path: Path, seconds: float = 2.0) -> None:
    sf.write(path, speech_like(seconds, np.random.default_rng(0))[0], 16000)


def test_mfa_speaker_tiers_of_a_conversation_are_read_together(tmp_path):
    """MFA 1.x names the tiers of a file with several speakers ``<speaker> - phones``; each speaker's
    empty intervals span the other's speech. Both speakers' phones label the audio."""
    _wav(tmp_path / "talk.wav")
    tiers = [
        interval_tier("anna - words", [(0.2, 0.6, "hi")], 0.0, 2.0),
        interval_tier("anna - phones", [(0.2, 0.4, "h"), (0.4, 0.6, "aj")], 0.0, 2.0),
        interval_tier("ben - words", [(1.0, 1.5, "yes")], 0.0, 2.0),
        interval_tier("ben - phones", [(1.0, 1.1, "j"), (1.1, 1.3, "ɛ"), (1.3, 1.5, "s")], 0.0, 2.0),
    ]
    write_textgrid(TextGrid(0.0, 2.0, tiers), tmp_path / "talk.TextGrid")
    [labels], warnings = _labels(tmp_path)
    assert warnings == []
    assert [ARPABET[labels[k]] for k in (5, 15, 25, 40, 52, 60, 70, 80)] == [
        "SIL", "HH", "AY", "SIL", "Y", "EH", "S", "SIL"
    ]  # fmt: skip
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 0, proc.stderr
    # two speakers talking at once cannot both label a frame: those phones are left out, said
    # (tests/test_review_aligners_s28.py)


def test_a_single_mfa_speaker_tier_reads_as_phones(tmp_path):
    _wav(tmp_path / "utt.wav")
    tier = interval_tier("s1 - phones", [(0.3, 0.6, "AA1"), (0.6, 0.9, "S")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), tmp_path / "utt.TextGrid")
    assert read_textgrid(tmp_path / "utt.TextGrid").speaker_tiers("phones") == [tier]
    [labels], _ = _labels(tmp_path)
    assert (ARPABET[labels[20]], ARPABET[labels[40]]) == ("AA", "S")


def _gentle_word(word: str, start: float, phones: list[tuple[str, float]]) -> dict:
    """A word as Gentle writes it: phones with a word-position suffix and a duration."""
    end = start + sum(d for _, d in phones)
    return {
        "alignedWord": word,
        "case": "success",
        "start": start,
        "end": end,
        "startOffset": 0,
        "endOffset": len(word),
        "word": word,
        "phones": [{"phone": p, "duration": d} for p, d in phones],
    }


def test_gentle_json_beside_its_audio(tmp_path):
    """Gentle's JSON: phones follow each other from the word's start; ``oov_S`` (a word outside its
    dictionary) is speech without a phone: unknown; words not found in the audio have no time, the
    stretch between the found words around them is unknown, said in one warning
    (tests/test_ppgignore_s28.py)."""
    _wav(tmp_path / "talk.wav")
    words = [
        _gentle_word("the", 0.2, [("dh_B", 0.1), ("ah_E", 0.2)]),
        {"case": "not-found-in-audio", "startOffset": 4, "endOffset": 9, "word": "quick"},
        _gentle_word("<unk>", 0.6, [("oov_S", 0.3)]),
        _gentle_word("a", 1.0, [("ah_S", 0.2)]),
    ]
    doc = {"transcript": "the quick fox a", "words": words}
    (tmp_path / "talk.json").write_text(json.dumps(doc, indent=4, sort_keys=True))
    [labels], warnings = _labels(tmp_path)
    named = ["?" if labels[k] == UNKNOWN else ARPABET[labels[k]] for k in (5, 12, 20, 27, 35, 52, 70)]
    assert named == ["SIL", "DH", "AH", "?", "?", "AH", "SIL"]
    assert warnings == [
        f"{tmp_path / 'talk.json'}: 1 of 4 words have no time (Gentle did not find them in the audio): "
        "their stretch of audio is unknown, left out of training"
    ]
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 0 and "1 of 4 words have no time" in proc.stderr, proc.stderr
    assert "outside ARPAbet" not in proc.stderr


def test_gentle_json_of_real_speech_labels_it_as_its_alignment(samples, tmp_path):
    """The LibriVox alignment as Gentle would write it (10 ms durations, no silence phones): the
    original's frame labels."""

    def write(folder, stem, utt):
        words = []
        for w in utt["words"]:
            n = len(w["phones"])
            where = ["S"] if n == 1 else ["B", *"I" * (n - 2), "E"]
            phones = [
                (f"{p['phone'].lower()}_{k}", round(p["end"] - p["start"], 2))
                for p, k in zip(w["phones"], where)
            ]
            if w["word"] != "<sil>":
                words.append(_gentle_word(w["word"], w["phones"][0]["start"], phones))
        (folder / f"{stem}.json").write_text(json.dumps({"transcript": utt["text"], "words": words}))

    expected = _librivox(samples, tmp_path / "gentle", write)
    labels, warnings = _labels(tmp_path / "gentle")
    assert warnings == [] and all(np.array_equal(a, b) for a, b in zip(labels, expected))


@pytest.mark.parametrize(
    "word, message",
    [
        ({"case": "success", "start": 0.1, "phones": [{"phone": "aa_S", "duration": "x"}]}, "word 0 phone 0"),
        ({"case": "success", "start": None, "phones": []}, "word 0: 'start' must be a finite number"),
        ({"case": "success", "start": 0.1}, "word 0: 'phones' must be a list"),
        ({"case": "success", "start": 0.1, "phones": [{"duration": 0.1}]}, "expected an object with phone"),
    ],
)
def test_damaged_gentle_json_is_one_line_error(tmp_path, word, message):
    _wav(tmp_path / "utt.wav")
    (tmp_path / "utt.json").write_text(json.dumps({"transcript": "a", "words": [word]}))
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"s2a-train: error: {tmp_path / 'utt.json'}: ") and message in proc.stderr


def test_gentle_json_without_its_audio_is_one_line_error(tmp_path):
    doc = {"transcript": "a", "words": [_gentle_word("a", 0.1, [("ah_S", 0.2)])]}
    (tmp_path / "utt.json").write_text(json.dumps(doc))
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "no audio file (.wav, .flac) with the same name" in proc.stderr


def test_tier_lookup_prefers_the_plain_phones_tier(tmp_path):
    tg = TextGrid(
        0.0, 1.0, [Tier("a - phones", 0.0, 1.0), Tier("phones", 0.0, 1.0), Tier("b - phones", 0.0, 1.0)]
    )
    assert [t.name for t in tg.speaker_tiers("phones")] == ["phones"]
    with pytest.raises(InputError, match=r"TextGrid has no tier 'words' \(tiers: \['a - phones', 'phones'"):
        tg.speaker_tiers("words")
