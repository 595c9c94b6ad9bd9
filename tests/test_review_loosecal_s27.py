"""Review of BEAT face JSONs found by ``--pair-audio``: a JSON of other data holding the keys "names",
"frames" and "weights" somewhere (a settings file) is skipped with a note as before, not taken for
blendshape weights (was: a failed source, "blendshape weights in JSON need their audio"); a BEAT face JSON
is still told apart however its keys fall across the blocks it is read in."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from conftest import run_here
from test_pairedformats_s27 import BEAT_NAMES, beat_face_json, write_audio

from capture import read_take
from capture.importer import is_weights_json

BLOCK = 1 << 20  # what is_weights_json reads at a time


def test_a_json_of_other_data_with_the_beat_keys_somewhere_is_skipped(tmp_path):
    clips = tmp_path / "clips"
    clips.mkdir()
    beat_face_json(clips / "2_scott_0_1_1.json", np.full((60, 51), 0.25), 30)
    write_audio(clips / "2_scott_0_1_1.wav", 2)
    settings = {"names": ["take A"], "frames": [{"time": 0.0, "camera": 2}], "ui": {"weights": [1, 2]}}
    (clips / "settings.json").write_text(json.dumps(settings))
    assert not is_weights_json(clips / "settings.json")
    proc = run_here("capture", "import", clips, "-o", tmp_path / "takes", "--pair-audio", "--json")
    # was: exit 1, "settings.json: blendshape weights in JSON need their audio (--audio, or --pair-audio)"
    assert proc.returncode == 0 and "need their audio" not in proc.stderr, proc.stderr
    (line,) = proc.stdout.splitlines()
    take = read_take(json.loads(line)["path"])
    assert take.meta.channels == BEAT_NAMES and take.audio is not None
    (said,) = [line for line in proc.stderr.splitlines() if "settings.json" in line]
    assert said.endswith('nor "names" and "frames" of "weights"): skipped'), said


def test_a_beat_face_json_is_told_whatever_block_its_keys_fall_in(tmp_path):
    """ "names" after a megabyte of frames; the first frame's "weights" across the first block's end; a
    frame's keys in another order: each is a BEAT face JSON, as ``read_json_matrix`` reads it."""
    frame = {"time": 0.0, "rotation": [], "weights": [0.5] * 51}
    frames = [frame] * (2 * BLOCK // len(json.dumps(frame)))
    late_names = tmp_path / "late_names.json"
    late_names.write_text(json.dumps({"frames": frames, "names": BEAT_NAMES}))
    assert late_names.stat().st_size > 2 * BLOCK and is_weights_json(late_names)
    head = '{"names": ' + json.dumps(BEAT_NAMES) + ', "note": "'
    split = tmp_path / "split.json"
    for cut in (6, 13, 30):  # the block ends inside "frames", between it and its list, inside "weights"
        pad = BLOCK - len(head) - cut
        split.write_text(head + "x" * pad + '", "frames": [{"time": 0.0, "weights": [0.5]}]}')
        assert json.loads(split.read_text())["frames"][0]["weights"] == [0.5]
        assert is_weights_json(split), cut
    # the first frame's "weights" is not a list: another file's data (a settings file's frames)
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"names": ["a"], "frames": [{"weights": 3}]}))
    assert not is_weights_json(other)


def test_a_settings_json_named_with_audio_says_what_it_lacks(tmp_path):
    """Named with ``--audio``, a JSON is read as weights whatever it holds: the reader names what is
    missing in one line (no traceback)."""
    settings = tmp_path / "settings.json"
    settings.write_text(json.dumps({"names": ["a"], "frames": [{"time": 0.0}], "ui": {"weights": 1}}))
    audio = write_audio(tmp_path / "settings.wav", 1)
    proc = run_here("capture", "import", settings, "--audio", audio, "-o", tmp_path / "takes")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "frames[0] has no weights" in proc.stderr, proc.stderr
    assert not any(Path(tmp_path / "takes").glob("*/take.json"))


def test_a_damaged_neutral_csv_beside_its_take_is_said_once_with_the_take(tmp_path, samples):
    """A loose trio whose ``_neutral.csv`` is not the app's CSV: its take is refused as its take folder
    refuses it, naming the neutral CSV, and the neutral CSV is no second failed source of its own (was:
    "2 sources failed", the same file said twice)."""
    loose = tmp_path / "loose"
    loose.mkdir()
    cal = samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"
    for variant in ("cal", "raw"):
        (loose / f"M_{variant}.csv").write_bytes(cal.read_bytes())
    (loose / "M_neutral.csv").write_text("saved over by a text editor\n")
    proc = run_here("capture", "import", loose, "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    failed = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [Path(f["source"]).name for f in failed] == ["M_cal.csv"], failed
    assert "M_neutral.csv:1: not a Live Link Face CSV" in failed[0]["error"]
    assert "M_raw.csv: the raw CSV of its take, M_cal.csv read instead: skipped" in proc.stderr
