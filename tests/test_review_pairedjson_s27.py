"""Review of the BEAT face JSON reader (``s2a-capture import --matrix FACE.json``): a names file given with
``--names`` names the weights, not the frame times the file adds; a damaged frame is named in JSON's
words."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from capture import read_take
from capture.channels import ARKIT52
from tests.conftest import run_here

# BEAT's 51 ARKit names (no tongueOut), in its order, and as a names file may spell them (Live Link Face's).
BEAT_NAMES = sorted(n for n in ARKIT52 if n != "tongueOut")
PASCAL_NAMES = [n[0].upper() + n[1:] for n in BEAT_NAMES]


def face_json(folder: Path, frames: int, fps: float) -> tuple[Path, Path, np.ndarray]:
    """A BEAT face JSON (frame j at ``j * (1 / fps)`` s, as DiffSHEG writes it) and 2 s of audio."""
    weights = np.random.default_rng(11).uniform(0, 0.7, (frames, len(BEAT_NAMES)))
    rows = [{"weights": w.tolist(), "time": j * (1 / fps), "rotation": []} for j, w in enumerate(weights)]
    path = folder / "face.json"
    path.write_text(json.dumps({"names": BEAT_NAMES, "frames": rows}, indent=4))
    audio = folder / "face.wav"
    sf.write(audio, np.zeros(32000, np.int16), 16000, subtype="PCM_16")
    return path, audio, weights


def test_names_file_names_the_weights_of_a_timed_beat_face_json(tmp_path):
    """``--names`` with 51 names for a BEAT file of 51 weights a frame: was refused as "51 channel names
    for a matrix of 52 columns" (the frame times counted as a column); now the names replace the file's
    and the times still place the frames."""
    face, audio, weights = face_json(tmp_path, 120, 60)
    names = tmp_path / "names.txt"
    names.write_text("\n".join(PASCAL_NAMES) + "\n")
    out = tmp_path / "takes"
    proc = run_here(
        "capture", "import", "--matrix", face, "--names", names, "--audio", audio, "-o", out, "--json"
    )
    assert proc.returncode == 0, proc.stderr
    take = read_take(json.loads(proc.stdout.splitlines()[-1])["path"])
    assert take.meta.channels == BEAT_NAMES and take.meta.fps == 60
    assert take.meta.audio.start_source == "paired_time_column"
    assert np.allclose(take.time, np.arange(120) / 60) and np.allclose(take.values, weights, atol=1e-6)


def test_names_file_of_another_count_than_the_weights_says_so(tmp_path):
    face, audio, _ = face_json(tmp_path, 60, 60)
    names = tmp_path / "names.txt"
    names.write_text("\n".join(PASCAL_NAMES[:50]) + "\n")
    proc = run_here(
        "capture", "import", "--matrix", face, "--names", names, "--audio", audio, "-o", tmp_path / "o"
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "50 channel names for a matrix of 51 columns" in proc.stderr, proc.stderr


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda frames: frames[2].pop("weights"), "frames[2] has no weights"),
        (lambda frames: frames[3].__setitem__("weights", None), "frames[3].weights holds null, names 51"),
        (lambda frames: frames[4].__setitem__("weights", "0.1"), "frames[4].weights holds a string, names"),
        (
            lambda frames: frames[5].__setitem__("weights", {"jawOpen": 0.1}),
            "frames[5].weights holds an object",
        ),
    ],
    ids=["no-weights", "null", "string", "object"],
)
def test_a_frame_without_a_list_of_weights_is_named_in_json_words(tmp_path, edit, needle):
    """Was "frames[2].weights holds NoneType", "... holds str", "... holds dict": Python's names."""
    face, audio, _ = face_json(tmp_path, 30, 60)
    data = json.loads(face.read_text())
    edit(data["frames"])
    face.write_text(json.dumps(data))
    proc = run_here("capture", "import", "--matrix", face, "--audio", audio, "-o", tmp_path / "o")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert needle in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
