"""Bad input to ``s2a-view``: one-line errors that name what the user gave, warnings for what was
repaired, bridged or clamped, and never a silently dropped take or a blank face. Inputs are cut from
the real Live Link Face samples; commands run as subprocesses."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import import_rig_take, run_here
from dataset_helpers import make_aligned_take
from live_helpers import datagrams, udp_receiver

from capture import livelink as ll
from capture import read_livelink_csv, read_take, write_take

CAL = "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"  # 60 fps, the app's own naming
ROWS = 60  # one second: enough for every check, cheap to read, render and stream


def _one_line_error(proc, *needles: str) -> str:
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert ".partial" not in lines[0]
    return lines[0]


def _json(proc) -> dict:
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _lines(samples: Path) -> list[str]:
    """The header and the first ``ROWS`` rows of the real calibrated take."""
    with open(samples / CAL, encoding="utf-8") as f:
        return [next(f) for _ in range(ROWS + 1)]


def _cell(line: str, column: int, value: str) -> str:
    cells = line.rstrip("\n").split(",")
    cells[column] = value
    return ",".join(cells) + "\n"


def _column(header: str, name: str) -> int:
    return [c.strip().lower() for c in header.split(",")].index(name.lower())


@pytest.fixture
def short_csv(samples, tmp_path) -> Path:
    path = tmp_path / "short" / "MySlate_166_iPhone_cal.csv"
    path.parent.mkdir()
    path.write_text("".join(_lines(samples)), encoding="utf-8")
    return path


# -- 5: a folder holding several takes ---------------------------------------------------------------
def test_render_and_plot_refuse_a_folder_of_several_takes(samples, tmp_path):
    folder = tmp_path / "two"
    folder.mkdir()
    for name in ("alexdjulin_S07/S07-001.csv", "alexdjulin_S88/S88-001.csv"):
        shutil.copy(samples / "livelinkface" / name, folder)
    for cmd, out in (("render", "f.png"), ("plot", "p.png")):
        proc = run_here("viewer", cmd, folder, "-o", tmp_path / out)
        line = _one_line_error(proc, "found 2 takes under it", "S07-001.csv", "S88-001.csv")
        assert line.startswith(f"s2a-view: error: {folder}: {cmd} ")
        assert not (tmp_path / out).exists()


def test_the_variants_of_one_take_in_a_folder_are_one_take(samples, tmp_path):
    folder = tmp_path / "take"
    folder.mkdir()
    text = "".join(_lines(samples))
    (folder / "MySlate_166_iPhone_cal.csv").write_text(text, encoding="utf-8")
    (folder / "MySlate_166_iPhone_raw.csv").write_text(text, encoding="utf-8")
    s = _json(run_here("viewer", "plot", folder, "-o", tmp_path / "p.png", "--json"))
    assert len(s["inputs"]) == 1 and (tmp_path / "p.png").is_file()


# -- 6: --time is checked like --frame ---------------------------------------------------------------
@pytest.mark.parametrize(
    ("option", "value", "needle"),
    [
        ("--time", "nan", "argument --time: "),  # values no take allows: usage errors (exit 2)
        ("--time", "inf", "argument --time: "),
        ("--time", "-5", "argument --time: "),
        ("--time", "1e9", "--time 1e+09 s is outside the take's 0..0.98"),  # past this take's end: exit 1
        ("--frame", "100000", "--frame 100000 is outside 0..59"),
    ],
)
def test_render_checks_time_and_frame_before_rendering(short_csv, tmp_path, option, value, needle):
    out = tmp_path / "f.png"
    proc = run_here("viewer", "render", short_csv, "-o", out, option, value, "--json")
    if needle.startswith("argument"):
        assert proc.returncode == 2 and needle in proc.stderr.strip().splitlines()[-1], proc.stderr
    else:
        _one_line_error(proc, needle)
    assert not out.exists()


# -- 9: report --limit -------------------------------------------------------------------------------
def test_report_limit_bounds_thumbnails_and_refuses_negative_values(short_csv, tmp_path):
    take = read_livelink_csv(short_csv)
    for tid in ("take_a", "take_b"):
        take.meta.id = tid
        write_take(take, tmp_path / "takes")
    out = tmp_path / "r.html"
    proc = run_here("viewer", "report", tmp_path / "takes", "-o", out, "--limit", "-1")
    assert proc.returncode == 2 and "argument --limit" in proc.stderr, proc.stderr  # a usage error
    assert not out.exists()
    for limit, thumbs in (("0", 0), ("1", 1)):
        s = _json(run_here("viewer", "report", tmp_path / "takes", "-o", out, "--limit", limit, "--json"))
        assert s["takes"] == 2 and s["thumbnails"] == thumbs  # every take listed, never one dropped
        assert "take_a" in out.read_text() and "take_b" in out.read_text()


def test_report_finds_outliers_among_takes_without_thumbnails(tmp_path):
    """The mouth-level outliers are computed over every take, not only those shown as thumbnails."""
    from dataset_helpers import make_aligned_take

    from dataset import BuildOptions, build_dataset
    from dataset.splits import SplitRule
    from viewer.report import gather

    for i in range(6):
        take = make_aligned_take(f"t{i}", 2.0, subject="a", seed=i)
        if i == 5:  # last by id and by path: beyond --limit 1
            take.values[:, take.meta.channels.index("jawOpen")] = 0.95
        write_take(take, tmp_path / "takes")
    options = BuildOptions(features=("energy", "fbank"), split=SplitRule("take", 0.0, 0.0))
    build_dataset([tmp_path / "takes"], tmp_path / "ds", options, say=lambda _m: None)
    for source in (tmp_path / "takes", tmp_path / "ds"):
        for limit in (0, 1, 500):
            flagged = {e["take"]: e["reasons"] for e in gather(source, limit=limit)["takes"] if e["reasons"]}
            assert list(flagged) == ["t5"] and "jawOpen p95 0.950" in flagged["t5"][0], (source, limit)


# -- 10: absurd values -------------------------------------------------------------------------------
@pytest.fixture
def absurd_csv(samples, tmp_path) -> Path:
    """Row 9 holds 1e30 in MouthClose; row 20 a JawOpen of 1.5 and a MouthFunnel of -0.25."""
    lines = _lines(samples)
    lines[10] = _cell(lines[10], _column(lines[0], "MouthClose"), "1e30")
    lines[21] = _cell(lines[21], _column(lines[0], "JawOpen"), "1.5")
    lines[21] = _cell(lines[21], _column(lines[0], "MouthFunnel"), "-0.25")
    path = tmp_path / "absurd.csv"
    path.write_text("".join(lines), encoding="utf-8")
    return path


def test_render_bridges_an_absurd_frame_and_clamps_weights(absurd_csv, tmp_path):
    out = tmp_path / "f.png"
    proc = run_here("viewer", "render", absurd_csv, "-o", out, "--frame", "9", "--size", "96", "--json")
    s = _json(proc)
    assert s["bad_values"] == [1] and s["clamped_values"] == [2]
    assert "1 frame(s) hold NaN, infinite or absurd (beyond ±10) values" in proc.stderr
    assert "2 blendshape value(s) outside 0..1 clamped" in proc.stderr
    import cv2

    img = cv2.imread(str(out))
    assert img is not None and img.std() > 20  # a face, not the blank background of a mesh blown apart


def test_bridged_and_clamped_weights(absurd_csv):
    from viewer.render import load_animation

    anim = load_animation(absurd_csv)
    jaw, close, funnel = 17, 18, 19  # ARKIT61 order
    assert anim.bad_values == 1 and anim.clamped == 2
    assert np.all(np.abs(anim.weights) <= 1.0)
    assert anim.weights[9, close] == pytest.approx((anim.weights[8, close] + anim.weights[10, close]) / 2)
    assert anim.weights[20, jaw] == 1.0 and anim.weights[20, funnel] == 0.0
    raw = load_animation(absurd_csv, clamp=False)  # what plot draws: the values as they are
    assert raw.clamped == 0 and raw.weights[20, jaw] == pytest.approx(1.5)


def test_stream_sends_an_absurd_frame_as_no_face_and_counts_it(absurd_csv):
    with udp_receiver() as sock:
        to = f"127.0.0.1:{sock.getsockname()[1]}"
        proc = run_here("viewer", "stream", absurd_csv, "--to", to, "--speed", "50", "--json")
        packets = datagrams(sock)
    s = _json(proc)
    assert s["bad_values"] == 1 and s["outside_0_1"] == 2
    assert "1 frames with NaN/inf values sent as no-face packets" in proc.stderr
    assert "2 blendshape value(s) outside 0..1 are sent as they are" in proc.stderr
    values = []
    for p in packets:
        offset, reason = ll.parse_header(p)
        assert reason is None
        if len(p) > offset + ll.FRAME_TIME_BYTES:
            values.append(np.frombuffer(p[-4 * ll.BLENDSHAPE_COUNT :], dtype=">f4"))
    assert len(packets) == ROWS and len(values) == ROWS - 1
    assert all(np.all(np.abs(v) <= 10) for v in values)


# -- 12: errors name the path the user gave ----------------------------------------------------------
@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_write_errors_name_the_given_path_and_the_reason(short_csv, tmp_path):
    takes = tmp_path / "takes"
    write_take(read_livelink_csv(short_csv), takes)
    for args, path, what in [
        (["plot", short_csv, "-o", "/proc/p.png"], "/proc/p.png", "cannot write the plot"),
        (["report", takes, "-o", "/proc/r.html"], "/proc/r.html", "cannot write the report"),
        (["render", short_csv, "-o", "/proc/f.png", "--size", "32"], "/proc/f.png", "cannot write the image"),
    ]:
        line = _one_line_error(run_here("viewer", *args), f"{path}: {what}: /proc does not take new files")
        assert "unknown extension" not in line


def test_export_face_refuses_a_folder_and_names_that_are_not_glb(tmp_path):
    folder = tmp_path / "v.glb"
    folder.mkdir()
    _one_line_error(run_here("viewer", "export-face", "-o", folder), f"{folder}: is a folder")
    assert list(folder.iterdir()) == [] and [p.name for p in tmp_path.iterdir()] == ["v.glb"]
    for name in ("face.gltf", "face.obj"):
        _one_line_error(run_here("viewer", "export-face", "-o", tmp_path / name), "ending in .glb")
        assert not (tmp_path / name).exists()


def test_an_empty_csv_error_names_no_capture_option(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.touch()
    other = tmp_path / "matrix.csv"
    other.write_text("jawOpen,mouthClose\n0.1,0.2\n", encoding="utf-8")
    for args in (["render", empty, "-o", tmp_path / "f.png"], ["plot", empty, "-o", tmp_path / "p.png"]):
        line = _one_line_error(run_here("viewer", *args), f"{empty}: file is empty")
        assert "--pair-audio" not in line
    line = _one_line_error(run_here("viewer", "stream", other, "--to", "127.0.0.1:9"), "--audio FILE")
    assert "--pair-audio" not in line


# -- 13: rows the reader dropped, NaN audio ----------------------------------------------------------
def test_rows_the_reader_dropped_are_warned_about(samples, tmp_path):
    lines = _lines(samples)
    lines[3] = "garbage" + lines[3][lines[3].index(",") :]  # line 4: a bad timecode
    lines[6] = ",".join(lines[6].split(",")[:10]) + "\n"  # line 7: too few fields
    lines[8] = ",".join(lines[8].split(",")[:10]) + "\n"  # line 9: too few fields
    csv = tmp_path / "rows.csv"
    csv.write_text("".join(lines), encoding="utf-8")
    proc = run_here("viewer", "plot", csv, "-o", tmp_path / "p.png", "--json")
    assert proc.returncode == 0, proc.stderr
    warnings = [w for w in proc.stderr.splitlines() if w.startswith("s2a-view: warning:")]
    assert f"warning: {csv}:4: timecode 'garbage'" in proc.stderr
    assert f"warning: {csv}:7: row has 10 fields" in proc.stderr and "(and 1 more like it)" in proc.stderr
    assert len(warnings) == 2


def test_nan_audio_is_refused(short_csv, tmp_path):
    x = np.sin(np.arange(16000) * 0.05).astype(np.float32) * 0.3
    x[4000:4100] = np.nan
    wav = tmp_path / "nan.wav"
    sf.write(wav, x, 16000, subtype="FLOAT")
    for cmd, out in (("plot", "p.png"), ("render", "f.png")):
        proc = run_here("viewer", cmd, short_csv, "--audio", wav, "-o", tmp_path / out)
        _one_line_error(proc, f"{wav}: the audio holds NaN or infinite samples")
        assert not (tmp_path / out).exists()
    take = read_take(write_take(read_livelink_csv(short_csv), tmp_path / "takes"))
    folder = tmp_path / "takes" / take.meta.id
    proc = run_here("viewer", "plot", folder, "--audio", wav, "-o", tmp_path / "p.png")
    _one_line_error(proc, "NaN or infinite sample")


@pytest.fixture
def rig_take(samples, tmp_path) -> Path:
    return import_rig_take(samples, tmp_path)


def test_a_rigs_own_controls_are_plotted_by_name_and_not_rendered_as_a_still_face(rig_take, tmp_path):
    """A FACEGOOD take (or a prediction of a run trained on one) holds no Live Link channel: render and
    stream used to show a neutral face and send zeros, and plot refused its channel names."""
    out = tmp_path / "rig.png"
    summary = _json(
        run_here("viewer", "plot", rig_take, "-o", out, "--channels", "mouth_oh_c,jaw_thrust_c", "--json")
    )
    assert summary["channels"] == ["mouth_oh_c", "jaw_thrust_c"] and out.stat().st_size > 0
    _one_line_error(
        run_here("viewer", "plot", rig_take, "-o", out, "--channels", "jawOpen"),
        "no input holds channel 'jawOpen'",
        "116 rig controls",
    )
    line = _one_line_error(run_here("viewer", "render", rig_take, "-o", tmp_path / "face.png"))
    assert "holds none of the 61 Live Link Face channels" in line and "s2a-view plot --channels" in line
    assert not (tmp_path / "face.png").exists()
    _one_line_error(run_here("viewer", "stream", rig_take, "--to", "127.0.0.1:9"), "stream shows Live Link")


def test_a_matrix_csv_without_a_rate_is_sent_to_import(samples, tmp_path):
    """A generic paired CSV without a time column has no frame rate, and the viewer has no --fps: the
    error used to say "give --fps", which the viewer refuses."""
    matrix = tmp_path / "weights.csv"
    matrix.write_text("jawOpen,mouthClose\n" + "".join(f"{i / 60:.3f},0.1\n" for i in range(60)))
    wav = samples / "paired" / "neurosync-trainer-lite-testset" / "audio.wav"
    line = _one_line_error(run_here("viewer", "plot", matrix, "--audio", wav, "-o", tmp_path / "p.png"))
    assert f"import it first (s2a-capture import --matrix {matrix} " in line


def test_a_take_with_rig_controls_beside_live_link_channels_is_plotted_and_rendered(rig_take, tmp_path):
    """A rig control that is NaN throughout (or on another scale) used to make every frame unusable for
    the face; a plot of inputs of which one holds none of the channels named it nowhere."""
    from capture import ARKIT52

    take = make_aligned_take("mixed", 1.0, channels=(*ARKIT52, "extra_ctl"))
    take.values[:, -1] = np.nan
    mixed = write_take(take, tmp_path / "takes")
    out = tmp_path / "both.png"
    proc = run_here("viewer", "plot", mixed, rig_take, "-o", out, "--channels", "jawOpen", "--json")
    summary = _json(proc)
    assert summary["inputs_without_these_channels"] == ["rig"]
    assert "rig holds none of the channels" in proc.stderr
    proc = run_here("viewer", "render", mixed, "-o", tmp_path / "face.png", "--json")
    assert _json(proc)["bad_values"] == [0] and "extra_ctl" in proc.stderr  # left out, with a warning
