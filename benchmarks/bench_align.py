"""Align stage: throughput (x real time, with and without VAD) and offset error on simulated takes with
known offsets of -200..+200 ms, plus the offsets found on the real NeuroSync and FACEGOOD takes.

Last full run (2-core machine shared with other jobs, so throughput is noisy): offset error median
2.3 ms, p95 9.0 ms (before the sonorant-band envelope, the 1-12 Hz band and the 2-stage refinement:
7.3 and 18.7 ms); NeuroSync +5.9 ms on its index clock (+24 ms on its timecodes); FACEGOOD -5.2..+20.2 ms
at 30 fps; see docs/align.md for the figures of the run and the throughput."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from align import AlignOptions, align_takes, align_with_report
from benchmarks.figure import Figure
from capture import Take, read_audio, read_livelink_csv, read_paired, write_take
from capture.simulate import TakeSpec, simulate_take, write_take_folder
from capture.take_folder import read_take_folder

SAMPLES = Path(__file__).resolve().parents[1].parent / "shared/samples/paired"
SAMPLE = SAMPLES / "neurosync-trainer-lite-testset"
FACEGOOD = SAMPLES / "facegood-audio2face"
FRAME_60_MS = 1000.0 / 60.0


def _simulated(n: int, seconds: float, out: Path) -> list[Take]:
    takes = []
    for i in range(n):
        spec = TakeSpec(
            seed=100 + i,
            speaker=i % 4,
            take=1 + i // 4,
            seconds=seconds,
            sample_rate=(16000, 44100, 48000)[i % 3],
        )
        takes.append(read_take_folder(write_take_folder(simulate_take(spec), out)))
    return takes


def _shifted(take: Take, shift_s: float) -> Take:
    """The take with its face moved ``shift_s`` later on the take clock (a known capture offset)."""
    return Take(take.meta, take.time + shift_s, take.values, take.frame_status, take.audio, take.neutral)


def _throughput(takes: list[Take], vad: str) -> tuple[float, float, float]:
    audio_s = sum(t.audio.duration_s for t in takes)
    opts = AlignOptions(vad=vad)
    align_with_report(takes[0], opts)  # warm: imports, the VAD model
    t0 = time.perf_counter()
    for t in takes:
        align_with_report(t, opts)
    wall = time.perf_counter() - t0
    return audio_s / wall, audio_s, wall


def run(quick: bool = False) -> list[Figure]:
    figures: list[Figure] = []
    n, seconds = (6, 20.0) if quick else (24, 30.0)
    with tempfile.TemporaryDirectory() as tmp:
        takes = _simulated(n, seconds, Path(tmp))
        raw = Path(tmp) / "raw"
        for t in takes:
            write_take(t, raw)
        audio_s = sum(t.audio.duration_s for t in takes)
        t0 = time.perf_counter()
        align_takes([raw], Path(tmp) / "aligned", AlignOptions(vad="silero"), jobs=2)
        wall = time.perf_counter() - t0
        figures.append(
            Figure(
                f"align throughput, VAD silero, --jobs 2 ({n} take folders, {audio_s:.0f} s of audio)",
                audio_s / wall,
                "x real time",
                "real time of the audio processed",
                1.0,
                higher_is_better=True,
                target=100.0,
                note=f"{wall:.2f} s wall incl. process start, reading and writing takes",
            )
        )
    for vad, target in (("none", 300.0), ("silero", None)):
        speed, audio_s, wall = _throughput(takes, vad)
        figures.append(
            Figure(
                f"align throughput, VAD {vad} ({n} simulated takes, {audio_s:.0f} s of audio, one process)",
                speed,
                "x real time",
                "real time of the audio processed",
                1.0,
                higher_is_better=True,
                target=target,
                note=f"{wall:.2f} s wall",
            )
        )
    shifts = np.linspace(-0.2, 0.2, n)
    errors = []
    for take, shift in zip(takes, shifts):
        truth = take.meta.extra["simulation"]
        opts = AlignOptions(vad="none", face_lead_ms=truth["face_lead_s"] * 1000)
        rep = align_with_report(_shifted(take, float(shift)), opts)[1]
        errors.append(abs(rep["offset_s"] - (truth["capture_offset_s"] + shift)) * 1000)
    errors = np.asarray(errors)
    label = f"{n} simulated takes of {seconds:g} s, offsets -200..+200 ms, known face lead"
    figures += [
        Figure(f"offset error median ({label})", float(np.median(errors)), "ms", "goal", 5.0, False, 1.0),
        Figure(
            f"offset error p95 ({label})",
            float(np.percentile(errors, 95)),
            "ms",
            "one frame at 60 fps",
            FRAME_60_MS,
            False,
            1.0,
            note=f"max {errors.max():.1f} ms",
        ),
    ]
    if (SAMPLE / "testset.csv").is_file():
        take = read_livelink_csv(SAMPLE / "testset.csv")
        take.attach_audio(read_audio(SAMPLE / "audio.wav"), 0.0, "paired_frame_convention")
        rep = align_with_report(take, AlignOptions())[1]
        shifted = []
        for shift in np.linspace(-0.2, 0.2, 9):
            found = align_with_report(_shifted(take, float(shift)), AlignOptions(vad="none"))[1]["offset_s"]
            shifted.append(abs(found - shift) * 1000)
        figures.append(
            Figure(
                "offset error median, real NeuroSync take with its face shifted by -200..+200 ms (9 shifts)",
                float(np.median(shifted)),
                "ms",
                "one frame at 60 fps",
                FRAME_60_MS,
                False,
                note=f"max {max(shifted):.1f} ms; truth = the shift (the take's own offset taken as 0)",
            )
        )
        by_timecode = align_with_report(take, AlignOptions(vad="none", frame_clock="timecode"))[1]
        figures.append(
            Figure(
                "|offset| found on the real NeuroSync test take (truth 0)",
                abs(rep["offset_s"]) * 1000,
                "ms",
                "one frame at 60 fps",
                FRAME_60_MS,
                False,
                1.0,
                note=f"offset {rep['offset_s'] * 1000:+.1f} ms, {rep['offset_source']}, "
                f"confidence {rep['offset_confidence']:.2f}, frame clock {rep['frame_clock']['clock']} "
                f"(timecodes {rep['frame_clock'].get('timecode_vs_nominal_ppm', 0):+.0f} ppm; placed by "
                f"timecode: {by_timecode['offset_s'] * 1000:+.1f} ms)",
            )
        )
    wavs = sorted((FACEGOOD / "wav").glob("*.wav"))
    if wavs:
        found = []
        for wav in wavs:
            fg = read_paired(
                wav, FACEGOOD / "bs_value" / f"bs_value_{wav.stem}.npy", 30.0, FACEGOOD / "bs_names.txt"
            )
            found.append(align_with_report(fg, AlignOptions(vad="none"))[1]["offset_s"] * 1000)
        figures.append(
            Figure(
                f"max |offset| on the {len(found)} real FACEGOOD takes at 30 fps (truth 0)",
                float(np.max(np.abs(found))),
                "ms",
                "one frame at 30 fps",
                1000.0 / 30.0,
                False,
                1.0,
                note="offsets " + ", ".join(f"{x:+.1f}" for x in found) + " ms",
            )
        )
    return figures
