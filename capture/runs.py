"""Runs of True in a boolean array: stretches of frames lost, clipped, voiced, off the row rate."""

from __future__ import annotations

import numpy as np


def run_bounds(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, stops) index arrays of the runs of True in ``mask`` (stop is one past the run's end)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], np.asarray(mask).astype(np.int8), [0]])))
    return edges[::2], edges[1::2]


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the runs of True in ``mask``."""
    return [(int(a), int(b)) for a, b in zip(*run_bounds(mask))]
