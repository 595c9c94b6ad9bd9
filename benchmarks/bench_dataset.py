"""Dataset build and read: throughput vs real time, peak memory, IterableDataset samples/s."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.figure import Figure, best_time, peak_measured, read_peak_kb

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=3600
    )


def simulated_aligned_takes(out: Path, takes: int, seconds: float) -> tuple[Path, str]:
    """Aligned takes from the simulated speaker (``s2a-capture simulate`` → import → ``s2a-align``).
    Returns the folder and its origin."""
    raw, imported, aligned = out / "raw", out / "imported", out / "aligned"
    speakers = str(max(1, takes // 4))
    steps = [
        (
            "capture",
            "simulate",
            "-o",
            str(raw),
            "--takes",
            str(takes),
            "--speakers",
            speakers,
            "--seconds",
            str(seconds),
        ),
        ("capture", "import", str(raw), "-o", str(imported)),
        ("align", str(imported), "-o", str(aligned), "--vad", "none", "--jobs", "2"),
    ]
    for step in steps:
        proc = _run(*step)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(step[:2])} failed: {proc.stderr.strip()}")
    return aligned, "simulated speaker, aligned by s2a-align"


def _audio_seconds(folder: Path) -> float:
    import json

    total = 0.0
    for meta in folder.rglob("meta.json"):
        a = json.loads(meta.read_text()).get("audio")
        if a:
            total += a["samples"] / a["sample_rate"]
    return total


def _timed_build(takes: Path, out: Path, ckpt: Path, jobs: int) -> tuple[float, float]:
    """Wall seconds and peak RSS (MB, the build process and its workers' largest) of one
    ``s2a-dataset build`` subprocess."""
    peak_file = out.with_name(out.name + ".peak")
    args = ["dataset", "build", str(takes), "-o", str(out), "--ppg", "bottleneck", "--ppg-model", str(ckpt)]
    cmd = peak_measured([sys.executable, "-m", *args, "--jobs", str(jobs)], peak_file)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr)
    return wall, read_peak_kb(peak_file) / 1024.0


def run(quick: bool = False) -> list[Figure]:
    import torch

    from dataset import BuildOptions, build_dataset
    from dataset.bottleneck import BottleneckPPG, save_bottleneck
    from dataset.torch_dataset import ShardDataset

    n_small, n_large, seconds = (4, 12, 15.0) if quick else (8, 32, 30.0)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        torch.manual_seed(0)
        ckpt = tmp / "ppg.pt"
        save_bottleneck(BottleneckPPG(), ckpt)
        small, origin = simulated_aligned_takes(tmp / "small", n_small, seconds)
        large, _ = simulated_aligned_takes(tmp / "large", n_large, seconds)
        small_s, large_s = _audio_seconds(small), _audio_seconds(large)
        # peak memory: each build in a fresh subprocess, measured on its own
        _, peak_small = _timed_build(small, tmp / "ds_small", ckpt, 1)
        cli1, peak_large = _timed_build(large, tmp / "ds_large1", ckpt, 1)
        cli2, _ = _timed_build(large, tmp / "ds_large2", ckpt, 2)
        # the library call itself, in one process (no interpreter, torch and Praat start-up)
        options = BuildOptions(ppg="bottleneck", ppg_model=str(ckpt))

        def library_build() -> None:
            build_dataset([large], tmp / "ds_lib", options)
            shutil.rmtree(tmp / "ds_lib")

        lib1 = best_time(library_build, repeat=2)
        data = ShardDataset(tmp / "ds_large1", "train", window=200, shuffle_buffer=16)
        t0 = time.perf_counter()
        count = sum(1 for _ in data)
        read_rate = count / (time.perf_counter() - t0)
        loader = torch.utils.data.DataLoader(data, batch_size=8, num_workers=2)
        t0 = time.perf_counter()
        count2 = sum(len(b["key"]) for b in loader)
        loader_rate = count2 / (time.perf_counter() - t0)
    feats = "pitch+energy+fbank+bottleneck PPG"
    minutes = f"{large_s / 60:.1f} min of audio"
    return [
        Figure(
            f"build_dataset() throughput, 1 process ({minutes}, {feats})",
            large_s / lib1,
            "x real time",
            "real time",
            1.0,
            True,
            target=100.0,
            note=f"{lib1:.2f} s; {origin}",
        ),
        Figure(
            f"s2a-dataset build --jobs 1, incl. start-up ({minutes})",
            large_s / cli1,
            "x real time",
            "real time",
            1.0,
            True,
            target=100.0,
            note=f"{cli1:.2f} s",
        ),
        Figure(
            f"s2a-dataset build --jobs 2, incl. start-up ({minutes})",
            large_s / cli2,
            "x real time",
            "real time",
            1.0,
            True,
            target=100.0,
            note=f"{cli2:.2f} s",
        ),
        Figure(
            f"build peak memory ({minutes})",
            peak_large,
            "MB",
            f"peak for {small_s / 60:.1f} min",
            peak_small,
            False,
            target=1.25,
            note="independent of dataset size when the ratio stays near 1",
        ),
        Figure(
            "shard read through ShardDataset (200-frame windows, 1 process)",
            read_rate,
            "samples/s",
            "real time at 30 s per sample",
            1 / 30.0,
            True,
            note=f"{count} samples",
        ),
        Figure(
            "shard read through DataLoader (2 workers, batch 8)",
            loader_rate,
            "samples/s",
            "real time at 30 s per sample",
            1 / 30.0,
            True,
            note=f"{count2} samples",
        ),
    ]
