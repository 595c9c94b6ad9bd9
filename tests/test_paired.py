"""Generic paired import: audio + frames x channels matrix + names + fps, from any rig."""

import json

import numpy as np
import pytest
import soundfile as sf

from capture import FrameStatus, InputError, read_paired, read_take
from tests.conftest import run_here


@pytest.fixture
def wav(tmp_path):
    path = tmp_path / "a.wav"
    sf.write(path, np.zeros(16000, np.int16), 16000, subtype="PCM_16")
    return path


def test_csv_matrix_with_header_and_livelink_names(tmp_path, wav):
    m = tmp_path / "m.csv"
    rows = "\n".join(f"{i / 30},0.1,-0.5" for i in range(30))
    m.write_text("JawOpen,MouthClose,lip_custom\n" + rows + "\n")
    take = read_paired(wav, m, 30)
    assert take.meta.channels == ["jawOpen", "mouthClose", "lip_custom"]
    assert take.time[1] == pytest.approx(1 / 30) and take.time[0] == 0
    assert take.values[:, 2].min() == -0.5  # never clamped
    assert take.meta.audio.start_s == 0.0


def test_nan_frames_are_marked_invalid(tmp_path, wav):
    m = tmp_path / "m.npy"
    x = np.full((30, 2), 0.2)
    x[5, 1] = np.nan
    np.save(m, x)
    names = tmp_path / "n.txt"
    names.write_text("a\nb\n")
    take = read_paired(wav, m, 30, names)
    assert take.frame_status[5] == FrameStatus.BAD_VALUE and take.valid.sum() == 29
    assert take.meta.repairs[0]["kind"] == "bad_value"


def test_bad_inputs_give_clear_errors(tmp_path, wav):
    names = tmp_path / "n.txt"
    names.write_text("a\nb\nc\n")
    good = tmp_path / "m.npy"
    np.save(good, np.zeros((30, 2)))
    with pytest.raises(InputError, match="3 channel names for a matrix of 2 columns"):
        read_paired(wav, good, 30, names)
    pickled = tmp_path / "p.npy"
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="not a numeric or string"):
        read_paired(wav, pickled, 30, names)
    ragged = tmp_path / "r.csv"
    ragged.write_text("1,2\n3\n")
    with pytest.raises(InputError) as exc:
        read_paired(wav, ragged, 30, names)
    assert exc.value.line == 2
    text = tmp_path / "t.csv"
    text.write_text("a,b\n1,2\nx,3\n")
    with pytest.raises(InputError) as exc:
        read_paired(wav, text, 30)
    assert exc.value.line == 3
    with pytest.raises(InputError, match="positive frame rate"):
        read_paired(wav, good, 0, names)
    with pytest.raises(InputError, match="no channel names"):
        read_paired(wav, good, 30)
    dupes = tmp_path / "d.txt"
    dupes.write_text("a\nA\n")
    with pytest.raises(InputError, match="twice"):
        read_paired(wav, good, 30, dupes)


def test_cli_generic_import_needs_its_flags(tmp_path, wav):
    proc = run_here("capture", "import", "--matrix", tmp_path / "m.npy", "-o", tmp_path / "o")
    assert proc.returncode == 1 and "--matrix needs --audio" in proc.stderr


def _a2f_export(path, frames=45, fps=30, **override):
    """An Audio2Face blendshape export: ARKit pose names as A2F writes them, weights, joint tracks."""
    from capture.channels import ARKIT52

    rng = np.random.default_rng(2)
    data = {
        "exportFps": fps,
        "trackPath": "/World/audio2face/Player",
        "numPoses": 52,
        "numFrames": frames,
        "facsNames": list(ARKIT52),
        "weightMat": rng.uniform(0, 1, (frames, 52)).round(6).tolist(),
        "joints": ["jaw", "eye_L", "eye_R"],
        "rotations": [[[0, 0, 0, 1]] * 3] * frames,
        "translations": [[[0, 0, 0]] * 3] * frames,
    } | override
    path.write_text(json.dumps(data))
    return data


def test_audio2face_json_import_takes_names_and_rate_from_the_file(tmp_path, wav):
    data = _a2f_export(tmp_path / "a2f.json", frames=45, fps=30)
    proc = run_here(
        "capture", "import", "--matrix", tmp_path / "a2f.json", "--audio", wav, "-o", tmp_path / "o", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    take = read_take(json.loads(proc.stdout)["path"])
    assert take.meta.fps == 30 and take.values.shape == (45, 52)
    assert take.meta.channels[:3] == ["eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft"]
    np.testing.assert_allclose(take.values, np.array(data["weightMat"]), atol=1e-6)
    assert take.time[44] == pytest.approx(44 / 30)
    # --fps must agree with the file; names from a file replace facsNames
    with pytest.raises(InputError, match="--fps 60 but the file says 30"):
        read_paired(wav, tmp_path / "a2f.json", 60)
    assert read_paired(wav, tmp_path / "a2f.json", 30).meta.fps == 30


def test_names_mapped_from_under_an_exporters_prefix_are_a_warning(tmp_path, wav):
    """An export whose pose names all carry one prefix (``A2F_jawOpen``) imports them as the Live Link
    names they hold: said on stderr, not only in meta.json (a channel's identity changed)."""
    from capture.channels import ARKIT52

    _a2f_export(tmp_path / "a2f.json", facsNames=[f"A2F_{n}" for n in ARKIT52])
    proc = run_here(
        "capture", "import", "--matrix", tmp_path / "a2f.json", "--audio", wav, "-o", tmp_path / "o"
    )
    assert proc.returncode == 0, proc.stderr
    (line,) = [x for x in proc.stderr.splitlines() if "warning:" in x]
    assert "'A2F_'" in line and "eyeBlinkLeft" in line, line


@pytest.mark.parametrize(
    "override, needle",
    [
        ({"numFrames": 44}, "numFrames is 44 but the file holds 45"),
        ({"numPoses": 51}, "numPoses is 51 but the file holds 52"),
        ({"weightMat": [[0.1] * 52] * 10 + [[0.1] * 51]}, r"weightMat\[10\] holds 51 values, facsNames 52"),
        ({"weightMat": [[0.1] * 51 + ["x"]]}, r"weightMat\[0\] holds a value that is not a number"),
        ({"weightMat": []}, "weightMat must be a non-empty list"),
        ({"facsNames": "jawOpen"}, "facsNames must be a non-empty list of names"),
        ({"exportFps": "30"}, "exportFps must be a number"),
        ({"exportFps": 0}, r"frame rate must be in \[1, 1000\], not 0"),
        ({"exportFps": None}, "no frame rate: give --fps"),
    ],
)
def test_audio2face_json_errors_name_the_field(tmp_path, wav, override, needle):
    path = tmp_path / "bad.json"
    data = _a2f_export(path, frames=45)
    if "weightMat" in override:
        data["numFrames"] = None  # so that the rows themselves are checked
    path.write_text(json.dumps(data | override))
    with pytest.raises(InputError, match=needle):
        read_paired(wav, path, None)


def test_json_that_is_not_an_audio2face_export(tmp_path, wav):
    path = tmp_path / "x.json"
    path.write_text('{"frames": [1, 2]}')
    with pytest.raises(InputError, match="not an Audio2Face blendshape export"):
        read_paired(wav, path, 30)
    path.write_text("{not json")
    proc = run_here("capture", "import", "--matrix", path, "--audio", wav, "-o", tmp_path / "o")
    assert proc.returncode == 1 and "not a JSON file" in proc.stderr and "Traceback" not in proc.stderr


def test_time_and_frame_columns_place_the_frames(tmp_path, wav):
    """A generator's CSV with a time column (seconds) or a frame index: not a channel, the rate comes from
    it, gaps become DROPPED frames, and dotted names like blendShapes.JawOpen are ARKit channels."""
    rows = [i for i in range(30) if i not in (7, 8)]  # two frames missing
    m = tmp_path / "t.csv"
    m.write_text("timeCode,blendShapes.JawOpen,custom\n" + "".join(f"{i / 30:.6f},0.5,{i}\n" for i in rows))
    take = read_paired(wav, m, None)
    assert take.meta.fps == 30 and take.meta.channels == ["jawOpen", "custom"]
    assert take.time.size == 30 and take.count(FrameStatus.DROPPED) == 2
    assert take.time[9] == pytest.approx(9 / 30) and take.values[9, 1] == 9
    assert any(r["kind"] == "dropped_frames" for r in take.meta.repairs)
    f = tmp_path / "f.csv"
    f.write_text("frame,jawOpen\n" + "".join(f"{i},0.25\n" for i in range(1, 31)))
    with pytest.raises(InputError, match="no frame rate"):
        read_paired(wav, f, None)
    take = read_paired(wav, f, 60, first_frame=0)  # numbered from 0: frame 1 one period in
    assert take.time[0] == pytest.approx(1 / 60) and take.meta.channels == ["jawOpen"]
    take = read_paired(wav, f, 60)  # from 1, as timelines count: frame 1 at the audio's start
    assert take.time[0] == 0 and any(r["kind"] == "frame_numbers_from_1" for r in take.meta.repairs)
    bad = tmp_path / "b.csv"
    bad.write_text("time,jawOpen\n0.0,0.1\n0.0333,0.1\n0.0333,0.2\n")
    with pytest.raises(InputError, match="must be finite and increase"):
        read_paired(wav, bad, None)
    wrong = tmp_path / "w.csv"
    wrong.write_text("time,jawOpen\n" + "".join(f"{i / 30:.6f},0.1\n" for i in range(30)))
    with pytest.raises(InputError, match=r"step \(0.033333 s\) does not match 60 frames per second"):
        read_paired(wav, wrong, 60)


@pytest.mark.parametrize(
    "name, text, needle",
    [
        (
            "gap",
            "time,jawOpen\n" + "".join(f"{t:.4f},0.1\n" for t in [0, 1 / 30, 2 / 30, 36000.0, 36000.0333]),
            r"jumps by 35999.9 s after frame 3 \(more than 30 s",
        ),
        (
            "ms",
            "time,jawOpen\n" + "".join(f"{i * 33.3333:.4f},0.1\n" for i in range(30)),
            r"frame rate must be in \[1, 1000\], not 0.03 \(is the time column in milliseconds\?\)",
        ),
        (
            "late",
            "time,jawOpen\n" + "".join(f"{100 + i / 30:.4f},0.1\n" for i in range(30)),
            r"the frames \(100..100.967 s\) lie outside the audio \(0..1.000 s\)",
        ),
        (
            "dup",
            "jawOpen,blendShapes.JawOpen,x\n0.1,0.2,0.3\n",
            "channels 'jawOpen' and 'blendShapes.JawOpen' are the same",
        ),
        ("case", "a,A\n0.1,0.2\n", "channels 'a' and 'A' are the same channel"),
        ("blank", "time,,jawOpen\n0,0.1,0.2\n", "the header leaves a column without a name"),
        ("header_only", "time,jawOpen\n", "matrix has no frames"),
        ("underscore", "jawOpen\n1_0\n", "non-numeric value in the matrix"),
    ],
)
def test_generic_csv_mistakes_are_one_line_errors(tmp_path, wav, name, text, needle):
    path = tmp_path / f"{name}.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=needle):
        read_paired(wav, path, None if name in ("gap", "ms", "late") else 30)


@pytest.mark.parametrize(
    "raw, needle",
    [
        (
            '{"exportFps": 30, "facsNames": ["a"], "weightMat": [[1' + "0" * 400 + "]]}",
            "too large for a float",
        ),
        (
            '{"exportFps": 1' + "0" * 400 + ', "facsNames": ["a"], "weightMat": [[1]]}',
            "exportFps must be a frame rate",
        ),
        (
            '{"exportFps": 30, "facsNames": ["a"], "weightMat": ' + "[" * 100_000 + "]" * 100_000 + "}",
            "nested too deeply",
        ),
        ('{"exportFps": 30, "numFrames": true, "facsNames": ["a"], "weightMat": [[1]]}', "numFrames is True"),
        ('{"exportFps": 30, "facsNames": [], "weightMat": [[]]}', "facsNames must be a non-empty list"),
        (
            '{"exportFps": 30, "facsNames": ["jawOpen", "JawOpen"], "weightMat": [[1, 2]]}',
            "are the same channel",
        ),
    ],
)
def test_audio2face_json_edge_cases(tmp_path, wav, raw, needle):
    path = tmp_path / "x.json"
    path.write_text(raw)
    proc = run_here("capture", "import", "--matrix", path, "--audio", wav, "-o", tmp_path / "o")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert needle in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
