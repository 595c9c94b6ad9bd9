"""An end-to-end review of paired data from generators nobody had tried: channel names that carry an
exporter's or rig's prefix or suffix around the ARKit name (``A2F_jawOpen``, ``CTRL_expressions_jawOpen``,
``jawOpen_bs``), and a batch of raw clips of which several cannot be aligned, built into a dataset.
Real files: the NeuroSync take's weights and speech (52 ARKit channels at 60 fps), real command lines."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here

NEUROSYNC = ("paired", "neurosync-trainer-lite-testset")


@pytest.fixture(scope="module")
def neurosync(samples):
    """The NeuroSync take's first 2 s: ARKit names as its CSV spells them, the weights (frames x 52), and
    the audio with its rate."""
    folder = samples.joinpath(*NEUROSYNC)
    with open(folder / "testset.csv", newline="") as f:
        rows = list(csv.reader(f))
    names = rows[0][2:54]
    weights = np.array([[float(x) for x in r[2:54]] for r in rows[1:121]], np.float32)
    audio, rate = sf.read(folder / "audio.wav", frames=2 * 44100)
    return names, weights, audio, rate


def import_matrix(tmp_path, neurosync, names: list[str], take_id: str, weights=None, *extra) -> dict:
    """``s2a-capture import --matrix`` of the NeuroSync weights (or ``weights``) under ``names``, with
    ``extra`` arguments; the take's meta.json."""
    _, ours, audio, rate = neurosync
    np.save(tmp_path / f"{take_id}.npy", ours if weights is None else weights)
    (tmp_path / f"{take_id}.txt").write_text("\n".join(names) + "\n")
    sf.write(tmp_path / f"{take_id}.wav", audio, rate)
    run_here(
        "capture", "import", "--matrix", tmp_path / f"{take_id}.npy", "--audio", tmp_path / f"{take_id}.wav",
        "--names", tmp_path / f"{take_id}.txt", "--fps", 60, "--id", take_id, "-o", tmp_path / "takes",
        *extra, check=True,
    )  # fmt: skip
    return json.loads((tmp_path / "takes" / take_id / "meta.json").read_text())


def lower_first(name: str) -> str:
    return name[0].lower() + name[1:]


def test_arkit_names_under_an_exporters_prefix_or_suffix_are_arkit_channels(tmp_path, neurosync):
    names = neurosync[0]
    plain = import_matrix(tmp_path, neurosync, names, "plain")["channels"]
    assert "jawOpen" in plain and len(plain) == 52
    for affix, spelled in (
        ("'A2F_'", [f"A2F_{lower_first(n)}" for n in names]),
        ("'CTRL_expressions_'", [f"CTRL_expressions_{lower_first(n)}" for n in names]),
        ("'_bs'", [f"{n}_bs" for n in names]),
    ):
        meta = import_matrix(tmp_path, neurosync, spelled, "take")
        # before: kept as 52 rig controls, which the dataset's default channels then all lacked
        assert meta["channels"] == plain, affix
        (note,) = [r["message"] for r in meta["repairs"] if r["kind"] == "channel_affix"]
        assert affix in note and "eyeBlinkLeft" in note
    with np.load(tmp_path / "takes" / "take" / "frames.npz") as z:
        jaw = z["values"][:, plain.index("jawOpen")]
    assert np.array_equal(jaw, neurosync[1][:, names.index("JawOpen")])  # each column keeps its curve


def test_a_rigs_own_controls_keep_their_names(tmp_path, neurosync):
    names = [f"CTRL_expressions_{lower_first(n)}" for n in neurosync[0]]
    names[-1] = "CTRL_expressions_mouthCornerPullL"  # a MetaHuman control no ARKit name stands for
    meta = import_matrix(tmp_path, neurosync, names, "rig")
    assert meta["channels"] == names and not any(r["kind"] == "channel_affix" for r in meta["repairs"])


def test_weights_stored_as_bytes_are_noted_with_the_scale_that_fixes_them(tmp_path, neurosync):
    names, weights = neurosync[0], neurosync[1]
    stored = np.round(weights * 255).astype(np.uint8)  # an 8-bit quantised export
    meta = import_matrix(tmp_path, neurosync, names, "bytes", stored)
    # before: no note, and the dataset build masked nine frames in ten as beyond +-10
    (note,) = [r["message"] for r in meta["repairs"] if r["kind"] == "percent_scale"]
    assert "0..255 scale" in note and "--value-scale 0.00392157" in note
    meta = import_matrix(tmp_path, neurosync, names, "scaled", stored, "--value-scale", "0.00392157")
    assert not any(r["kind"] == "percent_scale" for r in meta["repairs"])
    with np.load(tmp_path / "takes" / "scaled" / "frames.npz") as z:
        assert np.abs(z["values"] - weights).max() <= 0.5 / 255 + 1e-5
    # a 0..100 scale overshooting to 110 is no byte scale: 1/255 would be the wrong factor
    meta = import_matrix(tmp_path, neurosync, names, "over", weights * (110 / weights.max()))
    assert not any(r["kind"] == "percent_scale" for r in meta["repairs"])


def test_a_length_mismatch_of_an_export_that_gives_its_rate_names_that_rate(tmp_path, neurosync):
    names, weights, audio, rate = neurosync
    export = {"exportFps": 30, "facsNames": [lower_first(n) for n in names], "weightMat": weights.tolist()}
    (tmp_path / "a2f.json").write_text(json.dumps(export))  # 2 s of frames at 60 fps said to be at 30
    sf.write(tmp_path / "a2f.wav", audio, rate)
    proc = run_here(
        "capture", "import", "--matrix", tmp_path / "a2f.json", "--audio", tmp_path / "a2f.wav",
        "-o", tmp_path / "takes", check=True,
    )  # fmt: skip
    # before: "check --fps", which the export's own rate leaves nothing to give (another rate is refused)
    assert "2.000 s shorter than the frames: check the frame rate the file gives (30 fps)" in proc.stderr


def test_raw_takes_align_cannot_use_are_named_together(tmp_path, samples):
    """Raw takes of which several cannot be aligned (here the real Live Link CSVs recorded without
    audio; in a batch of paired clips, silent ones): the build names every one in its one error (before,
    it stopped at the first: one run per such take to find them all)."""
    takes = [samples / "livelinkface" / f"alexdjulin_{s}" for s in ("S07", "S88")]
    run_here("capture", "import", *takes, "-o", tmp_path / "takes", check=True)
    proc = run_here("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    (line,) = [x for x in proc.stderr.splitlines() if "error" in x]
    assert "2 raw take(s) cannot be aligned" in line, line
    assert all(f"take {t}-001 has no audio" in line for t in ("S07", "S88"))
    assert "s2a-align -o ALIGNED" in line
