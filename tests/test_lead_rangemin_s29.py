"""The least value over many ranges of packets, as a live session's steps are measured with."""

from __future__ import annotations

import numpy as np

from capture.session_takes import _range_min


def test_range_min_is_the_least_of_each_range():
    rng = np.random.default_rng(0)
    for _ in range(200):
        n = int(rng.integers(1, 300))
        values = rng.normal(size=n)
        values[rng.integers(0, n, size=3)] = np.inf  # packets of no lateness measured
        ends = np.sort(rng.integers(0, n + 1, size=(60, 2)), axis=1)
        got = _range_min(values, ends[:, 0], ends[:, 1])
        want = [values[a:b].min() if b > a else np.inf for a, b in ends]
        np.testing.assert_array_equal(got, want)
