"""A second pair of eyes on the viewer's block-wise reading of a plot's speech and on the train package
whose names import on first use (capture.lazy_package)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from capture import ARKIT61, Audio, Take, TakeMeta, write_take
from viewer.plot import plot_curves
from viewer.render import load_animation


def _take(folder: Path, frames: int = 150) -> Path:
    values = np.random.default_rng(0).uniform(0.0, 1.0, (frames, len(ARKIT61))).astype(np.float32)
    meta = TakeMeta(id="short", source_kind="simulated", fps=60.0, channels=list(ARKIT61))
    return write_take(Take(meta, np.arange(frames) / 60.0, values, np.zeros(frames, np.uint8)), folder)


def _waveform_rows(png: Path) -> int:
    """How many pixel rows of the figure's lower half (the speech panel) the gray waveform reaches."""
    import matplotlib.image

    rgb = matplotlib.image.imread(png)[..., :3]
    lower = rgb[rgb.shape[0] // 2 :]
    gray = (np.ptp(lower, axis=2) < 0.01) & (lower[..., 0] > 0.1) & (lower[..., 0] < 0.85)  # not the spines
    rows = np.flatnonzero(gray.sum(axis=1) > lower.shape[1] // 4)  # across the panel: not a label's
    return int(rows.max() - rows.min() + 1)


def test_a_plots_speech_is_scaled_to_its_loudest_sample_also_among_the_last_few(tmp_path):
    """The waveform's height is scaled to the loudest sample, as when all samples were loaded at once.
    Read a block at a time (viewer.plot.audio_frames), the last partial envelope row was left out of the
    scale too: a loud last sample (here 0.95 after samples within ±0.3) drew the waveform three times as
    high as before, filling its panel."""
    anim = load_animation(_take(tmp_path / "take"))
    quiet = np.random.default_rng(1).uniform(-0.3, 0.3, 40_001)  # 20000 rows of 2 samples, 1 left over
    loud_tail = quiet.copy()
    loud_tail[-1] = 0.95
    heights = []
    for name, samples in (("quiet", quiet), ("loud_tail", loud_tail)):
        anim.audio = Audio((samples * 32767).astype(np.int16)[:, None], 16000, "PCM_16")
        anim.audio_start_s = anim.t0
        plot_curves([anim], tmp_path / f"{name}.png", vad="none")
        heights.append(_waveform_rows(tmp_path / f"{name}.png"))
    quiet_rows, loud_tail_rows = heights
    assert loud_tail_rows < 0.5 * quiet_rows, heights  # scaled to 0.95, not 0.3
