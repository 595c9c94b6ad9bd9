"""``s2a-capture import`` warnings (session 22): repairs that may move the sound against the face or drop a
channel were only counted in the summary and listed in meta.json (``bad_audio``: MP3 frames lost to damage
put back as silence, perhaps shifting the sound after them; ``empty_channel``: a channel left out), now
printed as warnings; every stage's warning names its program (``s2a-capture: warning: ...``, as argparse's
errors), which a pipeline's log shared by several stages needs; and a CSV in the Live Link Face app's layout
read as generic paired data no longer keeps ``BlendShapeCount`` as a channel holding 61."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_cli
from test_audio_mp3_channel_change import joined, mp3
from test_import_mp3_damage import _damaged, _mp3
from test_readers_review_s22 import rows, write_csv

from capture.channels import CSV_ORDER
from capture.cli import WARN_REPAIRS
from capture.command import StageParser, run, warn

WARNING = "s2a-capture: warning: "


def _float_wav_with_nan(path: Path, seconds: float = 3.0, rate: int = 16000) -> Path:
    audio = (0.1 * np.sin(np.arange(round(seconds * rate)) / 10)).astype(np.float32)
    audio[rate : rate + 5] = np.nan
    sf.write(path, audio, rate, subtype="FLOAT")
    return path


def _damaged_untagged_mp3(path: Path) -> Path:
    path.write_bytes(_damaged(_mp3(22050, 1, 64000, False), (0.5, 600)))  # no Info frame, no LAME tag
    return path


def _mono_then_stereo_mp3(path: Path) -> Path:
    return joined(path, mp3(path.with_name("a.mp3"), 1, 1.0, 440), mp3(path.with_name("b.mp3"), 2, 2.0, 660))


AUDIO = {  # audio beside a 3 s CSV, and the repairs of it that the import must warn of
    "damaged_untagged_mp3": (_damaged_untagged_mp3, "audio.mp3", ["bad_audio", "encoder_delay_unknown"]),
    "mono_then_stereo_mp3": (_mono_then_stereo_mp3, "audio.mp3", ["channels_changed"]),
    "float_wav_with_nan": (_float_wav_with_nan, "audio.wav", ["bad_audio"]),
}


def _repairs(take: Path, kind: str) -> list[str]:
    return [
        r["message"] for r in json.loads((take / "meta.json").read_text())["repairs"] if r["kind"] == kind
    ]


@pytest.mark.parametrize("case", list(AUDIO))
def test_repairs_that_may_shift_sync_or_drop_a_channel_are_warnings(tmp_path, case):
    """A 3 s CSV whose 9 head and eye angle columns are empty on every row, with damaged or joined audio:
    each such repair of meta.json is a warning line naming the CSV, and ``--json`` still writes one JSON
    summary alone on stdout."""
    make, name, kinds = AUDIO[case]
    csv = write_csv(tmp_path / "take.csv", [row.rsplit(",", 9)[0] + "," * 9 for row in rows(180)])
    proc = run_cli(
        "capture", "import", csv, "--audio", make(tmp_path / name), "-o", tmp_path / "out", "--json"
    )
    assert proc.returncode == 0, proc.stderr
    (summary,) = [json.loads(line) for line in proc.stdout.splitlines()]
    take = Path(summary["path"])
    lines = proc.stderr.splitlines()
    for kind in ["empty_channel", *kinds]:
        messages = _repairs(take, kind)
        assert messages, (kind, proc.stderr)
        assert all(f"{WARNING}{csv}: {m}" in lines for m in messages), (kind, proc.stderr)
    if case == "damaged_untagged_mp3":  # lost frames counted from the bytes: the sound after may be off
        assert any("may be shifted by up to" in line for line in lines), proc.stderr
    warned = [r for r in json.loads((take / "meta.json").read_text())["repairs"] if r["kind"] in WARN_REPAIRS]
    assert len([x for x in lines if x.startswith(WARNING)]) == len(warned), proc.stderr


def test_warnings_of_paired_import_and_export_name_the_program(tmp_path):
    """A time column without its unit read in milliseconds, float audio with NaN samples: both warned of;
    writing the take back as a Live Link Face CSV warns of the rig's own channel left out, named by the
    program like every other warning (it was a bare ``warning: ...``)."""
    stamps = np.arange(90) * 1000 / 30
    matrix = tmp_path / "rig.csv"
    matrix.write_text("pts,jawOpen,myCtrl\n" + "".join(f"{t:.3f},0.2,0.5\n" for t in stamps))
    wav = _float_wav_with_nan(tmp_path / "rig.wav")
    proc = run_cli("capture", "import", "--matrix", matrix, "--audio", wav, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    for kind in ("time_unit", "bad_audio"):
        (message,) = _repairs(tmp_path / "out" / "rig", kind)
        assert f"{WARNING}{matrix}: {message}" in proc.stderr.splitlines(), proc.stderr
    proc = run_cli("capture", "export-csv", tmp_path / "out" / "rig", "-o", tmp_path / "back.csv")
    assert proc.returncode == 0, proc.stderr
    (line,) = [x for x in proc.stderr.splitlines() if "warning:" in x]
    assert line.startswith(f"{WARNING}rig: 1 of its 2 channels are not Live Link Face channels"), line


def test_warn_names_the_stage_whose_command_runs(capsys):
    """``warn`` prefixes the program ``run`` was given while its command runs, the toolkit's name outside
    one (a library call)."""
    assert run("s2a-align", lambda: StageParser(prog="s2a-align"), lambda args: warn("inside") or 0, []) == 0
    warn("outside")
    assert capsys.readouterr().err.splitlines() == ["s2a-align: warning: inside", "s2a: warning: outside"]


@pytest.mark.parametrize(
    "time_name, count_name, how",
    [("Timecode", "BlendShapeCount", "--matrix"), ("time", "blendshapecount", "--pair-audio")],
)
def test_the_count_column_of_the_apps_layout_is_no_paired_channel(tmp_path, time_name, count_name, how):
    """The app's layout with plain-number times, read as generic paired data: its 61 channels, not 62
    with ``BlendShapeCount`` first; a note says the column was left out."""
    header = f"{time_name},{count_name}," + ",".join(CSV_ORDER)
    cells = ",".join(["0.1"] * len(CSV_ORDER))
    csv = tmp_path / "face.csv"
    csv.write_text(header + "\n" + "".join(f"{i / 30:.6f},61,{cells}\n" for i in range(60)))
    wav = tmp_path / "face.wav"
    sf.write(wav, np.zeros(32000, np.float32), 16000)
    args = ["--matrix", csv, "--audio", wav] if how == "--matrix" else [csv, "--pair-audio"]
    proc = run_cli("capture", "import", *args, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((tmp_path / "out" / "face" / "meta.json").read_text())
    assert meta["source_kind"] == "paired_matrix"
    assert len(meta["channels"]) == 61 and "blendshapecount" not in [c.lower() for c in meta["channels"]]
    (note,) = [r["message"] for r in meta["repairs"] if r["kind"] == "count_column"]
    assert repr(count_name) in note
