"""``s2a-view`` as a user runs it: PNG and MP4 renders of real takes, curve plots, Live Link streaming
into the project's own listener on loopback, and the dataset report in headless Chromium."""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
import xml.etree.ElementTree as ET
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest
from conftest import run_cli, run_here
from dataset_helpers import write_aligned_set

from capture import (
    ARKIT61,
    Audio,
    FrameStatus,
    LiveRecorder,
    Take,
    TakeMeta,
    build_takes,
    read_csv_with_audio,
    read_livelink_csv,
    read_take,
    write_livelink_csv,
    write_take,
)

NEUROSYNC = "paired/neurosync-trainer-lite-testset"


def _json(proc) -> dict:
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _png(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None
    return img


@pytest.fixture(scope="module")
def short_take(samples, tmp_path_factory) -> Path:
    """The first 2 s of the NeuroSync test take with its speech, as a take folder."""
    src = samples / NEUROSYNC
    full = read_csv_with_audio(src / "testset.csv", src / "audio.wav")
    n = 120
    take = Take(full.meta, full.time[:n], full.values[:n], full.frame_status[:n])
    a = full.audio
    take.attach_audio(
        Audio(a.samples[: int(2.2 * a.sample_rate)], a.sample_rate, a.subtype),
        full.meta.audio.start_s,
        full.meta.audio.start_source,
    )
    take.meta.id = "neurosync_2s"
    return write_take(take, tmp_path_factory.mktemp("takes"))


@pytest.fixture(scope="module")
def prediction_csv(short_take, tmp_path_factory) -> Path:
    """A stand-in prediction: the recording with a damped jaw, written as Live Link Face CSV."""
    take = read_take(short_take)
    take.values = take.values.copy()
    take.values[:, take.channel_index("jawOpen")] *= 0.3
    out = tmp_path_factory.mktemp("pred") / "prediction.csv"
    write_livelink_csv(take, out)
    return out


def test_render_png_of_the_real_take(samples, tmp_path):
    src = samples / NEUROSYNC
    out = tmp_path / "face.png"
    s = _json(
        run_cli(
            "viewer",
            "render",
            src / "testset.csv",
            "--audio",
            src / "audio.wav",
            "-o",
            out,
            "--size",
            "160",
            "--json",
        )
    )
    img = _png(out)
    assert img.shape == (160, 160, 3) and img.std() > 20
    assert s["width"] == 160 and s["height"] == 160
    take = read_livelink_csv(src / "testset.csv")
    k = int(np.argmax(take.channel("jawOpen")))  # default frame: the widest open jaw
    assert s["time_s"] == pytest.approx(take.time[k] - take.time[0], abs=1e-6)


def test_render_mp4_side_by_side_has_every_frame_and_the_audio(short_take, prediction_csv, tmp_path):
    out = tmp_path / "compare.mp4"
    s = _json(
        run_here(
            "viewer", "render", short_take, "--compare", prediction_csv, "-o", out, "--size", "128", "--json"
        )
    )
    take = read_take(short_take)
    frames = int(round((take.time[-1] - take.time[0]) * take.meta.fps)) + 1
    assert s["frames"] == frames and s["audio"] is True
    with av.open(str(out)) as c:
        v = c.streams.video[0]
        assert (v.width, v.height) == (256, 128)
        assert v.average_rate == Fraction(60)
        decoded = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(decoded) == frames
    with av.open(str(out)) as c:
        assert len(c.streams.audio) == 1
        a = c.streams.audio[0]
        assert a.codec_context.name == "aac" and a.rate == 44100
        assert float(a.duration * a.time_base) == pytest.approx(frames / 60, abs=0.05)
        assert float(c.duration / 1e6) == pytest.approx(frames / 60, abs=0.05)
        samples_ = np.concatenate([f.to_ndarray().ravel() for f in c.decode(audio=0)])
    assert np.abs(samples_).max() > 0.01  # the speech, not silence
    # Left panel: the recording; right: the damped prediction. They differ, and frames change over time.
    last = decoded[-1].astype(int)
    assert np.abs(last[:, :128] - last[:, 128:]).mean() > 0.5
    assert np.abs(decoded[0].astype(int) - decoded[60]).mean() > 0.2


def test_render_beside_a_reference_video(short_take, tmp_path):
    video = tmp_path / "ref.mp4"
    with av.open(str(video), "w") as c:  # a 1 s, 30 fps, 160x120 video whose brightness ramps
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = 160, 120, "yuv420p"
        for k in range(30):
            f = av.VideoFrame.from_ndarray(np.full((120, 160, 3), 8 * k, np.uint8), format="rgb24")
            f.pts = k
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    out = tmp_path / "with_video.png"
    s = _json(
        run_cli(
            "viewer",
            "render",
            short_take,
            "--video",
            video,
            "--video-start",
            "0",
            "--time",
            "0.5",
            "-o",
            out,
            "--size",
            "120",
            "--no-labels",
            "--json",
        )
    )
    img = _png(out)
    assert img.shape == (120, 120 + 160, 3) and s["width"] == 280
    assert abs(int(img[60, 200:].mean()) - 8 * 15) <= 12  # frame 15 of the video at t = 0.5 s


def test_plot_png_and_svg(samples, short_take, prediction_csv, tmp_path):
    src = samples / NEUROSYNC
    out = tmp_path / "curves.png"
    s = _json(
        run_here(
            "viewer",
            "plot",
            src / "testset.csv",
            "--audio",
            src / "audio.wav",
            "-o",
            out,
            "--channels",
            "jawOpen,mouthClose",
            "--json",
        )
    )
    assert s["channels"] == ["jawOpen", "mouthClose"]
    assert s["vad"] == "speech (silero VAD)" and len(s["speech_segments"]) >= 3
    assert all(0 <= a < b <= 20.5 for a, b in s["speech_segments"])
    img = _png(out)
    assert img.shape[1] == 1000 and img.std() > 20
    svg = tmp_path / "compare.svg"
    s = _json(
        run_here(
            "viewer",
            "plot",
            short_take,
            prediction_csv,
            "-o",
            svg,
            "--labels",
            "recording,prediction",
            "--vad",
            "energy",
            "--json",
        )
    )
    assert s["inputs"] == ["recording", "prediction"] and s["vad"] == "loud (energy threshold)"
    root = ET.parse(svg).getroot()
    assert root.tag.endswith("svg")
    text = svg.read_text()
    assert "recording" in text and "prediction" in text and "jawOpen" in text


def _synthetic_csv(path: Path, n: int = 180) -> Take:
    rng = np.random.default_rng(5)
    values = rng.uniform(-0.5, 1.05, (n, 61)).astype(np.float32)
    meta = TakeMeta(
        id="synthetic",
        source_kind="simulated",
        fps=60.0,
        channels=list(ARKIT61),
        subject="iPhone",
        csv={"start_seconds_of_day": 12 * 3600.0},
    )
    take = Take(meta, np.arange(n) / 60.0, values, np.full(n, FrameStatus.TRACKED, np.uint8))
    write_livelink_csv(take, path)
    return read_livelink_csv(path)


def test_streamed_take_received_by_our_listener_equals_the_take(tmp_path):
    sent = _synthetic_csv(tmp_path / "pred.csv")
    rec = LiveRecorder(tmp_path / "rec", bind="127.0.0.1", port=0, fsync=False)
    _, port = rec.open()
    thread = threading.Thread(target=rec.run, kwargs={"duration_s": 60.0})
    thread.start()
    try:
        s = _json(
            run_cli(
                "viewer",
                "stream",
                tmp_path / "pred.csv",
                "--to",
                f"127.0.0.1:{port}",
                "--speed",
                "4",
                "--subject",
                "MetaHumanTest",
                "--json",
            )
        )
    finally:
        rec.request_stop()
        thread.join(30)
        rec.close()
    assert s["frames"] == sent.time.size and s["packets_sent"] == sent.time.size
    assert s["rate"] == [60, 1] and s["subject"] == "MetaHumanTest"
    summaries = build_takes(rec.session_dir, tmp_path / "takes")
    assert len(summaries) == 1 and summaries[0]["subject"] == "MetaHumanTest"
    got = read_take(summaries[0]["path"])
    assert got.time.size == sent.time.size and np.all(got.frame_status == FrameStatus.TRACKED)
    assert got.meta.extra["first_frame_number"] == 12 * 3600 * 60
    for name in ARKIT61:
        assert np.array_equal(got.channel(name), sent.channel(name)), name
    assert np.allclose(got.time - got.time[0], sent.time - sent.time[0], atol=1e-6)


def test_report_opens_in_headless_chromium(tmp_path):
    from dataset import build_dataset

    write_aligned_set(tmp_path / "takes", count=5, speakers=2, seconds=2.0)
    build_dataset([tmp_path / "takes"], tmp_path / "ds")
    out = tmp_path / "report.html"
    s = _json(
        run_cli("viewer", "report", tmp_path / "ds", "--takes", tmp_path / "takes", "-o", out, "--json")
    )
    assert s["kind"] == "dataset" and s["takes"] == 5 and s["with_align_report"] == 5
    page = out.read_text()
    assert "http://" not in page and "https://" not in page and 'src="//' not in page
    assert page.count('src="data:image/png;base64,') == 5
    assert "take00" in page and "Channel distributions" in page
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("Debian's chromium is not installed (apt-get install chromium): page not opened")
    flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--proxy-server=127.0.0.1:9",
        "--window-size=1200,1600",
    ]
    dom = subprocess.run(
        [chromium, *flags, f"--user-data-dir={tmp_path / 'profile1'}", "--dump-dom", out.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert 'data-ready="1"' in dom.stdout  # the inline script ran to its end without an exception
    assert dom.stdout.count("<tr") >= 5 + 3
    shot = tmp_path / "shot.png"
    proc = subprocess.run(
        [chromium, *flags, f"--user-data-dir={tmp_path / 'profile2'}", f"--screenshot={shot}", out.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0 and shot.is_file(), proc.stderr[-2000:]
    img = _png(shot)
    assert img.shape[:2] == (1600, 1200)
    assert img.std() > 10 and (img < 128).mean() > 0.005  # text and thumbnails drawn, not a blank page


def test_report_over_take_folders_without_a_dataset(short_take, tmp_path):
    out = tmp_path / "takes.html"
    s = _json(run_here("viewer", "report", short_take.parent, "-o", out, "--json"))
    assert s["kind"] == "takes" and s["takes"] == 1
    assert "Not a built dataset" in out.read_text()


def test_export_face_writes_a_glb_with_52_targets(tmp_path):
    s = _json(run_here("viewer", "export-face", "-o", tmp_path / "face.glb", "--names", "suffix", "--json"))
    assert s["channels"] == 52
    data = (tmp_path / "face.glb").read_bytes()
    assert data[:4] == b"glTF" and b"eyeBlink_L" in data and b"jawOpen" in data


@pytest.mark.parametrize(
    ("args", "code", "needle"),
    [
        (["render", "no/such/take", "-o", "x.png"], 1, "no such take folder or CSV file"),
        (["render", "no/such/take", "-o", "x.gif"], 1, "output must be .png"),
        (["plot", "no/such.csv", "-o", "x.pdf"], 1, "no such"),
        (["stream", "x.csv", "--to", "nowhere"], 1, "HOST:PORT"),
        (["report", "no/such/ds", "-o", "r.html"], 1, "no such dataset"),
        (["render"], 2, "usage"),
    ],
)
def test_errors_are_one_line_with_exit_codes(tmp_path, args, code, needle):
    proc = run_here(
        "viewer", *[a if not a.startswith(("no/", "x.", "r.")) else str(tmp_path / a) for a in args]
    )
    assert proc.returncode == code
    assert "Traceback" not in proc.stderr and needle in proc.stderr
    if code == 1:
        assert len(proc.stderr.strip().splitlines()) == 1
