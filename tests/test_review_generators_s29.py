"""Second review of the other capture apps' import (MediaPipe's ``_neutral`` and emotion weights left out,
Face Cap's text export, iFacialMocap's stream text, JSON of other layouts): what it left out, each
imported with ``s2a-capture import`` as a user would."""

from __future__ import annotations

import json

import numpy as np
from conftest import run_cli
from test_generators_s29 import face_cap_txt, imported, refused, silence

from capture.channels import ARKIT52, LIVELINK_ORDER

NEUROSYNC_EMOTIONS = ["Angry", "Disgusted", "Fearful", "Happy", "Neutral", "Sad", "Surprised"]


def weights_csv(path, names: list[str], seconds: float = 1) -> np.ndarray:
    """A 30 fps CSV of weights under a ``time`` column and ``names``."""
    values = np.random.default_rng(5).uniform(0, 1, (int(seconds * 30), len(names))).round(5)
    rows = [f"{i / 30:.6f}," + ",".join(map(str, row)) for i, row in enumerate(values)]
    path.write_text("\n".join([",".join(["time", *names]), *rows]) + "\n")
    return values


def test_an_avatars_own_expressions_beside_arkit_are_kept(tmp_path):
    """A VRM avatar's expression presets beside its 52 ARKit shapes (perfect sync) are its own face
    channels: Joy, Angry and Neutral were left out as "emotion weights" while Sorrow and Fun were kept.
    Only a generator's whole set of emotions (NeuroSync's 7) is left out."""
    audio = silence(tmp_path / "a.wav", 1)
    presets = ["Joy", "Angry", "Sorrow", "Fun", "Neutral"]
    values = weights_csv(tmp_path / "vrm.csv", [*ARKIT52, *presets])
    take = imported(tmp_path / "t1", "--matrix", tmp_path / "vrm.csv", "--audio", audio)
    assert take.meta.channels == [*ARKIT52, *presets] and np.allclose(take.values, values)
    assert "side_scores" not in [r["kind"] for r in take.meta.repairs]
    weights_csv(tmp_path / "gen.csv", [*LIVELINK_ORDER[:52], *NEUROSYNC_EMOTIONS])
    take = imported(tmp_path / "t2", "--matrix", tmp_path / "gen.csv", "--audio", audio)
    assert take.meta.channels == list(ARKIT52)


def test_ifacialmocap_version_2_stream_text_is_named(tmp_path):
    """iFacialMocap sends ``name&value`` (values perhaps negative) when asked for its data version 2
    (iOS app 1.1.8 on); saved a frame a line it was "non-numeric value in the matrix: '<the line>'"."""
    line = "trackingStatus&1|mouthSmile_R&-12.5|jawOpen&35|=head#-21.4,-6.0,-6.6,-0.03,-0.1,-0.6|"
    line += "rightEye#6.0,2.4,0.2|leftEye#6.0,-1.6,-0.1|"
    (tmp_path / "ifm.txt").write_text("\n".join([line] * 30) + "\n")
    message = refused(tmp_path, "--matrix", tmp_path / "ifm.txt", "--audio", silence(tmp_path / "a.wav", 1))
    assert "iFacialMocap's stream text" in message and "non-numeric" not in message


def test_a_long_cell_of_digits_is_refused_at_once(tmp_path):
    """A cell of 130,000 digits and a letter (below the csv module's cell limit) was matched against the
    digit-group pattern at every split of its digits: minutes to hours before the one-line error."""
    (tmp_path / "m.csv").write_text("jawOpen,mouthClose\n0.1," + "1" * 130_000 + "x\n")
    args = ["--matrix", tmp_path / "m.csv", "--audio", silence(tmp_path / "a.wav", 1), "--fps", 30]
    proc = run_cli("capture", "import", *args, "-o", tmp_path / "out")  # run_cli's timeout: 300 s
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1, proc.stderr
    assert "non-numeric value in the matrix: '111" in lines[0] and "digits grouped" not in lines[0]


def test_a_line_past_the_csv_cell_limit_is_a_one_line_error(tmp_path):
    """A first line longer than the csv module's cell limit (131,072 characters) in no separator's cells
    was a traceback (_csv.Error) while the separator was found."""
    (tmp_path / "m.csv").write_text("a" * 200_000 + "\n")
    message = refused(
        tmp_path, "--matrix", tmp_path / "m.csv", "--audio", silence(tmp_path / "a.wav", 1), "--fps", 30
    )
    assert "m.csv:1: not a CSV row (field larger than field limit" in message


def test_a_header_repeated_in_the_rows_is_named(tmp_path):
    """Two CSVs joined one after another hold the header again among the rows; the new hint said it was
    a blendshape's name in a column of names, one row per blendshape and frame."""
    (tmp_path / "joined.csv").write_text("jawOpen,mouthClose\n0.1,0.2\njawOpen,mouthClose\n0.3,0.4\n")
    message = refused(
        tmp_path, "--matrix", tmp_path / "joined.csv", "--audio", silence(tmp_path / "a.wav", 1), "--fps", 30
    )
    assert "joined.csv:3: non-numeric value in the matrix: 'jawOpen' in column 'jawOpen'" in message
    assert "the header row again" in message and "one row per blendshape" not in message
    (tmp_path / "log.csv").write_text("V,0,1\nV,1,2\n")  # no header: a first row of data with a letter
    message = refused(tmp_path, "--matrix", tmp_path / "log.csv", "--audio", tmp_path / "a.wav", "--fps", 30)
    assert "log.csv:2: non-numeric value in the matrix: 'V' in column 'V'" in message
    assert "header row again" not in message


def test_a_json_of_long_keys_is_said_short(tmp_path):
    """The keys a JSON of another layout holds were said whole: a key of 100,000 characters made an error
    line as long."""
    (tmp_path / "o.json").write_text(json.dumps({"k" * 100_000: 1, "fps": 30}))
    message = refused(tmp_path, "--matrix", tmp_path / "o.json", "--audio", silence(tmp_path / "a.wav", 1))
    assert "holds an object of 'kkk" in message and "'fps'" in message and len(message) < 400


def test_a_face_cap_line_cut_short_before_its_weights(tmp_path):
    """A k line holding fewer values than the time and the head and eye pose was said to hold a negative
    number of weights ("k line holds -8 weights")."""
    face_cap_txt(tmp_path / "fc.txt", 1)
    text = (tmp_path / "fc.txt").read_text()
    (tmp_path / "fc.txt").write_text(text + "k,1000,0.01,0.02,0.03\n")  # the app stopped mid-line
    message = refused(tmp_path, "--matrix", tmp_path / "fc.txt", "--audio", silence(tmp_path / "a.wav", 2))
    assert "fc.txt:63: k line holds 4 values, fewer than the time and 10 head and eye values" in message
    assert "-" not in message.split("k line holds")[1]


def test_an_emotion_label_among_the_rows_is_no_blendshape_name(tmp_path):
    """A column of emotion labels (``Happy``) in a table of a row per frame was said to hold a blendshape's
    name, one row per blendshape and frame (MediaPipe's categories are ARKit's names and ``_neutral``)."""
    (tmp_path / "l.csv").write_text("time,jawOpen,label\n0,0.1,Happy\n0.033,0.2,Happy\n")
    message = refused(tmp_path, "--matrix", tmp_path / "l.csv", "--audio", silence(tmp_path / "a.wav", 1))
    assert "l.csv:2: non-numeric value in the matrix: 'Happy' in column 'label'" in message
    assert "blendshape" not in message
