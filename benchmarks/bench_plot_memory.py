"""Peak memory of ``s2a-view plot`` against the recording's length: 1 h of speech against 1 min.

The real NeuroSync speech tiled to 1 h at 48 kHz (--quick: 20 min) and to 1 min, plotted with each VAD
method. The plot draws a bounded envelope, and the audio is read, resampled, filtered and detected a
block at a time.

Last full run (2 h at 48 kHz, before: the recorded samples held whole and align's 16 kHz copy made whole):
--vad none 838 -> 163 MB, webrtc 1325 -> 232 MB, silero 1555 -> 468 MB; a 1 min take's 154, 212, 446 MB."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import soundfile as sf

from benchmarks.figure import Figure, peak_measured, read_peak_kb

ROOT = Path(__file__).resolve().parents[1]
PAIR = ROOT.parent / "shared/samples/paired/neurosync-trainer-lite-testset"
RATE = 48000


def _tiled(path: Path, minutes: int) -> None:
    """The real speech tiled to ``minutes`` of 48 kHz int16 mono (its samples, played faster)."""
    speech, _ = sf.read(PAIR / "audio.wav", dtype="int16")
    with sf.SoundFile(path, "w", RATE, 1, "PCM_16") as f:
        n = minutes * 60 * RATE
        for lo in range(0, n, speech.size):
            f.write(speech[: n - lo])


def _plot_peak_mb(wav: Path, vad: str, tmp: Path) -> float:
    peak = tmp / "peak"
    cmd = [sys.executable, "-m", "viewer", "plot", str(PAIR / "testset.csv"), "--audio", str(wav)]
    cmd += ["-o", str(tmp / "plot.png"), "--vad", vad]
    proc = subprocess.run(peak_measured(cmd, peak), cwd=ROOT, capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(f"s2a-view plot failed: {proc.stderr.strip()}")
    return read_peak_kb(peak) / 1024


def run(quick: bool = False) -> list[Figure]:
    if not (PAIR / "audio.wav").is_file():
        return []
    minutes = 20 if quick else 60
    figures = []
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        short, long = tmp / "short.wav", tmp / "long.wav"
        _tiled(short, 1)
        _tiled(long, minutes)
        for vad in ("none", "webrtc") if quick else ("none", "webrtc", "silero"):
            reference = _plot_peak_mb(short, vad, tmp)
            figures.append(
                Figure(
                    f"s2a-view plot --vad {vad} peak RSS, {minutes} min at 48 kHz",
                    _plot_peak_mb(long, vad, tmp),
                    "MB",
                    "the same plot of 1 min",
                    reference,
                    higher_is_better=False,
                    target=1.5,
                    note=f"{minutes} min of int16 samples alone: {minutes * 60 * RATE * 2 / 2**20:.0f} MB",
                )
            )
    return figures
