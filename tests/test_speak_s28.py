"""``s2a-view speak``: a trained run animates speech as it is spoken and sends the face as Live Link
packets; over real UDP on loopback, the frames received are ``s2a-train predict``'s on the same audio."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT, run_cli, run_here
from live_helpers import wait_until
from test_train_pipeline import TINY

from capture import livelink as ll
from capture import read_livelink_csv
from capture.channels import ARKIT61, canonical

SPEECH = "paired/facegood-audio2face/wav/1114_2_01.wav"  # real speech (FACEGOOD, 16 kHz)


@pytest.fixture(scope="module")
def run(built, tmp_path_factory) -> Path:
    """A small model trained a few steps on the five-take dataset: its output moves from frame to frame."""
    from train.config import resolve_config
    from train.fit import fit

    out = tmp_path_factory.mktemp("speak") / "run"
    fit(built, out, resolve_config(sets=TINY + ["max_steps=8", "eval_every=8"]), say=lambda _m: None)
    return out


@pytest.fixture(scope="module")
def speech(samples, tmp_path_factory) -> Path:
    """3 s of real speech."""
    x, rate = sf.read(samples / SPEECH, dtype="float32", frames=3 * 16000, start=20 * 16000)
    path = tmp_path_factory.mktemp("speech") / "speech.wav"
    sf.write(path, x, rate)
    return path


class Receiver:
    """A UDP socket on loopback gathering every datagram in a thread until closed."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.to = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self.packets: list[bytes] = []
        self.open = True
        self.thread = threading.Thread(target=self._gather, daemon=True)
        self.thread.start()

    def _gather(self):
        while self.open:
            try:
                self.packets.append(self.sock.recv(4096))
            except TimeoutError:
                pass

    def frames(self) -> list[ll.LiveLinkFrame]:
        """Every datagram that arrived, also those still in the socket's buffer when the thread stops
        (a busy machine: the sender may be done long before the thread has read its last packets)."""
        self.open = False
        self.thread.join()
        self.sock.setblocking(False)
        while True:
            try:
                self.packets.append(self.sock.recv(4096))
            except BlockingIOError:
                break
        self.sock.close()
        return [ll.decode_packet(p) for p in self.packets]


def speak_cli(*args) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "viewer", "speak", *map(str, args), "--json"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def offline(run: Path, wav: Path, tmp: Path) -> np.ndarray:
    """``s2a-train predict``'s frames of ``wav`` as (frames, 61) in Live Link order."""
    assert run_here("train", "predict", run, wav, "-o", tmp / "offline.csv").returncode == 0
    take = read_livelink_csv(tmp / "offline.csv")
    index = {canonical(c): j for j, c in enumerate(take.meta.channels)}
    return np.stack([take.values[:, index[c]] for c in ARKIT61], axis=1)


def test_streamed_frames_are_predicts(run, speech, tmp_path):
    """Every frame of the audio arrives, once, at the run's rate, consecutive frame numbers; the values
    are predict's within a small error at the default latency and context (4x real time, so that a
    busy machine's late frames are late in time only, never in value)."""
    rx = Receiver()
    proc = speak_cli(run, "--to", rx.to, "--audio", speech, "--speed", 4)
    out, err = proc.communicate(timeout=120)
    frames = rx.frames()
    assert proc.returncode == 0, err
    summary = json.loads(out)
    want = offline(run, speech, tmp_path)
    assert len(frames) == summary["frames"] == want.shape[0] == 180
    assert {(f.rate_numerator, f.rate_denominator) for f in frames} == {(60, 1)}
    numbers = np.array([f.frame_number for f in frames])
    assert np.all(np.diff(numbers) == 1)  # in order, none missing, none twice
    got = np.stack([f.values for f in frames])
    rmse = float(np.sqrt(np.mean((got - want) ** 2)))
    shifted = float(np.sqrt(np.mean((got[1:] - want[:-1]) ** 2)))  # one frame off: what must not happen
    assert rmse < 0.01 and rmse < shifted / 2, (rmse, shifted)
    assert summary["latency_s"] == 0.3 and summary["send_delay_s"] == pytest.approx(
        0.3 + 2 * summary["hop_s"]
    )
    assert summary["achieved_latency_s"]["mean"] >= summary["send_delay_s"] - 0.01
    assert summary["stopped_by"] is None and summary["compute_ms_per_hop"]["max"] > 0


def test_sigterm_stops_with_a_summary(run, samples, tmp_path):
    """SIGTERM during a real-time stream stops it cleanly: exit 0 and the summary counts exactly the
    packets that arrived."""
    rx = Receiver()
    proc = speak_cli(run, "--to", rx.to, "--audio", samples / SPEECH, "--hop", 0.2, "--latency", 0.2)
    wait_until(lambda: len(rx.packets) >= 10 or proc.poll() is not None, "the first packets")
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    frames = rx.frames()
    assert proc.returncode == 0, err
    summary = json.loads(out)
    assert summary["stopped_by"] == "SIGTERM" and summary["frames"] == len(frames) >= 10
    assert "Traceback" not in err


def needs_a_ppg_model(run: Path, out: Path) -> Path:
    """``run`` as a run whose dataset's content features came from a bottleneck PPG: its features need
    the PPG model file, which is not given."""
    import torch

    out.mkdir()
    (out / "config.json").write_bytes((run / "config.json").read_bytes())
    payload = torch.load(run / "best.pt", weights_only=False, map_location="cpu")
    payload["inputs"]["content"] = "ppg"
    features = payload["dataset"]["features"]
    features["names"] = ["ppg" if n == "fbank" else n for n in features["names"]]
    features["dims"] = {"ppg" if k == "fbank" else k: v for k, v in features["dims"].items()}
    features["ppg"] = {"backend": "bottleneck", "model": "ppg.pt"}
    torch.save(payload, out / "best.pt")
    return out


def test_bad_input_is_one_line(run, speech, tmp_path):
    """A folder that is no run, a destination without a port, audio that is no audio or absent, --play
    with a microphone, a PPG run without its model: one line each, exit 1."""
    notrun = tmp_path / "notrun"
    notrun.mkdir()
    (notrun / "config.json").write_text("{}")
    noise = tmp_path / "noise.wav"
    noise.write_text("not audio")
    ppg_run = needs_a_ppg_model(run, tmp_path / "ppg_run")
    cases = [
        ([notrun, "--to", "127.0.0.1:11111", "--audio", speech], "notrun"),
        ([run, "--to", "localhost", "--audio", speech], "HOST:PORT"),
        ([run, "--to", "127.0.0.1:11111", "--audio", noise], "noise.wav"),
        ([run, "--to", "127.0.0.1:11111", "--audio", tmp_path / "absent.wav"], "absent.wav"),
        ([run, "--to", "127.0.0.1:11111", "--mic", "--play"], "--play"),
        ([ppg_run, "--to", "127.0.0.1:11111", "--audio", speech], "--ppg-model"),
    ]
    for args, named in cases:
        proc = run_here("viewer", "speak", *args)
        assert proc.returncode == 1, (args, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("s2a-view: error: ") and named in lines[0], lines


def test_no_microphone_is_one_line(run):
    """No sound card here: --mic is one line saying so (a subprocess: PortAudio's own chatter counts)."""
    proc = run_cli("viewer", "speak", run, "--to", "127.0.0.1:11111", "--mic")
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert "--mic" in proc.stderr and "Traceback" not in proc.stderr
