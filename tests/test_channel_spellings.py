"""Live Link channel names in the spellings other tools write (snake_case, ``_L``/``_R`` sides, namespace and
path prefixes), never a rig's own controls; and ``export-csv`` of a take that has few or none of them."""

from __future__ import annotations

import re

import numpy as np
import pytest
from conftest import import_rig_take, run_here

from capture import FrameStatus, Take, TakeMeta, read_take, write_take
from capture import channels as ch
from capture.csv_take import read_livelink_csv

NEUROSYNC = "paired/neurosync-trainer-lite-testset"
FACEGOOD = "paired/facegood-audio2face"

SPELLINGS = [
    ("jaw_open", "jawOpen"),
    ("JAW_OPEN", "jawOpen"),
    ("mouth_smile_left", "mouthSmileLeft"),
    ("Mouth_Smile_Right", "mouthSmileRight"),
    ("eyeBlink_L", "eyeBlinkLeft"),  # ARKit's own raw names
    ("eyeBlink_R", "eyeBlinkRight"),
    ("eyeBlink_l", "eyeBlinkLeft"),
    ("MouthSmile_L", "mouthSmileLeft"),
    ("Eye_Blink_L", "eyeBlinkLeft"),  # Reallusion's style
    ("EYE_BLINK_R", "eyeBlinkRight"),
    ("mouthSmile_Left", "mouthSmileLeft"),
    ("eye_look_up_left", "eyeLookUpLeft"),
    ("eyeLookUp_R", "eyeLookUpRight"),
    ("jaw_L", "jawLeft"),
    ("mouth_R", "mouthRight"),
    ("mouth_left", "mouthLeft"),
    ("left_eye_yaw", "leftEyeYaw"),
    ("head_pitch", "headPitch"),
    ("Maya:jawOpen", "jawOpen"),
    ("rig:face:eyeBlink_L", "eyeBlinkLeft"),
    ("/World/Face/jawOpen", "jawOpen"),
    ("|face_GRP|mouth_close", "mouthClose"),
    ("blendShapes.JawOpen", "jawOpen"),
    (" cheekPuff ", "cheekPuff"),
]
NOT_CHANNELS = [
    "eye_blink_l",  # all lower case with a one-letter side: how rigs name their own controls
    "mouth_dimple_l",
    "jaw_l",
    "eyeblink_r",
    "eyeBlinkL",  # no separator: mouthL would be mouthLeft and mouth + left alike
    "cheekPuff_L",  # not a left/right channel
    "jawOpen_L",
    "eye_lookUp_l",  # FACEGOOD's: lookUp is no ARKit word
    "jaw_open_c",
    "jawOpen.",
    "Maya:",
    "",
]


@pytest.mark.parametrize("name, channel", SPELLINGS)
def test_spellings_other_tools_write_are_the_channel(name, channel):
    assert ch.is_known(name) and ch.canonical(name) == channel
    assert ch.udp_index(name) == ch.ARKIT61.index(channel)
    assert ch.livelink_name(name) == channel[0].upper() + channel[1:]


@pytest.mark.parametrize("name", NOT_CHANNELS)
def test_names_that_are_no_channel(name):
    assert not ch.is_known(name)
    with pytest.raises(ch.InputError, match="unknown Live Link channel"):
        ch.canonical(name)


def _variants(pascal: str) -> list[str]:
    """Every spelling of one channel the module accepts (written out here, not taken from it)."""
    words = re.findall(r"[A-Z][a-z]*", pascal)
    camel = pascal[0].lower() + pascal[1:]
    snake = "_".join(w.lower() for w in words)
    out = [
        pascal,
        camel,
        camel.upper(),
        snake,
        snake.upper(),
        "_".join(words),
        f"ns:{camel}",
        f"/a/b/{snake}",
    ]
    if len(words) > 1 and words[-1] in ("Left", "Right"):
        base, side = "".join(words[:-1]), words[-1]
        snake_base = "_".join(w.lower() for w in words[:-1])
        out += [f"{base}_{side}", f"{base}_{side[0]}", f"{base[0].lower() + base[1:]}_{side[0]}"]
        out += [
            f"{snake_base}_{side.lower()}",
            f"{snake_base}_{side[0]}",
            f"{'_'.join(words[:-1])}_{side[0]}",
        ]
    return out


def test_no_spelling_names_two_channels():
    """Each channel's spellings lead to it and to no other: two channels never share one."""
    owner: dict[str, str] = {}
    for pascal in ch.LIVELINK_ORDER:
        for name in _variants(pascal):
            assert ch.livelink_name(name) == pascal, name
            assert owner.setdefault(name.lower(), pascal) == pascal, (name, owner[name.lower()], pascal)
    assert len(owner) > 61 * 5


def test_no_facegood_control_is_a_live_link_channel(samples):
    """FACEGOOD's 116 rig controls stay its own, though mouth_dimple_l and mouth_press_l read like snake_case
    ARKit names: a one-letter side in lower case is not taken for one."""
    names = (samples / FACEGOOD / "bs_names.txt").read_text().split()
    assert len(names) == 116 and "mouth_dimple_l" in names and "mouth_press_r" in names
    assert [n for n in names if ch.is_known(n)] == []


def test_a_paired_csv_in_other_spellings_imports_and_exports_as_live_link(samples, tmp_path):
    """NeuroSync's 52 channels under the spellings of other tools: the take holds the canonical names,
    and its Live Link Face CSV their values (the names were kept as given, and exported as zeros)."""
    truth = read_livelink_csv(samples / NEUROSYNC / "testset.csv")
    names = ch.LIVELINK_ORDER[:52]
    spelled = [_variants(n)[3 + k % (len(_variants(n)) - 3)] for k, n in enumerate(names)]  # not camelCase
    assert not any(s.lower() == n.lower() for s, n in zip(spelled, names))
    values = np.stack([truth.channel(ch.arkit_name(n)) for n in names], 1)
    matrix = tmp_path / "spelled.csv"
    matrix.write_text(
        ",".join(spelled) + "\n" + "".join(",".join(f"{v:.6f}" for v in r) + "\n" for r in values)
    )
    takes = tmp_path / "takes"
    audio = samples / NEUROSYNC / "audio.wav"
    proc = run_here("capture", "import", "--matrix", matrix, "--fps", 60, "--audio", audio, "-o", takes)
    assert proc.returncode == 0, proc.stderr
    take = read_take(takes / "spelled", audio=False)
    assert take.meta.channels == [ch.arkit_name(n) for n in names]
    out = tmp_path / "spelled_out.csv"
    proc = run_here("capture", "export-csv", takes / "spelled", "-o", out)
    assert proc.returncode == 0 and "warning" not in proc.stderr, proc.stderr
    header, *rows = out.read_text().splitlines()
    col = header.split(",").index("JawOpen")
    jaw = np.array([float(r.split(",")[col]) for r in rows])
    assert np.allclose(jaw, truth.channel("jawOpen"), atol=1e-6) and jaw.max() > 0.3


def test_export_csv_refuses_a_take_without_live_link_channels(samples, tmp_path):
    """A FACEGOOD take used to give a 61-column CSV of zeros and exit 0."""
    out = tmp_path / "rig.csv"
    proc = run_here("capture", "export-csv", import_rig_take(samples, tmp_path), "-o", out)
    assert proc.returncode == 1 and not out.exists()
    (line,) = proc.stderr.splitlines()
    assert line.startswith("s2a-capture: error: ") and "takes/rig" in line
    assert "none of the 61 Live Link Face channels" in line and "116 channels" in line
    assert "brow_lower_l, tongue_Scale_X, tongue_Scale__X, ..." in line


def test_export_csv_warns_of_the_channels_it_leaves_out(samples, tmp_path):
    """A take holding Live Link channels (in other tools' spellings too) and a rig's own controls: the
    CSV holds the first, and a warning says how many of the others are left out."""
    truth = read_livelink_csv(samples / NEUROSYNC / "testset.csv")
    names = ["jaw_open", "eyeBlink_L", "Maya:mouthClose", "mouth_dimple_l", "brow_raise_c"]
    n = 120
    values = np.stack([truth.channel("jawOpen")[:n], *(np.full(n, 0.25 * k) for k in range(1, 5))], 1)
    meta = TakeMeta(id="mixed", source_kind="paired_matrix", fps=60.0, channels=names)
    write_take(Take(meta, np.arange(n) / 60.0, values.astype(np.float32), np.zeros(n, np.uint8)), tmp_path)
    assert FrameStatus.TRACKED == 0
    out = tmp_path / "mixed.csv"
    proc = run_here("capture", "export-csv", tmp_path / "mixed", "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    assert '"channels_left_out": 2' in proc.stdout
    (line,) = [x for x in proc.stderr.splitlines() if "warning" in x]
    assert "2 of its 5 channels are not Live Link Face channels" in line
    assert "(mouth_dimple_l, brow_raise_c)" in line
    header, first, *_ = out.read_text().splitlines()
    row = dict(zip(header.split(","), first.split(",")))
    assert float(row["EyeBlinkLeft"]) == 0.25 and float(row["MouthClose"]) == 0.5
    assert float(row["JawOpen"]) == pytest.approx(truth.channel("jawOpen")[0], abs=1e-6)
