"""A fresh-eyes review of ``s2a-view`` on inputs it had not seen, and the lock of a render's partial file
taken inside the ``try`` that lets it go."""

from __future__ import annotations

import os
import signal
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import viewer.render
from capture import ARKIT61, Audio, Take, TakeMeta, write_take
from viewer.output import lock_partial
from viewer.plot import plot_curves, speech_segments
from viewer.render import load_animation

# ------------------------------------------------------------------------ a render's partial-file lock


def test_a_stop_landing_as_the_partial_file_is_locked_leaves_neither_lock_nor_file(tmp_path, monkeypatch):
    """``write_mp4`` took the lock one statement before its ``try``: a Ctrl-C landing as ``lock_partial``
    returned left the descriptor open (the next render of that name in the process refused as "another
    command is writing this video") and the empty partial file behind."""
    out, tmp = tmp_path / "take.mp4", tmp_path / ".take.mp4.partial.mp4"

    def then_ctrl_c(*args, **kwargs) -> int:
        fd = lock_partial(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)  # a real Ctrl-C, as the lock is taken
        return fd

    monkeypatch.setattr(viewer.render, "lock_partial", then_ctrl_c)
    before = len(os.listdir("/proc/self/fd"))
    with pytest.raises(KeyboardInterrupt):
        viewer.render.write_mp4(out, lambda k: np.zeros((16, 16, 3), np.uint8), 2, 30.0, None)
    assert len(os.listdir("/proc/self/fd")) == before
    assert os.listdir(tmp_path) == []
    os.close(lock_partial(tmp, out))  # not refused


def test_a_video_of_one_frame_counts_the_time_its_frame_took(tmp_path):
    """The first frame was rendered outside the clock: a 1-frame video said ``render_ms_per_frame`` 0."""

    def slow_frame(k: int) -> np.ndarray:
        time.sleep(0.05)
        return np.zeros((16, 16, 3), np.uint8)

    timing = viewer.render.write_mp4(tmp_path / "one.mp4", slow_frame, 1, 60.0, None)
    assert timing["render_s"] >= 0.05, timing


# ------------------------------------------------------------------------ long takes: memory


def _long_take(folder: Path, frames: int) -> Path:
    """A take folder of ``frames`` frames of the 61 channels, some weights past 1 (clamped by render)."""
    values = np.random.default_rng(0).uniform(0.0, 1.02, (frames, len(ARKIT61))).astype(np.float32)
    meta = TakeMeta(id="long", source_kind="simulated", fps=60.0, channels=list(ARKIT61))
    return write_take(Take(meta, np.arange(frames) / 60.0, values, np.zeros(frames, np.uint8)), folder)


def _peak_bytes(call) -> int:
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_long_take_is_loaded_without_copies_of_all_its_values(tmp_path):
    """A 2-hour take (432,000 frames) took 879 MB to render one PNG (717 MB now, 242 MB of it the CSV
    reader's): its values were converted to float64 whole, then copied whole twice more to find the bad
    frames and once more to count the weights outside 0..1. Now the weights (float64, frames x 61) are
    the one large array made."""
    folder = _long_take(tmp_path, 60_000)
    weights = 60_000 * len(ARKIT61) * 8
    load_animation(folder)  # imports and caches outside the measure
    peak = _peak_bytes(lambda: load_animation(folder))
    assert peak < 2.2 * weights, f"{peak / weights:.2f} x the weights"  # read values (0.5 x) + weights


def test_the_speech_under_a_plot_is_read_a_block_at_a_time(tmp_path):
    """``plot`` of a 2-hour take with 2 hours of 16 kHz speech (230 MB of int16) peaked at 2.5 GB: its
    waveform and its energy segments each made float32 copies of all the samples, the energy two float64
    ones more. Now a block at a time (744 MB, the take's weights and the audio read included); the
    figure is the same, pixel for pixel (checked on a take and on 5.1 audio)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401  (imported outside the measure)

    rate, seconds = 16000, 240
    t = np.arange(rate * seconds) / rate
    speech = (8000 * np.sin(2 * np.pi * 200 * t) * (np.sin(2 * np.pi * 0.2 * t) > 0)).astype(np.int16)
    anim = load_animation(_long_take(tmp_path, 600))
    anim.audio, anim.audio_start_s = Audio(speech[:, None], rate, "PCM_16"), anim.t0
    samples = speech.nbytes
    plot_curves([anim], tmp_path / "warm.png", vad="energy")
    peak = _peak_bytes(lambda: plot_curves([anim], tmp_path / "p.png", vad="energy"))
    assert peak < 2 * samples, f"{peak / samples:.1f} x the int16 samples"


def test_energy_segments_asked_for_are_not_called_a_fallback_for_want_of_a_model(tmp_path):
    """``--vad energy`` labelled its segments "fallback: no VAD model", though the model was there and
    the energy threshold what the user asked for."""
    anim = load_animation(_long_take(tmp_path, 600))
    rate = 16000
    t = np.arange(rate * 10) / rate
    speech = (8000 * np.sin(2 * np.pi * 200 * t) * (t > 3) * (t < 6)).astype(np.int16)
    anim.audio, anim.audio_start_s = Audio(speech[:, None], rate, "PCM_16"), anim.t0
    segments, label = speech_segments(anim, "energy")
    assert label == "loud (energy threshold)", label
    assert len(segments) == 1 and abs(segments[0][0] - anim.t0 - 3) < 0.05, segments
