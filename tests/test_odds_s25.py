"""Leftovers of the session's reviews: an Audio2Face export saved as UTF-16 or UTF-32 text with its mark is
found by ``s2a-capture import FOLDER --pair-audio``; a take skipped by the build as a duplicate is not
also said to be aligned twice; a file changed under ``FileAudio`` gives advice that fits every command."""

from __future__ import annotations

import codecs
import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from capture import InputError, read_take
from capture.audio_io import audio_left_in_files
from tests.conftest import run_cli, run_here
from viewer.plot import speech_segments
from viewer.render import load_animation

PAIR = "paired/neurosync-trainer-lite-testset"


# -- 1. an Audio2Face export in Windows' "Unicode" text, found in a folder ---------------------------------
@pytest.mark.parametrize(
    ("codec", "bom"),
    [
        ("utf-16-le", codecs.BOM_UTF16_LE),  # PowerShell 5's Out-File, Notepad's "Unicode"
        ("utf-16-be", codecs.BOM_UTF16_BE),
        ("utf-32-le", codecs.BOM_UTF32_LE),
    ],
)
def test_an_audio2face_export_in_unicode_text_is_found_in_a_folder(samples, tmp_path, codec, bom):
    """A folder holding ``line01_bsweight.json`` (UTF-16/32 with its mark, CRLF) and ``line01.wav``,
    imported with --pair-audio: the export is the take. It was skipped as "not an Audio2Face blendshape
    export" (only the UTF-8 bytes of its keys were looked for), and the import found nothing."""
    with open(samples / PAIR / "testset.csv", newline="") as f:
        header, *rows = list(csv.reader(f))[: 1 + 60]
    names = [n[0].lower() + n[1:] for n in header[2:54]]
    export = {"exportFps": 30.0, "numPoses": 52, "numFrames": len(rows), "facsNames": names}
    export["weightMat"] = [[float(v) for v in r[2:54]] for r in rows]
    folder = tmp_path / "a2f"
    folder.mkdir()
    text = json.dumps(export, indent=4).replace("\n", "\r\n")
    (folder / "line01_bsweight.json").write_bytes(bom + text.encode(codec))
    sf.write(folder / "line01.wav", np.zeros(16000 * 2, np.float32), 16000)
    proc = run_cli("capture", "import", folder, "--pair-audio", "-o", tmp_path / "out")
    assert proc.returncode == 0 and "skipped" not in proc.stderr, proc.stderr
    (take_dir,) = (tmp_path / "out").iterdir()
    take = read_take(take_dir)
    assert take.meta.fps == 30 and take.values.shape == (60, 52)
    assert take.values[:, take.meta.channels.index("jawOpen")] == pytest.approx(
        [float(r[2 + header[2:].index("JawOpen")]) for r in rows], abs=1e-6
    )


# -- 2. a take imported twice, aligned twice and built: one warning, the true one --------------------------
def _build_warnings(inputs: list[Path], out: Path) -> list[str]:
    proc = run_here("dataset", "build", *inputs, "-o", out, check=True)
    return [line for line in proc.stderr.splitlines() if "warning: take " in line]


def test_a_take_skipped_as_a_duplicate_is_not_said_to_be_aligned_twice(sim_take, tmp_path):
    """A take folder and its copy (``X (1)``, as a second download names it) imported into two folders
    (one id), each aligned alike, then built: the copy is skipped as a duplicate, and that is all that
    is said of it. It was also said to be "aligned twice with other options ... its speech counts twice
    in the dataset" (the raw takes' records differ in their source paths, so align's fingerprints
    differ), while the dataset held it once. (A take aligned twice, both built, is still said to be:
    test_align_dataset_crash.)"""
    copy = tmp_path / "src" / f"{sim_take.name} (1)"
    shutil.copytree(sim_take, copy)
    for source, takes in ((sim_take, "raw_a"), (copy, "raw_b")):
        run_here("capture", "import", source, "-o", tmp_path / takes, check=True)
    for takes, aligned in (("raw_a", "aligned_a"), ("raw_b", "aligned_b")):
        run_here("align", tmp_path / takes, "-o", tmp_path / aligned, check=True)
    take_id = read_take(next((tmp_path / "aligned_a").iterdir())).meta.id

    said = _build_warnings([tmp_path / "aligned_a", tmp_path / "aligned_b"], tmp_path / "ds_copy")
    assert len(said) == 1 and said[0].endswith(
        f"take {take_id} ({tmp_path / 'aligned_b' / take_id}) has the same frames and audio as take "
        f"{take_id}: skipped as a duplicate"
    ), said
    manifest = json.loads((tmp_path / "ds_copy" / "manifest.json").read_text())
    assert [s["take"] for s in manifest["sources"]] == [take_id], manifest["sources"]


# -- 3. a file changed since it was read, told to every command alike --------------------------------------
def test_audio_changed_under_a_plot_is_not_told_to_be_imported_again(samples, tmp_path):
    """The plot's speech left in its file, then rewritten before the detector reads it: the error says
    the file changed and to run the command again. It said "import it again" (the plot imports
    nothing)."""
    speech, rate = sf.read(samples / PAIR / "audio.wav", dtype="int16")
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, rate)
    with audio_left_in_files():
        anim = load_animation(samples / PAIR / "testset.csv", wav, clamp=False)
    sf.write(wav, speech[::-1].copy(), rate)
    with pytest.raises(InputError) as caught:
        speech_segments(anim, "webrtc")
    assert str(caught.value) == (
        f"{wav}: audio file changed since it was read (its samples differ from 0.0 s on): "
        "run the command again"
    )
