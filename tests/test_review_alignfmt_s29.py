"""Review of ``s2a-train ppg``'s new alignment formats (Kaldi CTM, MFA JSON/CSV, WebMAUS MAU tier, BAS
Partitur) in whole corpora: a JSON or ``.par`` file that is no alignment never fails the run, an old BAS
Partitur in Latin-1 is read, files of a format not read are said in one line per format, English SAMPA's
DRESS vowel ``e`` is EH, and a wrong time in MFA's JSON or CSV is named by its entry or line."""

from __future__ import annotations

import json

import numpy as np
import soundfile as sf
from conftest import run_here
from dataset_helpers import speech_like
from test_aligners_s28 import _labels

from capture.textgrid import TextGrid, interval_tier, write_textgrid
from dataset.phones import ARPABET


def _audio(path, seconds=2.0):
    sf.write(path, speech_like(seconds, np.random.default_rng(0))[0], 16000)


def _phones_at(labels, frames):
    return [ARPABET[labels[k]] for k in frames]


def _mfa_json(path, entries):
    tiers = {"phones": {"type": "interval", "entries": entries}}
    path.write_text(json.dumps({"start": 0, "end": 2.0, "tiers": tiers}, ensure_ascii=False))


def test_json_with_a_tiers_field_that_is_not_mfas_is_passed_over(tmp_path):
    """A settings file ``{"tiers": {...}}`` beside an MFA JSON: passed over as before, not taken for MFA's
    (was: "settings.json: no audio file with the same name", the corpus refused)."""
    _audio(tmp_path / "u.wav")
    _mfa_json(tmp_path / "u.json", [[0.2, 0.6, "ɑː"], [0.6, 0.9, "s"]])
    (tmp_path / "settings.json").write_text(json.dumps({"tiers": {"gold": 3, "silver": [1, 2]}}))
    (tmp_path / "empty.json").write_text(json.dumps({"tiers": {}}))
    [labels], warnings = _labels(tmp_path)
    assert warnings == [] and _phones_at(labels, (5, 20, 35, 60)) == ["SIL", "AA", "S", "SIL"]


def test_a_par_file_that_is_not_a_partitur_is_said_and_an_old_latin1_partitur_read(tmp_path):
    """A Parchive volume named ``.par`` beside the corpus: skipped with one line (was: "holds NUL bytes",
    the corpus refused); a BAS Partitur whose ORT words are Latin-1, as older BAS corpora write them: its
    ASCII MAU lines read (was: "not UTF-8 text")."""
    _audio(tmp_path / "u.wav")
    header = "LHD: Partitur 1.3\nSAM: 16000\nORT: 0 M\xfcller\nLBD:\n"
    mau = "MAU: 0 3199 -1 <p:>\nMAU: 3200 6399 0 m\nMAU: 9600 4799 0 V\n"
    (tmp_path / "u.par").write_bytes((header + mau).encode("latin-1"))
    (tmp_path / "backup.par").write_bytes(b"PAR\x00\x01\x02\xff\xfe" * 64)
    [labels], warnings = _labels(tmp_path)
    assert _phones_at(labels, (5, 15, 35, 50)) == ["SIL", "M", "AH", "SIL"]
    assert warnings == [
        f"{tmp_path / 'backup.par'}: no MAU tier (a BAS Partitur's phone segmentation): skipped"
    ]


def test_a_mau_line_with_digits_int_cannot_read_is_one_line_error(tmp_path):
    """``²`` passes ``str.isdigit`` but not ``int``: one line naming the line (was: a ValueError)."""
    _audio(tmp_path / "u.wav")
    (tmp_path / "u.par").write_text("SAM: 16000\nMAU: \u00b2 100 0 m\n", encoding="utf-8")
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert f"{tmp_path / 'u.par'}:2: expected 'MAU: <begin sample>" in proc.stderr


def test_files_of_a_format_not_read_are_said_in_one_line_per_format(tmp_path):
    """TIMIT's .phn and ELAN's .eaf beside a TextGrid corpus: one line per format, with the count (was: a
    line per file, 6,300 for TIMIT)."""
    _audio(tmp_path / "a.wav")
    tier = interval_tier("phones", [(0.2, 0.6, "AA1"), (0.6, 0.9, "S")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), tmp_path / "a.TextGrid")
    for stem in ("a", "b", "c"):
        (tmp_path / f"{stem}.phn").write_text("0 3200 h#\n")
    for stem in ("a", "b"):
        (tmp_path / f"{stem}.eaf").write_text("<ANNOTATION_DOCUMENT/>\n")
    labels, warnings = _labels(tmp_path)
    assert len(labels) == 1 and len(warnings) == 2, warnings
    eaf, phn = sorted(warnings)
    assert phn.startswith(f"{tmp_path / 'a.phn'} and 2 more: TIMIT .phn alignments are not read (")
    assert eaf.startswith(f"{tmp_path / 'a.eaf'} and 1 more: ELAN .eaf alignments are not read (")


def test_webmaus_british_sampa_dress_vowel_is_eh(tmp_path):
    """English SAMPA (eng-GB) writes "bed" ``b e d`` and "bade" ``b eI d``: EH and EY (was: both EY)."""
    _audio(tmp_path / "u.wav")
    segs = [
        (0.2, 0.3, "b"),
        (0.3, 0.5, "e"),
        (0.5, 0.6, "d"),
        (1.0, 1.1, "b"),
        (1.1, 1.3, "eI"),
        (1.3, 1.4, "d"),
    ]
    mau = interval_tier("MAU", [(0.0, 0.2, "<p:>"), *segs, (1.4, 2.0, "<p:>")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [mau]), tmp_path / "u.TextGrid")
    [labels], warnings = _labels(tmp_path)
    assert warnings == [] and _phones_at(labels, (12, 20, 27, 52, 60, 67)) == ["B", "EH", "D", "B", "EY", "D"]


def test_wrong_times_in_mfa_json_and_csv_name_their_entry_and_line(tmp_path):
    """Messages name the JSON entry and the CSV line, not an interval of the grid built from them with its
    gaps filled (was: "tier 'phones' interval 3 (0.1-2.0 s) overlaps ... interval 1" for one entry
    ending before it starts)."""
    _audio(tmp_path / "u.wav")
    _mfa_json(tmp_path / "u.json", [[0.5, 0.1, "s"]])
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "u.json: tier 'phones' entry 0 ends before it starts (0.5 > 0.1 s)" in proc.stderr
    (tmp_path / "u.json").unlink()
    rows = "Begin,End,Label,Type,Speaker\n0.1,0.5,AA1,phones,s\n0.4,0.6,S,phones,s\n"
    (tmp_path / "u.csv").write_text(rows)
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "u.csv: line 3 (0.4-0.6 s) overlaps line 2 (to 0.5 s)" in proc.stderr


def test_a_ctm_of_words_beside_a_textgrid_corpus_is_skipped_said(tmp_path):
    """An ASR's word CTM sorting before the TextGrids: skipped with one line, the TextGrids' phones train
    (was: the CTM's words claimed the audio, every label unknown, "no phone frames in the alignments")."""
    _audio(tmp_path / "u.wav")
    tier = interval_tier("phones", [(0.2, 0.6, "AA1"), (0.6, 0.9, "S")], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), tmp_path / "u.TextGrid")
    (tmp_path / "asr.ctm").write_text("u 1 0.20 0.40 hello 0.9\nu 1 0.60 0.30 world 0.8\nu 1 1.0 0.2 a 0.7\n")
    [labels], warnings = _labels(tmp_path)
    assert _phones_at(labels, (5, 20, 35, 60)) == ["SIL", "AA", "S", "SIL"]
    assert warnings == [
        f"{tmp_path / 'asr.ctm'}: most labels are not phones (e.g. 'hello', 'world'): a CTM of words? skipped"
    ]
