"""A folder of BEAT face JSONs beside their WAVs (as the BEAT dataset keeps them) imports with
``--pair-audio`` as a folder of Audio2Face exports does (was: each skipped as "not an Audio2Face blendshape
export"); a JSON of other data beside them is still skipped, and one named without audio says it needs it."""

from __future__ import annotations

import json

import numpy as np
from conftest import run_here
from test_pairedformats_s27 import BEAT_NAMES, beat_face_json, write_audio

from capture import read_take


def test_a_folder_of_beat_face_jsons_pairs_with_their_audio(tmp_path):
    clips = tmp_path / "beat"
    clips.mkdir()
    for n, stem in enumerate(["2_scott_0_1_1", "2_scott_0_2_2"]):
        weights = np.random.default_rng(n).uniform(0, 0.8, (120, 51)).round(6)
        beat_face_json(clips / f"{stem}.json", weights, 60)
        write_audio(clips / f"{stem}.wav", 2)
    (clips / "settings.json").write_text(json.dumps({"names": ["a"], "frames": 3}))  # no "weights"
    proc = run_here("capture", "import", clips, "-o", tmp_path / "takes", "--pair-audio", "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    paths = [json.loads(line)["path"] for line in proc.stdout.splitlines()]
    assert len(paths) == 2, proc.stdout
    for path in paths:
        take = read_take(path)
        assert take.meta.fps == 60 and take.meta.channels == BEAT_NAMES and take.audio is not None
    (said,) = [line for line in proc.stderr.splitlines() if "settings.json" in line]
    assert "skipped" in said and "BEAT face JSON" in said, said
    proc = run_here("capture", "import", clips / "2_scott_0_1_1.json", "-o", tmp_path / "alone")
    assert proc.returncode == 1 and "need their audio (--audio, or --pair-audio)" in proc.stderr, proc.stderr


def test_a_beat_face_json_named_with_its_audio_takes_its_rate_from_fps(tmp_path):
    """A face JSON without times named with ``--audio`` and ``--fps`` (was: "no frame rate: give --fps"
    though it was given: ``--matrix`` took it)."""
    face = beat_face_json(tmp_path / "clip.json", np.full((30, 51), 0.25), None)
    proc = run_here(
        "capture", "import", face, "--audio", write_audio(tmp_path / "clip.wav", 2), "--fps", 15,
        "-o", tmp_path / "takes", "--json",
    )  # fmt: skip
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    take = read_take(json.loads(proc.stdout.splitlines()[-1])["path"])
    assert take.meta.fps == 15 and len(take.time) == 30
