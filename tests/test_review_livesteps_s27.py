"""Second review of late frames next to a step of the phone's clock in live sessions: a packet the
network held back, delivered just before a burst it held back longer, neither makes the burst a step of
the clock nor is one itself; both stay in their take, in place. Sessions written as the recorder logs
them (arrival order), built by ``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import numpy as np
import pytest
from test_livesteps_s27 import _held, _repairs
from test_review_live_s25 import _markers, _recover

FPS = 60


@pytest.mark.parametrize(("single", "before_s"), [(2000, 0.5), (1000, 3.0), (2700, 0.5), (3000, 0.75)])
def test_a_late_frame_just_before_a_burst_held_longer_is_no_step_of_the_clock(tmp_path, single, before_s):
    # 60 s at 60 fps; the network holds 200 frames (40-43.3 s) for 20 s, and one frame (sent before or
    # after them) until ``before_s`` before they come, after the last frame. The burst's packets then
    # seemed to come over ``before_s``, at the recording's pace: a step back of the clock by their
    # lateness. With a frame from before them: the burst was moved 20 s on by it, a false clock_step_back
    # note and 341 DROPPED frames (as before the reviewed change). With one from after them: the reviewed
    # change kept the burst in place but moved that frame alone, into no take (1 DROPPED frame left).
    n = 60 * FPS
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(2400, 2600), 20.0)
    arrivals[single] = arrivals[2400] - before_s
    lines = _recover(tmp_path, arrivals)
    assert [(x["frames"], x["dropped_frames"], x["stray_packets"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert not _repairs(lines[0])
