"""Live speech animation (``s2a-view speak``, ``train.streaming.LiveAnimator``): compute per hop of a
paper-sized Transformer-S2A run over real speech, its real-time factor (compute / hop), the features'
and the model's share, 1 vs 2 threads, against offline ``animate_16k`` of the same context.

The run is a real one: simulated takes built into a dataset with the default features (pitch, energy,
filter banks) and ``s2a-train fit`` with the default (paper) sizes for two steps, loaded as ``speak``
loads it (``load_for_animation``); its weights are as good as random, which costs the same. The speech
is FACEGOOD's real 16 kHz recordings, made what the model hears (``model_audio``), handed to the
animator a hop at a time as fast as it computes (no pacing: only compute is measured). Hops before the
context is full (shorter contexts, cheaper) are not counted. Each hop is timed in wall and CPU time
(the process's, every thread's); the model's share is timed by hooks on its forward pass, the rest
(speech level, features, normalisation, de-normalisation) is the features'. After every hop, offline
``animate_16k`` of the same context audio is timed too (interleaved: load from other processes hits
both alike): a live hop cannot cost less than that.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.figure import Figure
from viewer.cli import DEFAULT_CONTEXT_S, DEFAULT_HOP_S, DEFAULT_LATENCY_S

FACEGOOD = Path(__file__).resolve().parents[1].parent / "shared/samples/paired/facegood-audio2face/wav"
SPEECH = ("1114_2_01.wav", "1114_2_03.wav")  # real Mandarin speech, 16 kHz (samples' SOURCES.md)
RUNS = (  # (context s, hop s, threads): speak's defaults first
    (DEFAULT_CONTEXT_S, DEFAULT_HOP_S, 1),
    (DEFAULT_CONTEXT_S, DEFAULT_HOP_S, 2),
    (2.0, DEFAULT_HOP_S, 1),
    (8.0, DEFAULT_HOP_S, 1),
)


def paper_sized_run(tmp: Path) -> Path:
    """A run of ``s2a-train fit`` at the default (paper) sizes, two steps on three simulated takes."""
    from benchmarks.bench_dataset import simulated_aligned_takes
    from dataset import BuildOptions, SplitRule, build_dataset
    from train.config import resolve_config
    from train.fit import fit

    aligned, _ = simulated_aligned_takes(tmp / "takes", 3, 4.0)
    build_dataset(
        [aligned], tmp / "ds", BuildOptions(split=SplitRule("take", 0.34, 0.0, 0)), say=lambda _m: None
    )
    cfg = resolve_config(sets=["max_steps=2", "eval_every=2", "batch_size=2"])
    fit(tmp / "ds", tmp / "run", cfg, say=lambda _m: None)
    return tmp / "run"


def real_speech(seconds: float) -> np.ndarray:
    """``seconds`` of FACEGOOD speech as the model hears it (16 kHz mono, ``model_audio``)."""
    from capture import Audio, read_audio
    from train.predict import model_audio

    parts, left = [], int(seconds * 16000)
    for name in SPEECH:
        raw = read_audio(FACEGOOD / name, [])
        cut = Audio(raw.samples[:left], raw.sample_rate, raw.subtype)  # 16 kHz: as many samples as heard
        parts.append(model_audio(cut))
        left -= parts[-1].size
        if left <= 0:
            break
    return np.concatenate(parts)


class ForwardClock:
    """Wall and CPU seconds spent in ``model``'s forward passes (hooks on the real model)."""

    def __init__(self, model) -> None:
        self.wall = self.cpu = 0.0
        model.register_forward_pre_hook(self._enter)
        model.register_forward_hook(self._leave)

    def _enter(self, *_args) -> None:
        self._at = time.perf_counter(), time.process_time()

    def _leave(self, *_args) -> None:
        self.wall += time.perf_counter() - self._at[0]
        self.cpu += time.process_time() - self._at[1]


def hops(model, payload, ppg, clock: ForwardClock, speech: np.ndarray, context_s: float, hop_s: float):
    """Per counted hop: (wall s, CPU s, model CPU s) of the live hop, (wall s, CPU s) of offline
    ``animate_16k`` of the same context."""
    from train.predict import animate_16k
    from train.streaming import LiveAnimator

    animator = LiveAnimator(model, payload, context_s, DEFAULT_LATENCY_S, ppg)
    step, context = int(round(hop_s * 16000)), int(round(context_s * 16000))
    live, offline = [], []
    for end in range(step, speech.size + 1, step):
        animator.add(speech[end - step : end])
        model_cpu = clock.cpu
        w, c = time.perf_counter(), time.process_time()
        animator.hop()
        w, c = time.perf_counter() - w, time.process_time() - c
        if end - 2 * step < context:  # the context is not full yet (a frame's worth of margin)
            continue
        live.append((w, c, clock.cpu - model_cpu))
        heard = speech[end - context : end]
        w, c = time.perf_counter(), time.process_time()
        animate_16k(model, payload, heard, ppg)
        offline.append((time.perf_counter() - w, time.process_time() - c))
    return np.array(live), np.array(offline)


def run(quick: bool = False) -> list[Figure]:
    import os

    import torch

    from train.predict import load_for_animation

    counted = 6.0 if quick else 25.0  # seconds of speech whose hops are counted, after the context fills
    runs = RUNS[:1] if quick else RUNS
    threads_before = torch.get_num_threads()
    figures = []
    with tempfile.TemporaryDirectory() as tmp:
        model, payload, ppg = load_for_animation(paper_sized_run(Path(tmp)), say=lambda _m: None)
    clock = ForwardClock(model)
    speech = real_speech(max(c for c, _h, _t in runs) + 0.5 + counted)
    try:
        for context_s, hop_s, threads in runs:
            torch.set_num_threads(threads)
            part = speech[: int((context_s + 0.5 + counted) * 16000)]
            live, offline = hops(model, payload, ppg, clock, part, context_s, hop_s)
            wall, cpu, model_cpu = (float(x) for x in np.median(live, axis=0))
            p95 = float(np.percentile(live[:, 0], 95))
            share = float(np.sum(live[:, 2]) / np.sum(live[:, 1]))
            off_wall, off_cpu = (float(x) for x in np.median(offline, axis=0))
            label = f"context {context_s:g} s, hop {hop_s:g} s, {threads} thread{'s' * (threads > 1)}"
            load = os.getloadavg()[0]
            note = (
                f"{len(live)} hops of real speech; model {share:.0%} of the CPU, features {1 - share:.0%}; "
                f"load average {load:.1f} at {time.strftime('%H:%M')}"
            )
            figures += [
                Figure(
                    f"speak compute per hop, median, {label}",
                    wall * 1e3,
                    "ms",
                    "offline animate_16k of the same context",
                    off_wall * 1e3,
                    False,
                    None,
                    f"p95 {p95 * 1e3:.0f} ms; {note}",
                ),
                Figure(
                    f"speak CPU time per hop, median, {label}",
                    cpu * 1e3,
                    "ms",
                    "offline animate_16k of the same context",
                    off_cpu * 1e3,
                    False,
                    None,
                    f"every thread's; model {model_cpu * 1e3:.0f} ms",
                ),
                Figure(
                    f"speak real-time factor (median compute per hop / hop), {label}",
                    wall,
                    "s",
                    "the hop",
                    hop_s,
                    False,
                    1.0,
                    f"p95: {p95 / hop_s:.2f}; in CPU time: {cpu / hop_s:.2f}",
                ),
            ]
    finally:
        torch.set_num_threads(threads_before)
    return figures
