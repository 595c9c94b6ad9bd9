"""Generic paired import: audio + frames x channels matrix + names + fps, from any rig."""

import numpy as np
import pytest
import soundfile as sf

from capture import FrameStatus, InputError, read_paired
from tests.conftest import run_cli


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
    proc = run_cli("capture", "import", "--matrix", tmp_path / "m.npy", "-o", tmp_path / "o")
    assert proc.returncode == 1 and "--matrix needs --audio and --fps" in proc.stderr
