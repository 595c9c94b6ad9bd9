"""Second review of the live clock's steps back (s29): a step's size is measured from packets of its own
clock only, not across a slower route the packets took a few seconds before the step (the lower envelope
of 5 s of packets took the route's extra lateness for part of the step); bursts the network held back
longer than a restart's jump are no step back, however a side of arrivals measures them. Sessions written
as the recorder logs them (arrival order), built by ``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import numpy as np
import pytest
from test_livesteps_s27 import _held, _repairs
from test_review_live_s25 import _markers, _recover

FPS = 60


@pytest.mark.parametrize(
    ("slower_s", "route_at", "step"),
    [
        (0.47, 25 * FPS, 47),  # a route 0.47 s slower from 25 s, the clock back 47 frames at 28.2 s
        (0.22, 25 * FPS, 23),
        (0.54, 28 * FPS, 11),  # the step 2.85 s after the route: measured 0.73 s, a clock step forward
    ],
)
def test_a_slower_route_before_a_step_back_is_not_part_of_the_step(tmp_path, slower_s, route_at, step):
    # 60 s at 60 fps with light jitter; from ``route_at`` every packet comes ``slower_s`` later (a route
    # that changed), and ``route_at`` + 190 frames (3.2 s) on the phone's clock steps back ``step``
    # frames. Before the fix, the step was measured over 5 s of packets before it, reaching back past the
    # route change: ``slower_s`` too much was undone (28, 13 and 32 frames), every frame after the step
    # placed that much late (DROPPED frames in the gap), or a take of its own after a clock step forward.
    n, at = 60 * FPS, route_at + 171
    frames = np.arange(n)
    frames[at:] -= step
    rng = np.random.default_rng(1)
    arrivals = 1.0 + np.arange(n) / FPS + rng.uniform(0, 0.03, n)
    arrivals[route_at:] += slower_s
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["frames"], x["dropped_frames"], x["same_time_dropped"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert _repairs(lines[0]) == ["clock_step_back"]


def test_two_bursts_held_back_over_8_s_at_the_end_of_a_session_are_no_step_back(tmp_path):
    # 34.5 s at 60 fps, light jitter, no step of the clock; the network holds frames 1565-1635 and
    # releases them 8.35 s after the last was sent, and frames 1595-1879 (overlapping) 8.5 s after: both
    # after the session's last on-time packet. Before the fix, the rise measured with a second of arrivals
    # each side (9.0 s) came under the 10 s a step back may reach (measured over packets, 12.2 s: a burst):
    # a step back undone, the frames from 1565 on a take of their own (582 frames, 80 of them DROPPED).
    n = 2067
    arrivals = 1.0 + np.arange(n) / FPS + np.random.default_rng(1).uniform(0, 0.004, n)
    _held(arrivals, slice(1565, 1636), 8.35)
    _held(arrivals, slice(1595, 1880), 8.5)
    lines = _recover(tmp_path, arrivals)
    assert [(x["frames"], x["dropped_frames"], x["same_time_dropped"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert _repairs(lines[0]) == []
