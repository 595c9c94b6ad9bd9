"""``s2a-train ppg`` on bad alignments and arguments: one-line errors naming the file and field, or
warnings (stderr and the JSON summary), never a traceback or a silently meaningless checkpoint."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch
from conftest import run_cli, run_here
from dataset_helpers import speech_like

from capture.errors import InputError
from capture.textgrid import Point, TextGrid, Tier, interval_tier, write_textgrid
from train.alignments import find_alignments
from train.ppg_train import train_ppg

PHONES = [(0.0, 0.3, ""), (0.3, 0.6, "AA1"), (0.6, 0.9, "S"), (0.9, 1.2, "")]


def _wav(path: Path, seconds: float = 1.2) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    sf.write(path, speech_like(seconds, np.random.default_rng(0))[0], 16000)
    return path


def _grid(folder: Path, stem: str, segs=PHONES, seconds: float = 1.2, suffix: str = ".TextGrid") -> Path:
    _wav(folder / f"{stem}.wav", seconds)
    end = max([b for _, b, _ in segs], default=seconds)
    path = folder / f"{stem}{suffix}"
    write_textgrid(TextGrid(0.0, end, [interval_tier("phones", segs, 0.0, end)]), path)
    return path


def _json(folder: Path, words, stem: str = "utt") -> Path:
    _wav(folder / f"{stem}.wav")
    path = folder / "align.json"
    path.write_text(json.dumps({stem: {"words": words}}))
    return path


def _phone(**fields) -> list:
    return [{"phones": [{"phone": "AA", "start": 0.1, "end": 0.5} | fields]}]


def _train(tmp_path: Path, *data: Path, **kw) -> tuple[dict, list[str]]:
    said: list[str] = []
    with contextlib.redirect_stderr(io.StringIO()) as err:  # its warnings, printed named on stderr
        summary = train_ppg(list(data), tmp_path / "p.pt", steps=1, batch_size=2, say=said.append, **kw)
    return summary, said + err.getvalue().splitlines()


def _one_line_error(proc, *parts: str) -> None:
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith("s2a-train: error: ") and "Traceback" not in proc.stderr
    for part in parts:
        assert part in proc.stderr, proc.stderr


@pytest.mark.parametrize(
    "words, message",
    [
        (_phone(start="0.1"), "word 0 phone 0: 'start' must be a finite number of seconds, found \"0.1\""),
        (_phone(start=None), "word 0 phone 0: 'start' must be a finite number of seconds, found null"),
        (_phone(phone=5), "word 0 phone 0: 'phone' must be a string, found 5"),
        ([{"phones": [{"phone": "AA", "start": 0.1}]}], "word 0 phone 0: no 'end'"),
        (["hello"], "word 0: expected an object with 'phones', found \"hello\""),
        ([{"phones": {"phone": "AA"}}], "word 0: 'phones' must be a list"),
        ([{"phones": None}], "word 0: 'phones' must be a list, found null"),
        ({"w": 1}, "'words' must be a list"),
        (_phone(start=float("nan")), "'start' must be a finite number of seconds, found NaN"),
        (_phone(end=float("inf")), "'end' must be a finite number of seconds, found Infinity"),
        (_phone(start=True), "'start' must be a finite number of seconds, found true"),
        (_phone(start=-0.1), "phone 0 starts at a negative time"),
        (_phone(start=0.6), "phone 0 ends before it starts"),
        (
            [
                {
                    "phones": [
                        {"phone": "AA", "start": 0.1, "end": 0.5},
                        {"phone": "S", "start": 0.4, "end": 0.7},
                    ]
                }
            ],
            "word 0 phone 1 (0.4-0.7 s) overlaps utterance 'utt' word 0 phone 0",
        ),
    ],
)
def test_bad_json_alignment_names_file_and_field(tmp_path, words, message):
    path = _json(tmp_path, words)
    with pytest.raises(InputError) as err:
        find_alignments([tmp_path])
    assert str(err.value).startswith(f"{path}: utterance 'utt'") and message in str(err.value)


def test_alignment_json_in_other_encodings_or_unreadable_is_never_dropped_silently(tmp_path):
    """A BOM or UTF-16 (Windows editors) is read; a truncated file, one nested too deeply and numbers
    too large for a float are named, never skipped without a word or a traceback."""
    good = json.dumps({"utt": {"words": _phone()}})
    for name, raw in (("bom", b"\xef\xbb\xbf" + good.encode()), ("u16", good.encode("utf-16"))):
        _wav(tmp_path / name / "utt.wav")
        (tmp_path / name / "align.json").write_bytes(raw)
        assert [w.name for w, _ in find_alignments([tmp_path / name])] == ["utt.wav"]
    _grid(tmp_path / "mixed", "other")
    _wav(tmp_path / "mixed" / "utt.wav")
    (tmp_path / "mixed" / "align.json").write_text(good[:-9])
    (tmp_path / "mixed" / "deep.json").write_text("[" * 100_000)
    warnings: list[str] = []
    assert [w.name for w, _ in find_alignments([tmp_path / "mixed"], warnings)] == ["other.wav"]
    assert any("align.json: not valid JSON" in w for w in warnings), warnings
    assert any("deep.json: nested too deeply" in w for w in warnings), warnings
    assert all(w.count(str(tmp_path)) == 1 for w in warnings), warnings  # the file named once
    # an integer of more digits than Python converts, and a lone unreadable file: named in the error
    (tmp_path / "huge").mkdir()
    (tmp_path / "huge" / "align.json").write_text('{"utt": {"words": ' + "1" * 5000 + "}}")
    with pytest.raises(InputError, match=r"no phone alignments found .*align.json: not readable JSON"):
        find_alignments([tmp_path / "huge"])
    path = _json(tmp_path / "big", _phone())
    path.write_text(path.read_text().replace('"end": 0.5', '"end": 1' + "0" * 400))
    with pytest.raises(InputError, match="'end' must be a finite number of seconds"):
        find_alignments([path])


def test_ppg_never_overwrites_a_file_that_is_not_a_ppg_checkpoint(tmp_path):
    _grid(tmp_path / "d", "utt")
    (tmp_path / "run").mkdir()
    best = tmp_path / "run" / "best.pt"
    torch.save({"format": "s2a-train-checkpoint", "version": 1}, best)
    before = best.read_bytes()
    proc = run_here("train", "ppg", "--data", tmp_path / "d", "-o", best, "--steps", "1")
    _one_line_error(proc, str(best), "exists and is not a PPG checkpoint")
    assert best.read_bytes() == before


def test_bad_json_is_one_line_error_on_the_command_line(tmp_path):
    """The command line as a user runs it (a subprocess); the other one-line errors here run in this
    process, without a PyTorch start-up each."""
    path = _json(tmp_path, _phone(start="0.1"))
    proc = run_cli("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt", "--steps", "1")
    _one_line_error(proc, str(path), "'start' must be a finite number")


def test_overlapping_or_negative_textgrid_intervals_are_refused(tmp_path):
    _grid(tmp_path / "a", "utt", [(0.0, 0.5, "AA"), (0.4, 0.9, "S")])
    with pytest.raises(InputError, match="interval 2 .* overlaps tier 'phones' interval 1"):
        find_alignments([tmp_path / "a"])
    g = _grid(tmp_path / "b", "utt", [(0.0, 0.5, "AA")])
    g.write_text(g.read_text().replace("xmin = 0 ", "xmin = -0.2 "))
    with pytest.raises(InputError, match="starts at a negative time"):
        find_alignments([g])


def _point_tier(folder: Path) -> Path:
    _wav(folder / "utt.wav")
    tier = Tier("phones", 0.0, 1.2, points=[Point(0.5, "AA")], kind="TextTier")
    return write_textgrid(TextGrid(0.0, 1.2, [tier]), folder / "utt.TextGrid")


@pytest.mark.parametrize(
    "make",
    [
        lambda d: _grid(d, "utt", [(0.0, 0.6, ""), (0.6, 1.2, "")]),  # all labels silence
        lambda d: _grid(d, "utt", [(0.0, 0.6, "ʘ"), (0.6, 1.2, "ǀ")]),  # clicks: not English, count as SIL
        lambda d: _grid(d, "utt", [(5.0, 6.0, "AA")]),  # past the audio's end
        lambda d: write_textgrid(
            TextGrid(0.0, 1.2, [Tier("phones", 0.0, 1.2)]), _wav(d / "utt.wav").with_suffix(".TextGrid")
        ),  # an empty tier
        _point_tier,
        lambda d: _json(d, []),
    ],
)
def test_no_phone_frames_is_an_error(tmp_path, make):
    make(tmp_path / "d")
    with pytest.raises(InputError, match="no phone frames in the alignments"):
        _train(tmp_path, tmp_path / "d")
    assert not (tmp_path / "p.pt").exists()


def test_utterance_without_phones_is_skipped_with_a_warning(tmp_path):
    _grid(tmp_path / "d", "good")
    _grid(tmp_path / "d", "empty", [(0.0, 1.2, "")])
    _point_tier(tmp_path / "d" / "points")
    _grid(tmp_path / "d", "ipa", [(0.0, 0.6, "ʘ"), (0.6, 1.2, "S")])
    proc = run_here(
        "train", "ppg", "--data", tmp_path / "d", "-o", tmp_path / "p.pt", "--steps", "1", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["utterances"] == 2  # good and ipa (which has an S)
    warnings = "\n".join(summary["warnings"])
    assert f"{tmp_path / 'd' / 'empty.wav'}: no phone frames" in warnings
    assert f"{tmp_path / 'd' / 'points' / 'utt.TextGrid'}: tier 'phones' is a point tier" in warnings
    assert "1 phone segments have labels outside ARPAbet: unknown, left out of training" in warnings
    assert "'ʘ'" in warnings
    assert all(f"warning: {w}" in proc.stderr for w in summary["warnings"])


def test_alignment_and_audio_of_different_lengths_warn(tmp_path):
    _grid(tmp_path / "long", "utt", [(0.0, 0.5, "AA"), (0.5, 500.0, "S")], seconds=1.2)
    _grid(tmp_path / "short", "utt", PHONES, seconds=3.0)
    _grid(tmp_path / "fits", "utt", PHONES, seconds=1.3)
    for name, expect in [
        ("long", "ends at 500.00 s but the audio is 1.20 s"),
        ("short", "1.20 s but the audio is 3.00"),
    ]:
        summary, said = _train(tmp_path, tmp_path / name)
        [w] = summary["warnings"]
        assert w.startswith(str(tmp_path / name / "utt.wav")) and expect in w
        assert f"s2a: warning: {w}" in said  # a library call's warnings are the toolkit's
    assert _train(tmp_path, tmp_path / "fits")[0]["warnings"] == []


def test_missing_tier_names_the_file(tmp_path):
    _wav(tmp_path / "utt.wav")
    path = write_textgrid(
        TextGrid(0.0, 1.2, [interval_tier("words", PHONES, 0.0, 1.2)]), tmp_path / "utt.TextGrid"
    )
    proc = run_here("train", "ppg", "--data", tmp_path, "-o", tmp_path / "p.pt")
    _one_line_error(proc, f"{path}: TextGrid has no tier 'phones' (tiers: ['words'])")


@pytest.mark.parametrize(
    "args, message",
    [
        (["--steps", "0"], "--steps must be at least 1 (got 0)"),
        (["--steps", "-3"], "--steps must be at least 1 (got -3)"),
        (["--seed", "-1"], "--seed must be between 0 and"),
        (["-o", "{tmp}/d"], "is a folder; -o names the checkpoint file"),
        (["-o", "{tmp}/afile/p.pt"], "afile is a file, not a folder"),
        (["-o", "/proc/p.pt"], "/proc/p.pt: cannot write the checkpoint"),
    ],
)
def test_bad_arguments_are_one_line_errors_before_training(tmp_path, args, message):
    _grid(tmp_path / "d", "utt")
    (tmp_path / "afile").write_text("x")
    if "/proc/p.pt" in args and not Path("/proc").is_dir():
        pytest.skip("no /proc")
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    out = [] if "-o" in args else ["-o", tmp_path / "p.pt"]
    proc = run_here("train", "ppg", "--data", tmp_path / "d", *out, *args)
    _one_line_error(proc, message)
    assert "ppg:" not in proc.stderr and not (tmp_path / "p.pt").exists()


def test_missing_output_folders_are_created(tmp_path):
    _grid(tmp_path / "d", "utt")
    said: list[str] = []
    train_ppg([tmp_path / "d"], tmp_path / "new" / "deeper" / "p.pt", steps=1, batch_size=2, say=said.append)
    assert (tmp_path / "new" / "deeper" / "p.pt").is_file()


def test_lower_case_textgrid_suffix_is_found_in_folders(tmp_path):
    _grid(tmp_path / "d", "a", suffix=".textgrid")
    _grid(tmp_path / "d", "b", suffix=".TEXTGRID")
    assert [w.name for w, _ in find_alignments([tmp_path / "d"])] == ["a.wav", "b.wav"]


def test_the_same_data_given_twice_is_read_once(tmp_path):
    for k in range(2):
        _grid(tmp_path / "d", f"u{k}")
    shutil.copytree(tmp_path / "d", tmp_path / "copy")  # a copy is different data: kept
    warnings: list[str] = []
    found = find_alignments([tmp_path / "d", tmp_path / "d", tmp_path / "d" / "u0.TextGrid"], warnings)
    assert len(found) == 2 and warnings == [
        "--data names 3 file(s) more than once (also through their folder): each is read once"
    ]
    assert len(find_alignments([tmp_path / "d", tmp_path / "copy"])) == 4
    summary, said = _train(tmp_path, tmp_path / "d", tmp_path / "d")
    assert summary["utterances"] == 2 and any("more than once" in s for s in said)
