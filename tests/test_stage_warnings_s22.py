"""Every stage's warnings name its program, as argparse names its errors (session 22): a line of a log
that several stages write to says which one warned. s2a-capture listen, s2a-train and s2a-view printed
a bare ``warning: ...``; each is run here as the user runs it, a process of its own."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import soundfile as sf
from conftest import run_cli
from dataset_helpers import make_aligned_take

from capture import write_take
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule
from train.config import resolve_config
from train.fit import fit


def _warnings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "warning:" in line]


def test_listen_names_its_warning(tmp_path):
    wav = tmp_path / "never.wav"  # to be written by the first packet: a warning, not an error
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "out"), "--port", "0"]
    cmd += ["--duration", "0.2", "--json", "--audio-file", str(wav), "--audio-start", "first-packet"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert _warnings(proc.stderr) == [
        f"s2a-capture: warning: {wav} does not exist yet: it has to be there when the first packet arrives"
    ]


def test_predict_names_its_warning(tmp_path):
    write_take(make_aligned_take("take0", 1.0), tmp_path / "takes")
    everything_trains = BuildOptions(split=SplitRule("take", 0.0, 0.0, 0, (), ()))
    build_dataset([tmp_path / "takes"], tmp_path / "ds", everything_trains, say=lambda _m: None)
    fit(tmp_path / "ds", tmp_path / "run", resolve_config(sets=["model=ridge"]), say=lambda _m: None)
    silent = tmp_path / "silent.wav"
    sf.write(silent, np.zeros(16000, np.float32), 16000)
    proc = run_cli("train", "predict", tmp_path / "run", silent, "-o", tmp_path / "silent.csv", "--json")
    assert proc.returncode == 0 and len(proc.stdout.splitlines()) == 1, proc.stderr
    assert _warnings(proc.stderr) == [
        f"s2a-train: warning: {silent}: the audio is silent (all zero): no speech to animate, "
        "the face stays still"
    ]


def test_view_names_its_warning(tmp_path):
    folder = write_take(make_aligned_take("t", 1.0), tmp_path)
    proc = run_cli("viewer", "plot", folder, "-o", tmp_path / "p.png", "--channels", "jawOpen,jawOpen")
    assert proc.returncode == 0, proc.stderr
    assert _warnings(proc.stderr) == [
        "s2a-view: warning: --channels names jawOpen more than once: drawn once"
    ]
