"""Paired data in the layouts other generators of ARKit-style blendshape animation write, each built as its
source documents it (synthetic values, the real layout) and imported with ``s2a-capture import``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_cli, run_here
from test_paired_probe_fixes import EMOTIONS

from capture import read_take
from capture.channels import ARKIT52

# The 51 names of a BEAT face JSON, in its order (ARKit's 52 without tongueOut, sorted by name).
BEAT_NAMES = sorted(n for n in ARKIT52 if n != "tongueOut")


def write_audio(path: Path, seconds: float) -> Path:
    sf.write(path, np.zeros(int(16000 * seconds), np.int16), 16000, subtype="PCM_16")
    return path


def beat_face_json(path: Path, weights: np.ndarray, fps: float | None) -> Path:
    """A face JSON as BEAT holds its ARKit weights and DiffSHEG writes them (``names``; ``frames`` of
    ``weights``, ``time`` in seconds from 0 and an empty ``rotation``; indented by 4)."""
    frames = [{"weights": row.tolist(), "rotation": []} for row in weights]
    if fps is not None:
        for j, frame in enumerate(frames):
            frame["time"] = j * (1 / fps)
    path.write_text(json.dumps({"names": BEAT_NAMES, "frames": frames}, indent=4))
    return path


def imported(tmp_path: Path, *args: object):
    proc = run_cli("capture", "import", *args, "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    return read_take(json.loads(proc.stdout.splitlines()[-1])["path"])


@pytest.mark.parametrize("fps", [60, 15])
def test_a_beat_face_json_is_read_with_its_names_and_frame_times(tmp_path, fps):
    """BEAT's face JSON: PantoMatrix/PantoMatrix dataloaders/beat.py reads ``frames[j]['weights']`` and
    takes the rate from ``frames[j]['time']`` (60 fps, "60FPS to 15FPS"); JeremyCJM/DiffSHEG
    trainers/ddpm_beat_trainer.py ``write_face_json`` writes ``{"names": [51 ARKit names], "frames":
    [{"weights": [...], "time": jj * (1/15), "rotation": []}]}``. Was refused as "not an Audio2Face
    blendshape export"."""
    weights = np.random.default_rng(3).uniform(0, 0.8, (3 * fps, 51)).round(6)
    face = beat_face_json(tmp_path / "2_scott_0_1_1.json", weights, fps)
    take = imported(tmp_path, "--matrix", face, "--audio", write_audio(tmp_path / "2_scott_0_1_1.wav", 3))
    assert take.meta.fps == fps and take.meta.channels == BEAT_NAMES
    assert take.meta.audio.start_source == "paired_time_column"
    assert np.allclose(take.time, np.arange(3 * fps) / fps) and np.allclose(take.values, weights, atol=1e-6)
    assert take.meta.repairs == []


def test_a_beat_face_json_named_directly_with_its_audio(tmp_path):
    """``s2a-capture import FACE.json --audio A.wav`` reads it as ``--matrix`` does."""
    weights = np.random.default_rng(4).uniform(0, 0.5, (120, 51))
    face = beat_face_json(tmp_path / "face.json", weights, 60)
    take = imported(tmp_path, face, "--audio", write_audio(tmp_path / "a.wav", 2))
    assert take.meta.fps == 60 and take.values.shape == (120, 51)


def test_a_beat_face_json_without_times_takes_its_rate_from_fps(tmp_path):
    weights = np.random.default_rng(5).uniform(0, 0.5, (30, 51))
    face = beat_face_json(tmp_path / "face.json", weights, None)
    audio = write_audio(tmp_path / "a.wav", 1)
    take = imported(tmp_path, "--matrix", face, "--audio", audio, "--fps", "30")
    assert take.meta.fps == 30 and take.meta.audio.start_source == "paired_frame_convention"
    proc = run_here("capture", "import", "--matrix", face, "--audio", audio, "-o", tmp_path / "o")
    assert proc.returncode == 1 and "no frame rate: give --fps" in proc.stderr, proc.stderr


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda d: d["frames"][3]["weights"].pop(), "frames[3].weights holds 50 values, names 51 names"),
        (lambda d: d["frames"][2]["weights"].__setitem__(0, "0.1"), "frames[2].weights holds a value that"),
        (lambda d: d["frames"][1].pop("time"), "frames[1] has no time, frames[0] has"),
        (lambda d: d["frames"][4].__setitem__("time", None), "frames[4].time holds a value that is not"),
        (lambda d: d.__setitem__("frames", {}), "frames must be a non-empty list of frames"),
        (lambda d: d.__setitem__("names", "jawOpen"), "names must be a non-empty list of names"),
        (lambda d: d["frames"][5].__setitem__("time", 0.0), "time column 'time' must be finite and increase"),
    ],
    ids=[
        "short-row",
        "text-value",
        "untimed-frame",
        "null-time",
        "frames-not-list",
        "names-not-list",
        "time-back",
    ],
)
def test_a_damaged_beat_face_json_is_a_one_line_error_naming_the_field(tmp_path, edit, needle):
    path = beat_face_json(tmp_path / "face.json", np.full((10, 51), 0.2), 60)
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    proc = run_here(
        "capture",
        "import",
        "--matrix",
        path,
        "--audio",
        write_audio(tmp_path / "a.wav", 1),
        "-o",
        tmp_path / "o",
    )
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert needle in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr


# Audio2Face-3D's ARKit names in the order its sample client writes them, and the head angles after them.
A2F3D_NAMES = [n[0].upper() + n[1:] for n in ARKIT52] + ["HeadRoll", "HeadPitch", "HeadYaw"]


def test_audio2face_3d_sample_client_output_folder(tmp_path):
    """NVIDIA/Audio2Face-3D-Samples scripts/audio2face_3d_api_client/a2f_3d/client/service.py writes a
    folder of ``out.wav`` and ``pandas.json_normalize([{"timeCode": t, "blendShapes": {name: w}}])
    .to_csv("animation_frames.csv")`` (pandas' index column under an empty header cell, ``timeCode`` in
    seconds, ``blendShapes.EyeBlinkLeft``, ..., ``blendShapes.HeadYaw``: the header of the
    ``animation_frames.csv`` in qwert1887/Audio2Face-3D-Samples), beside ``a2f_smoothed_emotion_output.csv``
    (``time_code``, ``emotion_values.<emotion>``). Read as 55 channels at 30 fps, the emotions skipped."""
    folder = tmp_path / "20250101_120000_000000"
    folder.mkdir()
    weights = np.random.default_rng(6).uniform(0, 0.4, (60, len(A2F3D_NAMES)))
    lines = [",timeCode," + ",".join(f"blendShapes.{n}" for n in A2F3D_NAMES)]
    lines += [f"{i},{i / 30!r}," + ",".join(map(repr, row.tolist())) for i, row in enumerate(weights)]
    (folder / "animation_frames.csv").write_text("\n".join(lines) + "\n")
    (folder / "a2f_smoothed_emotion_output.csv").write_text(
        ",time_code,"
        + ",".join(f"emotion_values.{e}" for e in EMOTIONS)
        + "\n0,0.0,"
        + ",".join(["0.1"] * 10)
        + "\n"
    )
    write_audio(folder / "out.wav", 2)
    proc = run_cli("capture", "import", folder, "--pair-audio", "-o", tmp_path / "takes", "--json")
    assert proc.returncode == 0, proc.stderr
    assert "a2f_smoothed_emotion_output.csv: holds emotion weights" in proc.stderr
    take = read_take(json.loads(proc.stdout.splitlines()[-1])["path"])
    assert take.meta.fps == 30 and take.meta.channels[:2] == ["eyeBlinkLeft", "eyeLookDownLeft"]
    assert len(take.meta.channels) == 55 and take.meta.audio.start_source == "paired_time_column"
    assert np.allclose(take.values, weights, atol=1e-6) and take.meta.repairs == []


def test_a_said_coefficients_csv_at_its_60_fps(tmp_path):
    """yunik1004/SAiD said/util/blendshape.py ``save_blendshape_coeffs``: ``pandas.DataFrame(coeffs,
    columns=classes).to_csv(path, index=False)``, a header of its 32 lower-face ARKit names (the header of
    data/coeffs_std.csv) over one row per frame, no time column; script/inference.py writes it at
    ``--fps`` 60 by default, frame i at i/60 of the audio. Its diffusion output may dip a little below 0."""
    names = (
        "jawForward,jawLeft,jawRight,jawOpen,mouthClose,mouthFunnel,mouthPucker,mouthLeft,mouthRight,"
        "mouthSmileLeft,mouthSmileRight,mouthFrownLeft,mouthFrownRight,mouthDimpleLeft,mouthDimpleRight,"
        "mouthStretchLeft,mouthStretchRight,mouthRollLower,mouthRollUpper,mouthShrugLower,mouthShrugUpper,"
        "mouthPressLeft,mouthPressRight,mouthLowerDownLeft,mouthLowerDownRight,mouthUpperUpLeft,"
        "mouthUpperUpRight,cheekPuff,cheekSquintLeft,cheekSquintRight,noseSneerLeft,noseSneerRight"
    ).split(",")
    weights = np.random.default_rng(7).uniform(-0.02, 0.7, (120, 32))
    path = tmp_path / "out.csv"
    path.write_text(
        ",".join(names) + "\n" + "\n".join(",".join(map(repr, r.tolist())) for r in weights) + "\n"
    )
    audio = write_audio(tmp_path / "sentence01.wav", 2)
    take = imported(tmp_path, "--matrix", path, "--audio", audio, "--fps", "60")
    assert take.meta.channels == names and take.meta.fps == 60
    assert take.meta.audio.start_source == "paired_frame_convention" and np.allclose(
        take.time, np.arange(120) / 60
    )
    assert np.allclose(take.values, weights, atol=1e-6) and take.meta.repairs == []
