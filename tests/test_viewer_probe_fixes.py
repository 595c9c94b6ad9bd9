"""What a report-only probe of ``s2a-view`` found, each fixed and held here: speech that stays with its
face, the audio beside a CSV, AAC rates, frames too large for H.264, offsets that are no number,
SIGTERM, folders left by a bad input, legend names, one-frame and missing-channel takes, damaged take
folders in a report, stream counts, repeated channels and messages that say what to do. Inputs are
cut from the real Live Link Face samples; commands run in this process (``run_here``) at 32 px, and as
a subprocess where a real process is the subject (SIGTERM)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import av
import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_here
from live_helpers import datagrams, udp_receiver

from capture import Audio, Take, TakeMeta, read_livelink_csv, write_take
from capture import livelink as ll

CAL = "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"  # 60 fps, the app's own naming
NEUROSYNC = "paired/neurosync-trainer-lite-testset/testset.csv"  # 20 s at 60 fps


def _json(proc) -> dict:
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _one_line_error(proc, *needles: str) -> str:
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def _csv(samples: Path, path: Path, rows: int, edit=None) -> Path:
    """The header and the first ``rows`` rows of the real calibrated take at ``path``; ``edit`` maps
    the list of lines (header first) to others."""
    with open(samples / CAL, encoding="utf-8") as f:
        lines = [next(f) for _ in range(rows + 1)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(edit(lines) if edit else lines), encoding="utf-8")
    return path


def _speech(seconds: float, rate: int, burst_s: float | None = None) -> np.ndarray:
    """Quiet noise, with a loud burst of 0.2 s at ``burst_s`` when given: an onset to find again."""
    x = np.random.default_rng(0).normal(0, 0.01, int(seconds * rate)).astype(np.float32)
    if burst_s is not None:
        k, n = int(burst_s * rate), rate // 5
        x[k : k + n] = 0.5 * np.sin(np.arange(n) * 2 * np.pi * 440 / rate)
    return x


def _mp4_audio(path: Path) -> tuple[np.ndarray, int]:
    with av.open(str(path)) as c:
        stream = c.streams.audio[0]
        blocks = [f.to_ndarray().reshape(-1) for f in c.decode(stream)]
        return np.concatenate(blocks), stream.codec_context.sample_rate


# -- 1: the speech of a compare input starts where its face does ------------------------------------
def test_mp4_speech_of_a_compare_input_keeps_its_offset(samples, tmp_path):
    face = _csv(samples, tmp_path / "face" / "main.csv", 90)  # 1.5 s, no audio of its own
    take = read_livelink_csv(_csv(samples, tmp_path / "cmp.csv", 60))
    take.meta.id = "voiced"
    take.attach_audio(Audio(_speech(1.0, 16000, burst_s=0.2), 16000), start_s=float(take.time[0]))
    voiced = write_take(take, tmp_path / "takes")
    out = tmp_path / "off.mp4"
    args = ["render", face, "--compare", voiced, "--compare-offset", "1.0", "-o", out, "--size", 32]
    s = _json(run_here("viewer", *args, "--json"))
    x, rate = _mp4_audio(out)
    onset = np.flatnonzero(np.abs(x) > 0.25)[0] / rate
    assert onset == pytest.approx(1.2, abs=0.05)  # 0.2 s into its face, which starts 1 s in (was 0.2)
    assert s["audio_from"] == str(voiced / "audio.wav")


# -- 2: a CSV named directly brings the audio beside it ---------------------------------------------
def test_a_csv_named_directly_brings_the_audio_beside_it(samples, tmp_path):
    csv = _csv(samples, tmp_path / "loose" / "pred.csv", 30)
    sf.write(tmp_path / "loose" / "pred.wav", _speech(0.5, 16000), 16000)
    out = tmp_path / "p.mp4"
    s = _json(run_here("viewer", "render", csv, "-o", out, "--size", 32, "--json"))
    assert s["audio"] and s["audio_from"] == str(tmp_path / "loose" / "pred.wav")
    with av.open(str(out)) as c:
        assert len(c.streams.audio) == 1


def test_a_csv_in_a_live_link_face_take_folder_reads_as_the_folder(samples, tmp_path):
    folder = tmp_path / "MySlate_166"
    csv = _csv(samples, folder / "MySlate_166_iPhone_cal.csv", 30)
    (folder / "take.json").write_text('{"identifier": "MySlate_166"}', encoding="utf-8")
    sf.write(folder / "MySlate_166_iPhone.wav", _speech(0.5, 16000, burst_s=0.2), 16000)
    by_file = _json(run_here("viewer", "plot", csv, "-o", tmp_path / "f.png", "--vad", "energy", "--json"))
    by_folder = _json(
        run_here("viewer", "plot", folder, "-o", tmp_path / "d.png", "--vad", "energy", "--json")
    )
    assert by_file["speech_segments"] == by_folder["speech_segments"] != []  # the burst, heard both ways
    assert by_file["audio_file"] == by_folder["audio_file"] == str(folder / "MySlate_166_iPhone.wav")
    assert by_file["inputs"] == by_folder["inputs"]


# -- 3: audio at a rate AAC does not take -----------------------------------------------------------
@pytest.mark.parametrize(("rate", "aac"), [(22000, 22050), (192000, 96000), (1000, 7350)])
def test_mp4_audio_at_a_rate_aac_does_not_take_is_resampled(samples, tmp_path, rate, aac):
    csv = _csv(samples, tmp_path / "take.csv", 20)
    sf.write(tmp_path / "odd.wav", _speech(0.4, rate), rate)
    out = tmp_path / "r.mp4"
    proc = run_here(
        "viewer", "render", csv, "--audio", tmp_path / "odd.wav", "-o", out, "--size", 32, "--json"
    )
    assert _json(proc)["audio_rate"] == aac
    assert f"{rate} Hz audio resampled to {aac} Hz" in proc.stderr
    x, got = _mp4_audio(out)
    assert got == aac and x.size > 0.2 * aac


# -- 4: a frame wider than H.264 takes ----------------------------------------------------------------
def test_a_frame_too_large_for_h264_is_refused_before_rendering(samples, tmp_path):
    from viewer.render import mp4_frame_fits

    assert mp4_frame_fits(16384, 16) and not mp4_frame_fits(16400, 16)  # libx264's own limit
    assert mp4_frame_fits(8192, 4096) and not mp4_frame_fits(12288, 4096)  # H.264 level 6.2
    csv = _csv(samples, tmp_path / "take.csv", 10)
    out = tmp_path / "w.mp4"
    proc = run_here("viewer", "render", csv, "--compare", csv, csv, csv, csv, "--size", 4096, "-o", out)
    line = _one_line_error(proc, "20480x4096", "--size")
    fits = int(line.split("--size ")[1].split()[0])
    assert mp4_frame_fits(5 * fits, fits) and not mp4_frame_fits(5 * (fits + 1), fits + 1)
    assert not out.exists()


# -- 5: offsets that are no number, and inputs outside the rendered span -----------------------------
@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
@pytest.mark.parametrize("option", ["--compare-offset", "--video-start"])
def test_offsets_must_be_finite(samples, tmp_path, option, value):
    csv = _csv(samples, tmp_path / "take.csv", 10)
    out = tmp_path / "n.png"
    extra = ["--compare", csv] if option == "--compare-offset" else ["--video", tmp_path / "any.mov"]
    proc = run_here("viewer", "render", csv, *extra, option, value, "-o", out, "--size", 32, "--json")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr  # a usage error
    assert (
        proc.stderr.strip()
        .splitlines()[-1]
        .endswith(f"argument {option}: must be a number of seconds, not {value}")
    )
    assert not out.exists()


def test_inputs_outside_the_rendered_span_are_warned_about(samples, tmp_path):
    csv = _csv(samples, tmp_path / "take.csv", 30)
    video = tmp_path / "ref.mp4"
    with av.open(str(video), "w") as c:  # 10 frames at 30 fps
        vs = c.add_stream("libx264", rate=30)
        vs.width, vs.height, vs.pix_fmt = 32, 32, "yuv420p"
        for k in range(10):
            frame = av.VideoFrame.from_ndarray(np.full((32, 32, 3), 20 * k, np.uint8), format="rgb24")
            for p in vs.encode(frame):
                c.mux(p)
        for p in vs.encode():
            c.mux(p)
    out = tmp_path / "o.png"
    base = ["render", csv, "-o", out, "--size", 32, "--json"]
    proc = run_here("viewer", *base, "--compare", csv, "--compare-offset", "-1e3")  # a value, not an option
    assert _json(proc)["compare_offset_s"] == [-1000.0]
    assert "(compare) spans -1000.000..-999.5" in proc.stderr and "outside the rendered" in proc.stderr
    assert "its face stays at its last frame" in proc.stderr
    proc = run_here("viewer", *base, "--video", video, "--video-start", "1e300")
    assert _json(proc) and "(video) spans 1e+300..1e+300 s" in proc.stderr and "stays black" in proc.stderr
    proc = run_here("viewer", *base, "--video-start", "0.5")
    assert (
        _json(proc) and "--video-start places a reference video: without --video it is ignored" in proc.stderr
    )


# -- 6: SIGTERM cleans up as Ctrl-C does -------------------------------------------------------------
@pytest.mark.parametrize(
    ("sig", "code", "said"),
    [(signal.SIGTERM, 143, "terminated (SIGTERM)"), (signal.SIGINT, 130, "interrupted")],
)
def test_a_signal_during_an_mp4_render_leaves_no_partial_file(samples, tmp_path, sig, code, said):
    out = tmp_path / "k.mp4"
    partial = tmp_path / ".k.mp4.partial.mp4"
    cmd = [sys.executable, "-m", "viewer", "render", samples / NEUROSYNC, "-o", out, "--size", "32"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not partial.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert partial.exists(), proc.communicate()[1]
    proc.send_signal(sig)  # mostly while VTK renders, where an exception raised in Python used to vanish
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert said in err and "Traceback" not in err and "ProcessRequest" not in err  # nor VTK's log of it
    assert list(tmp_path.iterdir()) == []


# -- 7: a bad input leaves no output folder ----------------------------------------------------------
def test_render_of_a_missing_input_creates_no_folder(tmp_path):
    proc = run_here("viewer", "render", tmp_path / "nonexist.csv", "-o", tmp_path / "a" / "b" / "x.png")
    _one_line_error(proc, "no such take folder or CSV file")
    assert not (tmp_path / "a").exists()


# -- 8: legend names are unique, by render's rule ----------------------------------------------------
def test_plot_names_two_takes_of_one_id_apart(samples, tmp_path):
    raw = _csv(samples, tmp_path / "raw" / "MySlate_166_iPhone_cal.csv", 30)
    aligned = _csv(samples, tmp_path / "aligned" / "MySlate_166_iPhone_cal.csv", 30)
    take = read_livelink_csv(raw)
    raw_take, aligned_take = write_take(take, tmp_path / "takes"), write_take(take, tmp_path / "seg")
    s = _json(run_here("viewer", "plot", raw_take, aligned_take, "-o", tmp_path / "p.png", "--json"))
    assert len(set(s["inputs"])) == 2 and s["inputs"][0].endswith("(takes)")
    s = _json(run_here("viewer", "plot", raw, aligned, "-o", tmp_path / "q.png", "--json"))  # same file names
    assert len(set(s["inputs"])) == 2


# -- 9: a one-frame take ---------------------------------------------------------------------------
def test_a_one_frame_take_plots_as_a_point_without_a_matplotlib_warning(samples, tmp_path):
    csv = _csv(samples, tmp_path / "one.csv", 1, lambda lines: [lines[0], _jaw(lines[0], lines[1], "0.5")])
    out = tmp_path / "one.png"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # matplotlib's "identical low and high xlims" was one
        _json(run_here("viewer", "plot", csv, "-o", out, "--json"))
    import cv2

    img = cv2.imread(str(out))
    h, w = img.shape[:2]
    middle = img[:, int(0.4 * w) : int(0.6 * w)].astype(int)  # the point, at the middle of the x range
    blue = (np.abs(middle[..., 0] - 0xB4) < 40) & (np.abs(middle[..., 2] - 0x1F) < 40)  # tab:blue, BGR
    assert blue.sum() > 10


def _jaw(header: str, line: str, value: str) -> str:
    names = [c.strip().lower() for c in header.split(",")]
    cells = line.rstrip("\n").split(",")
    cells[names.index("jawopen")] = value
    return ",".join(cells) + "\n"


# -- 10: a missing face channel is named --------------------------------------------------------------
def test_a_csv_without_a_face_channel_is_warned_about_once(samples, tmp_path):
    def drop_jaw(lines):
        j = [c.strip().lower() for c in lines[0].split(",")].index("jawopen")
        return [
            ",".join(c for k, c in enumerate(line.rstrip("\n").split(",")) if k != j) + "\n" for line in lines
        ]

    csv = _csv(samples, tmp_path / "nojaw.csv", 20, drop_jaw)
    proc = run_here("viewer", "render", csv, "-o", tmp_path / "m.png", "--size", 32, "--json")
    _json(proc)
    named = [line for line in proc.stderr.splitlines() if "not in the take, shown at 0" in line]
    assert len(named) == 1 and named[0].endswith(": jawOpen")


# -- 11: a damaged take folder in a report, and --takes of an unaligned take -------------------------
def test_report_lists_a_damaged_take_folder_and_reports_the_others(samples, tmp_path):
    take = read_livelink_csv(_csv(samples, tmp_path / "t.csv", 30))
    for tid in ("good", "damaged", "other"):
        take.meta.id = tid
        write_take(take, tmp_path / "takes")
    frames = tmp_path / "takes" / "damaged" / "frames.npz"
    frames.write_bytes(frames.read_bytes()[:200])
    out = tmp_path / "r.html"
    proc = run_here("viewer", "report", tmp_path / "takes", "-o", out, "--json")
    s = _json(proc)
    assert s["takes"] == 2 and [u["path"] for u in s["unreadable"]] == [str(frames.parent)]
    assert "frames.npz: frames are unreadable" in s["unreadable"][0]["error"]
    assert "listed as unreadable" in proc.stderr
    assert "Unreadable take folders (1)" in out.read_text(encoding="utf-8")
    take.meta.id = "unaligned"
    write_take(take, tmp_path / "more")
    proc = run_here("viewer", "report", tmp_path / "takes", "--takes", tmp_path / "more", "-o", out, "--json")
    assert (
        "unaligned: --takes names aligned take folders (s2a-align output); this one has no align report"
        in (proc.stderr)
    )
    assert _json(proc)["warnings"]


# -- 12: stream counts say what was sent ----------------------------------------------------------------
def test_stream_counts_add_up_to_the_packets_sent(samples, tmp_path):
    def nan_jaw(lines):
        return [lines[0]] + [
            _jaw(lines[0], line, "nan") if 10 <= k < 20 else line for k, line in enumerate(lines[1:])
        ]

    csv = _csv(samples, tmp_path / "nan.csv", 40, nan_jaw)
    with udp_receiver() as sock:
        to = f"127.0.0.1:{sock.getsockname()[1]}"
        s = _json(run_here("viewer", "stream", csv, "--to", to, "--speed", "50", "--json"))
        packets = datagrams(sock)
    no_face = sum(1 for p in packets if len(p) <= ll.parse_header(p)[0] + ll.FRAME_TIME_BYTES)
    assert s["packets_sent"] == len(packets) == 40
    assert s["frames"] + s["no_face"] == s["packets_sent"]
    assert s["no_face"] == no_face == 10 and s["bad_values"] == 10 and s["face_lost"] == 0


# -- 13: a channel named twice ------------------------------------------------------------------------
def test_a_channel_named_twice_is_drawn_once(samples, tmp_path):
    csv = _csv(samples, tmp_path / "t.csv", 20)
    proc = run_here(
        "viewer", "plot", csv, "-o", tmp_path / "p.png", "--channels", "jawOpen,JawOpen", "--json"
    )
    s = _json(proc)
    assert s["channels"] == ["jawOpen"] and s["repeated_channels"] == ["jawOpen"]
    assert "--channels names jawOpen more than once: drawn once" in proc.stderr


# -- 14: messages that say what to do -----------------------------------------------------------------
def test_a_truncated_glb_is_called_truncated(tmp_path):
    from capture.errors import InputError
    from viewer.gltf import load_gltf

    doc = json.dumps({"asset": {"version": "2.0"}, "meshes": []}).encode()
    doc += b" " * (-len(doc) % 4)
    glb = b"glTF" + (2).to_bytes(4, "little") + (12 + 8 + len(doc)).to_bytes(4, "little")
    glb += len(doc).to_bytes(4, "little") + b"JSON" + doc
    (tmp_path / "cut.glb").write_bytes(glb[: len(glb) // 2])
    with pytest.raises(InputError, match="GLB is truncated: its header says"):
        load_gltf(tmp_path / "cut.glb")


def test_a_rig_take_refusal_suggests_channels_that_vary(tmp_path):
    n = 30
    t = np.arange(n) / 30
    values = np.stack([np.zeros(n), 0.5 + 0.5 * np.sin(6 * t), 0.1 * t], axis=1).astype(np.float32)
    meta = TakeMeta(
        id="rig", source_kind="paired_matrix", fps=30.0, channels=["brow_lower_l", "mouth_oh_c", "jaw_c"]
    )
    folder = write_take(Take(meta, t, values, np.zeros(n, np.uint8)), tmp_path / "takes")
    proc = run_here("viewer", "render", folder, "-o", tmp_path / "r.png", "--size", 32)
    _one_line_error(proc, "plot --channels mouth_oh_c,jaw_c")


def test_report_on_live_link_face_csvs_says_to_import_them_first(samples, tmp_path):
    _csv(samples, tmp_path / "csvs" / "MySlate_166_iPhone_cal.csv", 10)
    proc = run_here("viewer", "report", tmp_path / "csvs", "-o", tmp_path / "r.html")
    _one_line_error(proc, "import them first (s2a-capture import")
    assert not (tmp_path / "r.html").exists()


def test_a_take_of_the_52_blendshapes_alone_is_not_warned_about(tmp_path):
    from capture.channels import ARKIT52

    n = 20
    t = np.arange(n) / 30
    values = np.full((n, len(ARKIT52)), 0.1, np.float32)
    meta = TakeMeta(id="face52", source_kind="paired_matrix", fps=30.0, channels=list(ARKIT52))
    folder = write_take(Take(meta, t, values, np.zeros(n, np.uint8)), tmp_path / "takes")
    proc = run_here("viewer", "render", folder, "-o", tmp_path / "r.png", "--size", 32, "--json")
    _json(proc)
    assert "shown at 0" not in proc.stderr  # no head or eye angle is asked of a take without head tracking


def test_a_rig_take_with_a_channel_of_no_value_is_refused_in_one_line(tmp_path):
    n = 30
    t = np.arange(n) / 30
    values = np.stack([np.full(n, np.nan), 0.5 + 0.5 * np.sin(6 * t), 0.1 * t], axis=1).astype(np.float32)
    meta = TakeMeta(
        id="rig", source_kind="paired_matrix", fps=30.0, channels=["blank_c", "mouth_oh_c", "jaw_c"]
    )
    folder = write_take(Take(meta, t, values, np.zeros(n, np.uint8)), tmp_path / "takes")
    with warnings.catch_warnings():
        warnings.simplefilter("always")  # numpy's "All-NaN slice encountered" came before the error
        proc = run_here("viewer", "render", folder, "-o", tmp_path / "r.png", "--size", 32)
    _one_line_error(proc, "plot --channels mouth_oh_c,jaw_c")


# From the guide walkthrough: a report of a dataset whose aligned takes have moved said so only on the page.
def test_report_warns_when_the_align_reports_are_not_where_the_manifest_says(tmp_path):
    from dataset_helpers import write_aligned_set

    from dataset import build_dataset
    from viewer.report import gather

    write_aligned_set(tmp_path / "takes", count=4, speakers=2, seconds=2.0)
    build_dataset([tmp_path / "takes"], tmp_path / "ds")
    assert gather(tmp_path / "ds", limit=0)["warnings"] == []
    (tmp_path / "takes").rename(tmp_path / "moved")
    (warning,) = gather(tmp_path / "ds", limit=0)["warnings"]
    assert "align reports of 4 take(s) were not found" in warning and "--takes" in warning
    found = gather(tmp_path / "ds", [tmp_path / "moved"], limit=0)
    assert found["warnings"] == [] and all(e["align"] for e in found["takes"])


# From the crash probe: a render under a low `ulimit -v` blamed missing Debian packages.
def test_a_failed_render_probe_under_a_low_memory_limit_says_so(monkeypatch):
    import importlib
    import resource

    probe_module = importlib.import_module("viewer.probe")  # the package's `probe` is the function
    crashed = subprocess.CompletedProcess([], -11, "", "")
    monkeypatch.setattr(probe_module, "_RESULT", None)
    monkeypatch.setattr(probe_module.subprocess, "run", lambda *a, **k: crashed)
    monkeypatch.setattr(resource, "getrlimit", lambda _which: (800 << 20, resource.RLIM_INFINITY))
    with pytest.raises(probe_module.RenderUnavailable, match=r"at most 800 MB \(ulimit -v\)"):
        probe_module.probe()
    monkeypatch.setattr(resource, "getrlimit", lambda _which: (resource.RLIM_INFINITY,) * 2)
    with pytest.raises(probe_module.RenderUnavailable) as no_limit:
        probe_module.probe()
    assert str(no_limit.value).startswith("offscreen rendering is not available")
