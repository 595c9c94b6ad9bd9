"""Inference over audio longer than the model should see at once.

A Transformer's attention grows with the square of the sequence, and its positional encoding only
covers ``max_frames``; training and evaluation see samples of at most the dataset's ``max_sample_s``
(30 s by default). ``infer_windowed`` runs a long sequence as evenly spaced windows of ``window``
frames, each overlapping the next by at least half a window, and blends them: a window's weight ramps
up linearly over its first quarter and down over its last (not at the ends of the sequence), and each
frame is the weighted mean of the windows that hold it, so no window edge shows as a step.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from .precision import infer

# The longest stretch run at once by ``s2a-train predict``: the dataset builder's default longest sample.
PREDICT_WINDOW_S = 30.0


def window_starts(frames: int, window: int) -> list[int]:
    """First frame of each window: evenly spaced at most ``window // 2`` apart, from 0 to
    ``frames - window``."""
    if frames <= window:
        return [0]
    count = math.ceil((frames - window) / max(1, window // 2)) + 1
    return [round(i * (frames - window) / (count - 1)) for i in range(count)]


def blend_weights(window: int, first: bool, last: bool) -> torch.Tensor:
    """A window's weights: linear ramps over its first and last quarter (none at the sequence's ends)."""
    ramp = max(1, window // 4)
    j = torch.arange(window, dtype=torch.float32)
    w = torch.ones(window)
    if not first:
        w = torch.minimum(w, (j + 0.5) / ramp)
    if not last:
        w = torch.minimum(w, (window - j - 0.5) / ramp)
    return w


def _unwatched(done: int, count: int) -> None:
    """No one shows this inference's progress."""


def infer_windowed(
    model: torch.nn.Module,
    content: torch.Tensor,
    prosody: torch.Tensor | None,
    mask: torch.Tensor,
    window: int,
    on_window: Callable[[int, int], None] | None = None,
) -> torch.Tensor:
    """``infer`` over (1, frames, ...) inputs, in blended windows of ``window`` frames when longer.
    ``on_window(done, count)`` before the first window (0) and after each: an hour of speech is
    minutes of windows, whose progress the caller shows."""
    frames = content.shape[1]
    starts = window_starts(frames, window)
    on_window = on_window or _unwatched
    on_window(0, len(starts))
    if len(starts) == 1:
        y = infer(model, content, prosody, mask)
        on_window(1, 1)
        return y
    out = total = None
    for i, s in enumerate(starts):
        part = slice(s, s + window)
        y = infer(model, content[:, part], None if prosody is None else prosody[:, part], mask[:, part])
        if out is None:
            out, total = torch.zeros(y.shape[0], frames, y.shape[2]), torch.zeros(1, frames, 1)
        w = blend_weights(window, i == 0, i == len(starts) - 1)[None, :, None]
        out[:, part] += y * w
        total[:, part] += w
        on_window(i + 1, len(starts))
    return out / total
