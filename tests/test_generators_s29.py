"""Weights written by other face-capture apps and generators beside Live Link Face, each built as its
writer documents it (synthetic values, the real layout) and imported with ``s2a-capture import``:
MediaPipe FaceLandmarker's blendshapes as scripts save them, Face Cap's text export, iFacialMocap's stream
text, JSON of other layouts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_cli, run_here

from capture import read_take
from capture.channels import canonical

# MediaPipe FaceLandmarker's 52 blendshape categories in its order: index 0 `_neutral` (a score of the
# neutral face, no ARKit shape), then ARKit's names sorted, without tongueOut (the task's kBlendshapeNames).
MEDIAPIPE = ["_neutral", *sorted((
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff",
    "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft", "eyeBlinkRight", "eyeLookDownLeft",
    "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight",
    "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight",
    "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose", "mouthDimpleLeft", "mouthDimpleRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthFunnel", "mouthLeft", "mouthLowerDownLeft",
    "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight", "mouthPucker", "mouthRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthSmileLeft",
    "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "noseSneerLeft", "noseSneerRight",
))]  # fmt: skip
# Face Cap's blendshape names as its bs line gives them (ARKit's raw names: sides as _L/_R), in its order.
FACE_CAP = [
    "browInnerUp", "browDown_L", "browDown_R", "browOuterUp_L", "browOuterUp_R", "eyeLookUp_L", "eyeLookUp_R",
    "eyeLookDown_L", "eyeLookDown_R", "eyeLookIn_L", "eyeLookIn_R", "eyeLookOut_L", "eyeLookOut_R",
    "eyeBlink_L", "eyeBlink_R", "eyeSquint_L", "eyeSquint_R", "eyeWide_L", "eyeWide_R", "cheekPuff",
    "cheekSquint_L", "cheekSquint_R", "noseSneer_L", "noseSneer_R", "jawOpen", "jawForward", "jawLeft",
    "jawRight", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthRollUpper", "mouthRollLower",
    "mouthShrugUpper", "mouthShrugLower", "mouthClose", "mouthSmile_L", "mouthSmile_R", "mouthFrown_L",
    "mouthFrown_R", "mouthDimple_L", "mouthDimple_R", "mouthUpperUp_L", "mouthUpperUp_R", "mouthLowerDown_L",
    "mouthLowerDown_R", "mouthPress_L", "mouthPress_R", "mouthStretch_L", "mouthStretch_R", "tongueOut",
]  # fmt: skip
SPEECH = "speech/pocketsphinx-testdata-librivox/sense_and_sensibility_01_austen_64kb-0870.wav"


def silence(path: Path, seconds: float) -> Path:
    sf.write(path, np.zeros(int(16000 * seconds), np.int16), 16000, subtype="PCM_16")
    return path


def imported(out: Path, *args: object):
    proc = run_cli("capture", "import", *args, "-o", out, "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    return read_take(json.loads(proc.stdout.splitlines()[-1])["path"])


def refused(tmp_path: Path, *args: object) -> str:
    """The one-line error of an import (in this process: the subject is the message)."""
    proc = run_here("capture", "import", *args, "-o", tmp_path / "refused")
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


def mediapipe_csv(path: Path, seconds: float, frame_column: bool = False) -> np.ndarray:
    """Blendshape scores as MediaPipe scripts write them from a 30 fps video: a row per frame, the frame's
    timestamp in whole milliseconds (what ``detect_for_video`` is given: ``round(i * 1000 / fps)``), a
    column per category under its name, ``_neutral`` first; a ``frame`` column before it when asked."""
    frames = int(seconds * 30)
    scores = np.random.default_rng(1).uniform(0, 0.7, (frames, len(MEDIAPIPE))).round(6)
    scores[:, 0] = np.random.default_rng(2).uniform(0, 1e-4, frames).round(7)  # _neutral: near 0
    head = ["frame"] * frame_column + ["timestamp_ms", *MEDIAPIPE]
    lines = [",".join(head)]
    for i, row in enumerate(scores):
        cells = [str(i)] * frame_column + [str(round(i * 1000 / 30)), *map(str, row)]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return scores


@pytest.mark.parametrize("frame_column", [False, True], ids=["timestamp_ms", "frame_and_timestamp_ms"])
def test_mediapipe_blendshapes_leave_neutral_out(tmp_path, frame_column):
    """`_neutral` (MediaPipe's category 0, a neutral-face score) was kept as a channel of its own; it is
    left out with a note, the 51 ARKit names kept as they are (MediaPipe's Left is the subject's left, as
    ARKit's), the milliseconds read as milliseconds."""
    scores = mediapipe_csv(tmp_path / "mp.csv", 3, frame_column)
    take = imported(
        tmp_path / "takes", "--matrix", tmp_path / "mp.csv", "--audio", silence(tmp_path / "a.wav", 3)
    )
    assert take.meta.fps == 30 and take.meta.channels == MEDIAPIPE[1:]
    assert np.allclose(take.values, scores[:, 1:], atol=1e-6)
    assert np.allclose(take.time, np.round(np.arange(90) * 1000 / 30) / 1000)
    notes = {r["kind"]: r["message"] for r in take.meta.repairs}
    assert "'_neutral' (MediaPipe's neutral-face score)" in notes["side_scores"]
    assert ("frame_column" in notes) == frame_column


def test_emotion_weights_beside_arkit_channels_are_left_out(tmp_path):
    """A generator's emotion weights written after its ARKit channels (NeuroSync's 7, here under a time
    column rather than the app's Timecode) were kept as channels of their own; a rig's own control named
    like an emotion, in a layout of rig controls, is kept."""
    emotions = ["Angry", "Disgusted", "Fearful", "Happy", "Neutral", "Sad", "Surprised"]
    values = np.random.default_rng(3).uniform(0, 1, (60, 9)).round(5)
    rows = [f"{i / 60:.6f}," + ",".join(map(str, r)) for i, r in enumerate(values)]
    (tmp_path / "gen.csv").write_text("\n".join(["time,JawOpen,MouthClose," + ",".join(emotions), *rows]))
    take = imported(
        tmp_path / "t1", "--matrix", tmp_path / "gen.csv", "--audio", silence(tmp_path / "a.wav", 1)
    )
    assert take.meta.channels == ["jawOpen", "mouthClose"] and np.allclose(take.values, values[:, :2])
    assert "'Angry', 'Disgusted'" in next(
        r["message"] for r in take.meta.repairs if r["kind"] == "side_scores"
    )
    (tmp_path / "rig.csv").write_text(
        "\n".join(["time,brow_l,brow_r,happy", *(r.rsplit(",", 6)[0] for r in rows)])
    )
    take = imported(tmp_path / "t2", "--matrix", tmp_path / "rig.csv", "--audio", tmp_path / "a.wav")
    assert take.meta.channels == ["brow_l", "brow_r", "happy"]


def face_cap_txt(path: Path, seconds: float) -> np.ndarray:
    """Face Cap's text export at 60 fps: ``info`` line, ``bs`` line of its 52 names, then per frame
    ``k,<ms from the start>,<head position 3>,<head rotation 3, degrees>,<eyes 2 + 2, degrees>,<52 weights>``
    (the layout the DAZ importer and Faceit read)."""
    frames = int(seconds * 60)
    weights = np.random.default_rng(4).uniform(0, 1, (frames, 52)).round(5)
    weights[:, FACE_CAP.index("mouthSmile_L")] = 0.9  # one side only: a mirrored reading would show
    weights[:, FACE_CAP.index("mouthSmile_R")] = 0.0
    pose = "0.012,-0.03,-0.36,4.2,-12.5,1.1,6.0,-3.1,6.1,-2.8"
    lines = ["info,Face Cap,1.0,60", "bs," + ",".join(FACE_CAP)]
    lines += [f"k,{round(i * 1000 / 60)},{pose}," + ",".join(map(str, row)) for i, row in enumerate(weights)]
    path.write_text("\r\n".join(lines) + "\r\n")
    return weights


def test_face_cap_text_export_is_read(tmp_path):
    """Was "row has 64 values, the first row 53"."""
    weights = face_cap_txt(tmp_path / "FC_2024-1-1_12-00-00.txt", 2)
    take = imported(
        tmp_path / "takes",
        "--matrix",
        tmp_path / "FC_2024-1-1_12-00-00.txt",
        "--audio",
        silence(tmp_path / "a.wav", 2),
    )
    assert take.meta.fps == 60 and take.meta.channels == [canonical(n) for n in FACE_CAP]
    assert take.meta.audio.start_source == "paired_time_column"
    assert np.allclose(take.time, np.round(np.arange(120) * 1000 / 60) / 1000)
    assert np.allclose(take.values, weights, atol=1e-6)
    column = take.meta.channels.index
    assert (take.values[:, column("mouthSmileLeft")] == np.float32(0.9)).all()
    assert (take.values[:, column("mouthSmileRight")] == 0).all()
    assert [r["kind"] for r in take.meta.repairs] == ["pose_left_out"]


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda t: t.replace("k,", "k,x", 1), "non-numeric value in a k line: 'x0'"),
        (lambda t: t.replace(",0.9,", ",", 1), "k line holds 51 weights after the time and 10 head and eye"),
        (
            lambda t: t.replace("info,", "inf,", 1),
            "not a Face Cap line (info, bs or k): 'inf,Face Cap,1.0,60'",
        ),
        (lambda t: t.replace("bs,browInnerUp,", "bs,,", 1), "the bs line leaves a blendshape without a name"),
        (lambda t: "\r\n".join(t.splitlines()[:2]), "a Face Cap export without k lines (frames)"),
    ],
)
def test_a_damaged_face_cap_export_is_a_one_line_error(tmp_path, edit, needle):
    face_cap_txt(tmp_path / "fc.txt", 1)
    (tmp_path / "fc.txt").write_text(edit((tmp_path / "fc.txt").read_text()))
    assert needle in refused(
        tmp_path, "--matrix", tmp_path / "fc.txt", "--audio", silence(tmp_path / "a.wav", 1)
    )


def test_ifacialmocap_stream_text_is_named(tmp_path):
    """iFacialMocap's UDP text (``name-value|...`` on 0..100, then ``=head#...``) saved a frame a line was
    "non-numeric value in the matrix: '<the whole line>' ... (digits grouped with '_' are not read)"."""
    line = "mouthSmile_R-0|eyeLookOut_L-12|jawOpen-35|=head#-21.4,-6.0,-6.6,-0.03,-0.1,-0.6|"
    line += "rightEye#6.0,2.4,0.2|leftEye#6.0,-1.6,-0.1|"
    audio = silence(tmp_path / "a.wav", 1)
    for name in ("ifm.txt", "ifm.csv"):
        (tmp_path / name).write_text("\n".join([line] * 60) + "\n")
        message = refused(tmp_path, "--matrix", tmp_path / name, "--audio", audio)
        assert "iFacialMocap's stream text" in message and "0..100" in message and len(message) < 400
    assert "iFacialMocap's stream text" in refused(tmp_path, tmp_path / "ifm.csv", "--audio", audio)


def test_a_unity_animation_clip_is_named(tmp_path):
    """Unity's Face Capture records a take as an animation clip (YAML); it was "row has 1 values, the
    first row 2"."""
    clip = "%YAML 1.1\n%TAG !u! tag:unity3d.com,2011:\n--- !u!74 &7400000\nAnimationClip:\n  m_Name: take\n"
    (tmp_path / "take.anim").write_text(clip)
    message = refused(tmp_path, "--matrix", tmp_path / "take.anim", "--audio", silence(tmp_path / "a.wav", 1))
    assert "take.anim:1: a YAML file (a Unity animation clip" in message


def test_one_row_per_blendshape_is_named(tmp_path):
    """MediaPipe scripts that write a row per category and frame (``frame,timestamp_ms,category_name,score``)
    were told '_neutral' is "digits grouped with '_'"; the message now says what the layout is."""
    lines = ["frame,timestamp_ms,category_name,score"]
    lines += [f"{i},{round(i * 1000 / 30)},{n},0.1" for i in range(30) for n in MEDIAPIPE]
    (tmp_path / "long.csv").write_text("\n".join(lines) + "\n")
    message = refused(tmp_path, "--matrix", tmp_path / "long.csv", "--audio", silence(tmp_path / "a.wav", 1))
    assert "'_neutral' in column 'category_name'" in message and "one row per blendshape and frame" in message
    assert "digits grouped" not in message
    (tmp_path / "grouped.csv").write_text("jawOpen,mouthClose\n0.1,1_0\n")
    assert "digits grouped with '_'" in refused(
        tmp_path, "--matrix", tmp_path / "grouped.csv", "--audio", tmp_path / "a.wav", "--fps", 30
    )


def test_a_json_of_another_layout_says_what_it_holds(tmp_path):
    """MediaPipe's results dumped as JSON (a list of frames of ``faceBlendshapes``) is no layout read; the
    error now says what the file holds besides what it lacks."""
    frames = [
        {"timestamp": 0, "faceBlendshapes": [{"categories": [{"categoryName": "jawOpen", "score": 0.1}]}]}
    ]
    (tmp_path / "mp.json").write_text(json.dumps(frames * 5))
    audio = silence(tmp_path / "a.wav", 1)
    assert "holds a list of 5 items: not an Audio2Face" in refused(
        tmp_path, "--matrix", tmp_path / "mp.json", "--audio", audio
    )
    (tmp_path / "o.json").write_text(json.dumps({"fps": 30, "blendshapes": []}))
    assert "holds an object of 'fps', 'blendshapes': not" in refused(
        tmp_path, "--matrix", tmp_path / "o.json", "--audio", audio
    )


def test_mediapipe_take_with_real_speech_builds_without_neutral(tmp_path, samples):
    """import, info, s2a-align and s2a-dataset build of MediaPipe scores paired with real speech: the
    dataset's channels (``--channels varying``) were 52 with `_neutral` as a target; now the 51 ARKit."""
    speech = samples / SPEECH
    mediapipe_csv(tmp_path / "mp.csv", sf.info(speech).duration)
    imported(tmp_path / "takes", "--matrix", tmp_path / "mp.csv", "--audio", speech)
    info = run_cli("capture", "info", tmp_path / "takes", "--json", check=True)
    assert json.loads(info.stdout.splitlines()[-1])["channels"] == 51
    run_cli("align", tmp_path / "takes", "-o", tmp_path / "aligned", check=True)
    run_cli(
        "dataset", "build", tmp_path / "aligned", "-o", tmp_path / "ds", "--channels", "varying", check=True
    )
    channels = json.loads((tmp_path / "ds" / "manifest.json").read_text())["channels"]
    assert channels == MEDIAPIPE[1:]
