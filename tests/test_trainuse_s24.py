"""A trainer using ``s2a-train`` and ``s2a-view`` on inputs they had not seen: ``eval`` on a dataset built
with other channels than the run (the run's in another order, or more of them) scores the run's channels
instead of refusing them all as "channels differ"; ``predict`` on clipped audio says so (align flags it,
predict said nothing and reported a peak above 0 dBFS); an MP4 of a prediction without audio says it
is silent; and a ``VTK_DEFAULT_OPENGL_WINDOW`` set for on-screen VTK no longer stops every render with
advice to install GL drivers that are there. Command lines run as subprocesses on a tiny ridge run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_cli
from dataset_helpers import build_take_split, write_aligned_set


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """Five aligned 2 s takes, datasets of them with other channel sets, and a ridge run on jawOpen and
    mouthClose."""
    root = tmp_path_factory.mktemp("trainuse")
    takes = write_aligned_set(root / "takes", count=5, speakers=2, seconds=2.0)
    build_take_split(takes, root / "jaw", channels="jawOpen,mouthClose")
    build_take_split(takes, root / "jaw_swapped", channels="mouthClose,jawOpen")
    build_take_split(takes, root / "mouth", channels="jawOpen,mouthClose,mouthFunnel")
    build_take_split(takes, root / "funnel", channels="jawOpen,mouthFunnel")
    run_cli("train", "fit", "--data", root / "jaw", "--model", "ridge", "-o", root / "run", check=True)
    return root


def _eval(work: Path, ds: str) -> subprocess.CompletedProcess:
    return run_cli("train", "eval", work / "run", "--data", work / ds, "--json")


@pytest.mark.parametrize("ds", ["jaw_swapped", "mouth"])
def test_eval_on_a_dataset_holding_the_runs_channels_scores_them(work, ds):
    """The run's channels in another order, or among more channels, were "dataset channels differ from
    the channels the run was trained on" (exit 1): the same takes could not be scored."""
    own = _eval(work, "jaw")
    other = _eval(work, ds)
    assert own.returncode == 0, own.stderr
    assert other.returncode == 0, other.stderr
    a, b = json.loads(own.stdout), json.loads(other.stdout)
    assert list(b["per_channel"]) == ["jawOpen", "mouthClose"]
    for key in ("rmse_entire", "rmse_crucial"):
        assert b[key] == pytest.approx(a[key], rel=1e-9)
        assert b["floor"][key] == pytest.approx(a["floor"][key], rel=1e-9)
    assert b["per_channel"] == pytest.approx(a["per_channel"], rel=1e-9)
    assert "the run's channels are scored" in other.stderr


def test_eval_on_a_dataset_lacking_a_channel_of_the_run_names_it(work):
    proc = _eval(work, "funnel")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert "dataset lacks 1 of the 2 channels the run was trained on (mouthClose)" in line, line


def test_predict_on_clipped_audio_says_it_is_clipped(work, tmp_path):
    """Audio driven past full scale animated without a word (its JSON line said a peak of +1.5 dBFS)."""
    rate = 16000
    t = np.arange(2 * rate) / rate
    voice = 0.3 * np.sin(2 * np.pi * 180 * t) * (0.5 + 0.5 * np.sin(2 * np.pi * 4 * t))
    sf.write(tmp_path / "loud.wav", np.clip(20 * voice, -1, 1), rate, subtype="PCM_16")
    sf.write(tmp_path / "fine.wav", voice, rate, subtype="PCM_16")
    audio = [tmp_path / "loud.wav", tmp_path / "fine.wav"]
    proc = run_cli("train", "predict", work / "run", *audio, "-o", tmp_path / "csv", "--json")
    assert proc.returncode == 0, proc.stderr
    loud, fine = (json.loads(line) for line in proc.stdout.splitlines())
    assert loud["clipped_audio"] > 0.3 and fine["clipped_audio"] == 0.0
    warned = [line for line in proc.stderr.splitlines() if "clipped (held flat at full scale)" in line]
    assert len(warned) == 1 and "loud.wav" in warned[0] and "warning" in warned[0], proc.stderr


def _probe_env(**values: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    return env | values


def _probe(env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "viewer", "probe", "--json"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=300,
    )


def test_a_window_class_set_for_on_screen_vtk_is_named_and_offscreen_rendering_still_used():
    """With ``VTK_DEFAULT_OPENGL_WINDOW=vtkXOpenGLRenderWindow`` (set for on-screen VTK) and no display,
    the probe tried that class alone, crashed, and said to install GL packages that were installed."""
    usual = _probe(_probe_env())
    if usual.returncode != 0:
        pytest.skip(f"no offscreen rendering here: {usual.stderr.strip()[-200:]}")
    proc = _probe(_probe_env(VTK_DEFAULT_OPENGL_WINDOW="vtkXOpenGLRenderWindow"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["window"] == json.loads(usual.stdout)["window"]
    (line,) = [x for x in proc.stderr.splitlines() if "warning" in x]
    assert line.startswith("s2a-view: warning: VTK_DEFAULT_OPENGL_WINDOW=vtkXOpenGLRenderWindow cannot")


def test_without_any_gl_the_probe_still_says_what_to_install(tmp_path):
    """The fallback changes nothing where no class works: one line, the packages named."""
    env = _probe_env(
        VTK_DEFAULT_OPENGL_WINDOW="vtkXOpenGLRenderWindow",
        __EGL_VENDOR_LIBRARY_FILENAMES=str(tmp_path / "no-such-vendor.json"),
    )
    proc = _probe(env)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("s2a-view: error: offscreen rendering is not available") and "libegl1" in line
    assert "vtkXOpenGLRenderWindow:" in line and "vtkEGLRenderWindow:" in line


def test_an_mp4_of_a_prediction_without_audio_says_it_is_silent(work, tmp_path):
    """A predicted CSV in a folder without its audio rendered a silent MP4 without a word."""
    sf.write(tmp_path / "voice.wav", 0.1 * np.sin(np.arange(8000) / 5.0), 16000)
    run_cli("train", "predict", work / "run", tmp_path / "voice.wav", "-o", tmp_path / "csv", check=True)
    csv = tmp_path / "csv" / "voice.csv"
    silent = run_cli("viewer", "render", csv, "-o", tmp_path / "a.mp4", "--size", 32, "--json")
    if silent.returncode == 1 and "offscreen rendering is not available" in silent.stderr:
        pytest.skip("no offscreen rendering here")
    assert silent.returncode == 0, silent.stderr
    assert json.loads(silent.stdout)["audio"] is False
    assert f"note: no input has audio: {tmp_path / 'a.mp4'} is silent" in silent.stderr
    voiced = run_cli(
        "viewer", "render", csv, "--audio", tmp_path / "voice.wav", "-o", tmp_path / "b.mp4", "--size", 32
    )
    assert voiced.returncode == 0 and "no input has audio" not in voiced.stderr, voiced.stderr
