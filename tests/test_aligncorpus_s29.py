"""``s2a-train ppg`` on whole alignment corpora: an utterance aligned in several formats is read from the
preferred one whatever the files' names, said once per pair of formats; MFA's JSON/CSV phones snapped over
the last phone are mended as in its TextGrids; a CSV that cannot be read is passed over with a line."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from conftest import run_here
from test_aligners_s28 import _labels
from test_review_alignfmt_s29 import _audio, _mfa_json, _phones_at

from capture.textgrid import TextGrid, interval_tier, write_textgrid


def _grid(path, phones=("AA1", "S")):
    tier = interval_tier("phones", [(0.2, 0.6, phones[0]), (0.6, 0.9, phones[1])], 0.0, 2.0)
    write_textgrid(TextGrid(0.0, 2.0, [tier]), path)


def test_an_utterance_aligned_in_several_formats_is_read_from_its_textgrid_said_once(tmp_path):
    """MFA's TextGrids beside its JSON and CSV of other phones, a lowercase ``.textgrid``, and a CTM sorting
    before the TextGrids: every utterance is its TextGrid's, one line per pair of formats (was: the first
    file in case-sensitive path order, ``all.ctm`` and ``b.csv`` won, a line per utterance)."""
    for stem in "abcd":
        _audio(tmp_path / f"{stem}.wav")
    for name in ("a.TextGrid", "b.textgrid", "c.TextGrid", "d.TextGrid"):
        _grid(tmp_path / name)
    for stem in "ab":
        _mfa_json(tmp_path / f"{stem}.json", [[0.2, 0.6, "m"], [0.6, 0.9, "n"]])
        (tmp_path / f"{stem}.csv").write_text("Begin,End,Label,Type,Speaker\n0.2,0.9,IY1,phones,s\n")
    (tmp_path / "all.ctm").write_text("c 1 0.2 0.7 M\nd 1 0.2 0.7 M\n")
    labels, warnings = _labels(tmp_path)
    assert [_phones_at(x, (5, 20, 35, 60)) for x in labels] == [["SIL", "AA", "S", "SIL"]] * 4
    said = "2 utterances have alignments in two formats: TextGrid used, {} passed over (e.g. {})"
    assert warnings == [
        said.format("MFA CSV", tmp_path / "a.csv"),
        said.format("MFA JSON", tmp_path / "a.json"),
        said.format("Kaldi CTM", tmp_path / "all.ctm"),
    ]


def test_an_utterance_in_two_files_of_one_format_is_read_from_the_first_said_once(tmp_path):
    """Two CTMs naming the same utterances: the first in path order, one line with the count."""
    for stem in "cd":
        _audio(tmp_path / f"{stem}.wav")
    (tmp_path / "a.ctm").write_text("c 1 0.2 0.4 AA1\nc 1 0.6 0.3 S\nd 1 0.2 0.4 AA1\nd 1 0.6 0.3 S\n")
    (tmp_path / "b.ctm").write_text("c 1 0.2 0.7 M\nd 1 0.2 0.7 M\n")
    labels, warnings = _labels(tmp_path)
    assert [_phones_at(x, (5, 20, 35, 60)) for x in labels] == [["SIL", "AA", "S", "SIL"]] * 2
    assert warnings == [
        "2 utterances have two Kaldi CTM alignments: the first in path order used, the other passed over "
        f"(e.g. {tmp_path / 'b.ctm'})"
    ]


def test_mfa_json_and_csv_phones_snapped_to_the_end_over_the_last_are_mended(tmp_path):
    """MFA's JSON and CSV writers move every end within 20 ms of the file's end to it: a phone before a
    10 ms last phone then overlaps it. It ends where the last begins, as in MFA's TextGrid, with one line
    (was: "overlaps ...; phones must not overlap", the corpus refused)."""
    for stem in "ab":
        _audio(tmp_path / f"{stem}.wav")
    _mfa_json(tmp_path / "a.json", [[0.2, 0.6, "ɑː"], [0.6, 2.0, "s"], [1.99, 2.0, "t"]])
    rows = "0.2,0.6,AA1,phones,s\n0.6,2.0,S,phones,s\n1.985,2.0,T,phones,s\n0.2,2.0,word,words,s\n"
    (tmp_path / "b.csv").write_text("Begin,End,Label,Type,Speaker\n" + rows)
    labels, warnings = _labels(tmp_path)
    assert [_phones_at(x, (5, 20, 35, 60, 99)) for x in labels] == [["SIL", "AA", "S", "S", "S"]] * 2
    assert warnings == [
        f"{tmp_path / 'a.json'} and 1 more file: 2 phones end at the file's end over the last phone (MFA's "
        "JSON and CSV export moves every end within 20 ms of the end to it): they end where the next phone "
        "begins, as in MFA's TextGrids"
    ]
    # an overlap anywhere else is still refused
    _mfa_json(tmp_path / "a.json", [[0.2, 0.6, "ɑː"], [0.6, 2.0, "s"], [1.95, 2.0, "t"]])
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "2")
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert "phones must not overlap" in proc.stderr


def test_a_csv_fifo_is_passed_over_with_a_line_not_waited_on(tmp_path):
    """A FIFO named ``.csv`` given to ``--data`` beside the corpus: passed over, said (was: the run waited
    for a writer forever)."""
    _audio(tmp_path / "a.wav")
    _grid(tmp_path / "a.TextGrid")
    os.mkfifo(tmp_path / "pipe.csv")
    code = (
        "import sys; from train.alignments import find_alignments; w = []; "
        "print(len(find_alignments(sys.argv[1:], w))); print(*w, sep='\\n')"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path), str(tmp_path / "pipe.csv")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == [
        "1",
        f"{tmp_path / 'pipe.csv'}: cannot be read (not a regular file) to tell whether it is MFA's CSV: "
        "passed over",
    ]


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads any file")
def test_a_csv_without_read_permission_is_passed_over_with_a_line(tmp_path):
    """A take's CSV the user may not read, in the corpus: passed over, said (was: "Permission denied", the
    run refused)."""
    _audio(tmp_path / "a.wav")
    _grid(tmp_path / "a.TextGrid")
    (tmp_path / "take.csv").write_text("Timecode,BlendShapeCount\n")
    (tmp_path / "take.csv").chmod(0)
    labels, warnings = _labels(tmp_path)
    assert len(labels) == 1
    assert warnings == [
        f"{tmp_path / 'take.csv'}: cannot be read (Permission denied) to tell whether it is MFA's CSV: "
        "passed over"
    ]
