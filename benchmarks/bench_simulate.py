"""Simulated speaker: seconds of paired data produced per CPU second (target >= 200x real time)."""

from __future__ import annotations

import os
import tempfile
import time

from benchmarks.figure import Figure

# One core: BLAS/OpenMP pools are held to one thread where they have not started yet, and the
# figure uses this process's CPU time, which counts every thread anyway.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def _speed(seconds: float, takes: int, sample_rate: int, mov: bool) -> tuple[float, float]:
    """(audio seconds produced, CPU seconds spent) simulating and writing ``takes`` take folders."""
    from capture.simulate import TakeSpec, simulate_take, write_take_folder

    simulate_take(TakeSpec(99, 0, 1, 3.0, sample_rate=sample_rate))  # warm caches and lazy imports
    audio_s = cpu_s = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(takes):
            spec = TakeSpec(1, k % 2, k // 2 + 1, seconds, sample_rate=sample_rate, mov=mov)
            t0 = time.process_time()
            sim = simulate_take(spec)
            write_take_folder(sim, tmp)
            cpu_s += time.process_time() - t0
            audio_s += sim.audio.duration_s
    return audio_s, cpu_s


def run(quick: bool = False) -> list[Figure]:
    seconds, takes = (20.0, 2) if quick else (60.0, 6)
    figures = []
    for rate, mov, target in ((16000, False, 200.0), (44100, False, 200.0), (44100, True, None)):
        audio_s, cpu_s = _speed(seconds, takes if not mov else 1, rate, mov)
        what = f"{rate} Hz" + (", with .mov + frame_log" if mov else "")
        figures.append(
            Figure(
                name=f"simulate speed ({what})",
                value=audio_s / cpu_s,
                unit="s of take per CPU s",
                reference="real time",
                reference_value=1.0,
                higher_is_better=True,
                target=target,
                note=f"{audio_s:.0f} s of takes in {cpu_s:.2f} CPU s, 60 fps, all artifacts, written to disk",
            )
        )
    return figures
