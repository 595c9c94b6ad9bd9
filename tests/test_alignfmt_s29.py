"""``s2a-train ppg`` on more aligners' output formats: Kaldi CTM phone alignments (one file for many
utterances, word-position suffixes, integer ids named by ``phones.txt``), Montreal Forced Aligner 3's
``--output_format json`` and ``csv``, WebMAUS's TextGrid ``MAU`` tier and BAS Partitur ``.par`` (SAMPA);
IPA centring diphthongs. The real LibriVox sample's own alignment, written in each format, must give the
frame labels the original gives; a file of a format not read is said, naming the formats read."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here
from dataset_helpers import speech_like
from test_aligners_s28 import _as_mfa, _labels, _librivox

from capture.textgrid import TextGrid, interval_tier, write_textgrid
from dataset.phones import ARPABET, phone_index

# an English SAMPA transcription of each ARPAbet phone, as WebMAUS writes eng-US (r-coloured ``3```, ``oU``)
SAMPA = dict(
    AA="A:", AE="{", AH="V", AO="O:", AW="aU", AY="aI", B="b", CH="tS", D="d", DH="D", EH="E", ER="3`",
    EY="eI", F="f", G="g", HH="h", IH="I", IY="i:", JH="dZ", K="k", L="l", M="m", N="n", NG="N", OW="oU",
    OY="OI", P="p", R="r\\", S="s", SH="S", T="t", TH="T", UH="U", UW="u:", V="v", W="w", Y="j", Z="z",
    ZH="Z", SIL="<p:>",
)  # fmt: skip


def _phones(utt: dict) -> list[dict]:
    return [p for w in utt["words"] for p in w["phones"]]


def _kaldi_phones(utt: dict) -> list[tuple[float, float, str]]:
    """(start, duration, phone) as Kaldi's word-position-dependent phones name them: ``DH_B AH_E``, ``AH_S``,
    silence ``SIL``."""
    out = []
    for w in utt["words"]:
        n = len(w["phones"])
        where = ["S"] if n == 1 else ["B", *"I" * (n - 2), "E"]
        for p, k in zip(w["phones"], where):
            label = "SIL" if p["phone"] == "SIL" else f"{p['phone']}_{k}"
            out.append((p["start"], p["end"] - p["start"], label))
    return out


def _ctm_line(stem: str, start: float, duration: float, phone: str) -> str:
    return f"{stem} 1 {start:.2f} {duration:.2f} {phone} 1.00\n"  # ali-to-phones --ctm-output


def _write_ctm(folder: Path, stem: str, utt: dict) -> None:
    with open(folder / "phones.ctm", "a") as f:
        f.writelines(_ctm_line(stem, *p) for p in _kaldi_phones(utt))


def _phone_table() -> dict[str, int]:
    """A Kaldi phones.txt of word-position-dependent phones: ``<eps> 0``, ``SIL 1``, ``AA_B 2``, ..."""
    names = ["<eps>", "SIL", *(f"{p}_{k}" for p in ARPABET[1:] for k in "BIES")]
    return {name: i for i, name in enumerate(names)}


def test_kaldi_ctm_of_many_utterances_labels_real_speech_as_its_alignment(samples, tmp_path):
    """One CTM of the five utterances beside their audio (word-position suffixes, confidences): the
    original's frame labels (the old reader passed the CTM over: no phone alignments found)."""
    expected = _librivox(samples, tmp_path / "kaldi", _write_ctm)
    labels, warnings = _labels(tmp_path / "kaldi")
    assert warnings == [] and len(labels) == 5
    assert all(np.array_equal(a, b) for a, b in zip(labels, expected))
    proc = run_here("train", "ppg", "--data", tmp_path / "kaldi", "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 0 and "5 utterances" in proc.stderr + proc.stdout, proc.stderr
    assert "outside ARPAbet" not in proc.stderr


def test_kaldi_ctm_of_integer_ids_is_named_by_the_phone_table_beside_it(samples, tmp_path):
    """A CTM written before ``int2sym.pl`` (integer phone ids), its audio in a folder below, an utterance
    without audio: the ids are named by ``phones.txt``, the audio found by utterance id, the utterance
    without audio said in one line; without ``phones.txt`` the CTM is skipped, said."""
    table = _phone_table()

    def write(folder, stem, utt):
        (folder / "wav").mkdir(exist_ok=True)
        (folder / f"{stem}.wav").rename(folder / "wav" / f"{stem}.wav")
        with open(folder / "phones.ctm", "a") as f:
            f.writelines(_ctm_line(stem, a, d, str(table[p])) for a, d, p in _kaldi_phones(utt))

    expected = _librivox(samples, tmp_path / "ids", write)
    ctm = tmp_path / "ids" / "phones.ctm"
    with open(ctm, "a") as f:
        f.write(_ctm_line("no-such-recording", 0.0, 0.5, str(table["SIL"])))
    (tmp_path / "ids" / "phones.txt").write_text("".join(f"{p} {i}\n" for p, i in table.items()))
    labels, warnings = _labels(tmp_path / "ids")
    assert all(np.array_equal(a, b) for a, b in zip(labels, expected)) and len(labels) == 5
    assert warnings == [
        f"{ctm}: 1 of 6 utterances have no audio file (.wav, .flac) of that name in {ctm.parent} or below "
        "(e.g. 'no-such-recording'): left out"
    ]
    (tmp_path / "ids" / "phones.txt").unlink()
    proc = run_here("train", "ppg", "--data", tmp_path / "ids", "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "the phones are Kaldi's integer ids and no phones.txt lies beside it" in proc.stderr


def test_a_ctm_of_one_utterance_beside_its_audio(tmp_path):
    """``utt.ctm`` beside ``utt.wav`` whose utterance id is not the file's name (a speaker prefix): the
    audio of the CTM's own name."""
    sf.write(tmp_path / "utt.wav", speech_like(2.0, np.random.default_rng(0))[0], 16000)
    (tmp_path / "utt.ctm").write_text(
        ";; phone alignment\nspk1-utt 1 0.00 0.30 SIL\nspk1-utt 1 0.30 0.20 HH_B\nspk1-utt 1 0.50 0.30 AY_E\n"
    )
    [labels], warnings = _labels(tmp_path)
    assert warnings == [] and [ARPABET[labels[k]] for k in (5, 20, 30, 60)] == ["SIL", "HH", "AY", "SIL"]


@pytest.mark.parametrize(
    "line, message",
    [
        ("utt 1 0.0 SIL", "expected 'utterance channel start duration phone [confidence]', found 4 fields"),
        ("utt 1 x 0.1 SIL", "the start must be a finite number of seconds, found 'x'"),
        ("utt 1 0.1 nan SIL", "the duration must be a finite number of seconds, found 'nan'"),
        ("utt 1 0.1 -0.2 SIL", "ends before it starts"),
    ],
)
def test_damaged_ctm_is_one_line_error(tmp_path, line, message):
    sf.write(tmp_path / "utt.wav", speech_like(1.0, np.random.default_rng(0))[0], 16000)
    (tmp_path / "utt.ctm").write_text(f"utt 1 0.00 0.10 SIL\n{line}\n")
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"s2a-train: error: {tmp_path / 'utt.ctm'}") and message in proc.stderr


def _mfa_json(folder: Path, stem: str, utt: dict) -> None:
    """``mfa align --output_format json`` (MFA 3): silence left out of the tiers (its default clean-up),
    english_mfa's IPA phones."""
    spoken = [p for p in _phones(utt) if p["phone"] != "SIL"]
    words = [[w["start"], w["end"], w["word"]] for w in utt["words"] if w["word"] != "<sil>"]
    phones = [[p["start"], p["end"], x] for p, x in zip(spoken, _as_mfa([p["phone"] for p in spoken]))]
    tiers = {
        "words": {"type": "interval", "entries": words},
        "phones": {"type": "interval", "entries": phones},
    }
    doc = {"start": 0, "end": utt["duration_s"], "tiers": tiers}
    (folder / f"{stem}.json").write_text(json.dumps(doc, indent=4, ensure_ascii=False), encoding="utf-8")


def _mfa_csv(folder: Path, stem: str, utt: dict) -> None:
    """``mfa align --output_format csv``: a row per word and phone (english_us_arpa: ARPAbet with stress)."""
    rows = ["Begin,End,Label,Type,Speaker"]
    rows += [
        f"{w['start']},{w['end']},{w['word']},words,reader" for w in utt["words"] if w["word"] != "<sil>"
    ]
    rows += [
        f"{p['start']},{p['end']},{p['phone']}{'1' if p['phone'][0] in 'AEIOU' else ''},phones,reader"
        for p in _phones(utt)
        if p["phone"] != "SIL"
    ]
    (folder / f"{stem}.csv").write_text("\n".join(rows) + "\n")


@pytest.mark.parametrize("write", [_mfa_json, _mfa_csv], ids=["json", "csv"])
def test_mfa_json_and_csv_label_real_speech_as_its_alignment(samples, tmp_path, write):
    """MFA 3's JSON and CSV exports beside the audio: the original's frame labels (the old reader passed
    the CSV over, and took the JSON for the toolkit's, failing the corpus: "utterance 'tiers': 'words' must
    be a list")."""
    expected = _librivox(samples, tmp_path / "mfa", write)
    labels, warnings = _labels(tmp_path / "mfa")
    assert warnings == [] and len(labels) == 5
    assert all(np.array_equal(a, b) for a, b in zip(labels, expected))


def test_mfa_json_of_two_speakers_reads_their_tiers_together(tmp_path):
    sf.write(tmp_path / "talk.wav", speech_like(2.0, np.random.default_rng(0))[0], 16000)
    tiers = {
        "anna - phones": {"type": "interval", "entries": [[0.2, 0.4, "h"], [0.4, 0.6, "aj"]]},
        "ben - phones": {"type": "interval", "entries": [[1.0, 1.2, "j"], [1.2, 1.4, "ɛ"]]},
    }
    (tmp_path / "talk.json").write_text(json.dumps({"start": 0, "end": 2.0, "tiers": tiers}))
    [labels], warnings = _labels(tmp_path)
    assert warnings == [] and [ARPABET[labels[k]] for k in (5, 15, 25, 40, 55, 65, 90)] == [
        "SIL", "HH", "AY", "SIL", "Y", "EH", "SIL"
    ]  # fmt: skip


def test_damaged_mfa_json_is_one_line_error(tmp_path):
    sf.write(tmp_path / "utt.wav", speech_like(1.0, np.random.default_rng(0))[0], 16000)
    tiers = {"phones": {"type": "interval", "entries": [[0.1, 0.2, "a"], [0.2, "end", "b"]]}}
    (tmp_path / "utt.json").write_text(json.dumps({"start": 0, "end": 1.0, "tiers": tiers}))
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "tier 'phones' entry 1: end must be a finite number of seconds" in proc.stderr


def _maus_labels(utt: dict) -> list[tuple[float, float, str]]:
    return [(p["start"], p["end"], SAMPA[p["phone"]]) for p in _phones(utt)]


def _maus_textgrid(folder: Path, stem: str, utt: dict) -> None:
    """WebMAUS's TextGrid: ORT-MAU and KAN-MAU word tiers, the MAU phone tier in SAMPA, pauses ``<p:>``."""
    end = utt["duration_s"]
    words = [(w["start"], w["end"], w["word"]) for w in utt["words"] if w["word"] != "<sil>"]
    tiers = [
        interval_tier("ORT-MAU", words, 0.0, end),
        interval_tier("KAN-MAU", words, 0.0, end),
        interval_tier("MAU", _maus_labels(utt), 0.0, end),
    ]
    write_textgrid(TextGrid(0.0, end, tiers), folder / f"{stem}.TextGrid")


def _partitur(folder: Path, stem: str, utt: dict) -> None:
    """A BAS Partitur: begin and duration in samples (a segment ends the sample before the next begins)."""
    lines = ["LHD: Partitur 1.3", "SAM: 16000", "SPN: reader", "LBD:"]
    word = -1
    for w in utt["words"]:
        word += w["word"] != "<sil>"
        for p in w["phones"]:
            a, b = round(p["start"] * 16000), round(p["end"] * 16000)
            lines.append(
                f"MAU:\t{a}\t{b - a - 1}\t{-1 if p['phone'] == 'SIL' else word}\t{SAMPA[p['phone']]}"
            )
    (folder / f"{stem}.par").write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("write", [_maus_textgrid, _partitur], ids=["textgrid", "partitur"])
def test_webmaus_sampa_labels_real_speech_as_its_alignment(samples, tmp_path, write):
    """WebMAUS's output in SAMPA (its TextGrid's MAU tier; a BAS Partitur's MAU lines): the original's frame
    labels. SAMPA's T D S Z N V are θ ð ʃ ʒ ŋ ʌ, never the ARPAbet phones of those letters (the old reader
    refused the TextGrid: no 'phones' tier; passed the Partitur over)."""
    expected = _librivox(samples, tmp_path / "maus", write)
    labels, warnings = _labels(tmp_path / "maus")
    assert warnings == [] and len(labels) == 5
    assert all(np.array_equal(a, b) for a, b in zip(labels, expected))


def test_english_sampa_maps_onto_the_39_by_articulation():
    from dataset.phones import sampa_to_ipa

    british = dict(Q="AA", V="AH", **{"@": "AH", "@U": "OW", "3:": "ER", "6": "AH", "4": "T", "5": "L"})
    for arpa, sampa in {**SAMPA, **{v: k for k, v in british.items()}}.items():
        if arpa != "SIL":
            assert ARPABET[phone_index(sampa_to_ipa(sampa))] == arpa, sampa
    for sampa, arpa in british.items():
        assert ARPABET[phone_index(sampa_to_ipa(sampa))] == arpa, sampa
    assert [ARPABET[phone_index(sampa_to_ipa(x))] for x in ("I@", "U@", "e@", "l=", "n=")] == [
        "IH", "UH", "EH", "L", "N"
    ]  # fmt: skip
    assert sampa_to_ipa("<p:>") == "<p:>" and phone_index(sampa_to_ipa("x")) is None


def test_ipa_centring_diphthongs_are_their_first_vowel():
    """NEAR, CURE, SQUARE (ɪə ʊə eə ɛə; the old table left them outside the phone set): IH UH EH. The
    tap ɾ (US flap, Indian English /r/) stays T."""
    assert [phone_index(x) for x in ("ɪə", "ʊə", "eə", "ɛə", "ɾ")] == [
        ARPABET.index(p) for p in ("IH", "UH", "EH", "EH", "T")
    ]


def test_a_file_of_a_format_not_read_is_said_naming_the_formats_read(tmp_path):
    """TIMIT's .phn beside the audio: one line naming the file and the formats read (the old reader
    passed it over without a word); the corpus's TextGrid still trains."""
    sf.write(tmp_path / "a.wav", speech_like(2.0, np.random.default_rng(0))[0], 16000)
    sf.write(tmp_path / "b.wav", speech_like(2.0, np.random.default_rng(1))[0], 16000)
    (tmp_path / "a.phn").write_text("0 3200 h#\n3200 6400 aa\n6400 32000 h#\n")
    tier = interval_tier("phones", [(0.2, 0.6, "AA1"), (0.6, 0.9, "S")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), tmp_path / "b.TextGrid")
    _, warnings = _labels(tmp_path)
    assert len(warnings) == 1 and warnings[0].startswith(
        f"{tmp_path / 'a.phn'}: TIMIT .phn alignments are not"
    )
    assert "Kaldi CTM" in warnings[0] and "WebMAUS 'MAU' tier" in warnings[0]
    (tmp_path / "b.TextGrid").unlink()
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "no phone alignments found (read: Praat TextGrids" in proc.stderr and "a.phn" in proc.stderr


def test_csv_that_is_not_mfas_is_passed_over(tmp_path, sim_take):
    """A Live Link Face take's CSV (blendshapes) is no alignment: passed over without a word, as before."""
    tier = interval_tier("phones", [(0.2, 0.6, "AA1"), (0.6, 0.9, "S")], 0.0, 2.0)
    folder = tmp_path / "take"
    folder.mkdir()
    for f in sim_take.iterdir():
        if f.suffix.lower() == ".csv":
            (folder / f.name).write_bytes(f.read_bytes())
    assert list(folder.glob("*.csv"))
    sf.write(folder / "u.wav", speech_like(2.0, np.random.default_rng(0))[0], 16000)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), folder / "u.TextGrid")
    labels, warnings = _labels(folder)
    assert len(labels) == 1 and warnings == []
