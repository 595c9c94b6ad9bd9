"""A burst the network held back across midnight in a live session: judged by its last frames (with which
the phone's clock returns to the next day), at most 10 s late, it stays on its day however long it is;
held back longer, it is no step back of the clock by a day: ``_undo_steps_back`` undoes no step further
back than late frames lie behind the clock (``MAX_LATENESS_S``, past which the clock's jump back is a
restart). Sessions written as the recorder logs them (arrival order), built by ``s2a-capture recover`` (a
subprocess)."""

from __future__ import annotations

import numpy as np
from test_livesteps_s27 import _held, _repairs
from test_review_live_s25 import START, _markers, _recover

FPS = 60
DAY = 86400 * FPS  # frames in a day
N = 40 * FPS  # 40 s from 23:59:40
BURST = slice(18 * FPS, 20 * FPS)  # the 2 s of frames sent from 23:59:58 to midnight


def _across_midnight(tmp_path, late_s: float) -> list[dict]:
    """The take lines of 40 s at 60 fps from 23:59:40 whose frames of 23:59:58 to midnight the network
    held back, delivering them ``late_s`` after the last of them was sent."""
    frames = (DAY - 20 * FPS + np.arange(N)) % DAY - START
    arrivals = 1.0 + np.arange(N) / FPS
    _held(arrivals, BURST, late_s)
    return _recover(tmp_path, arrivals, frames)


def test_a_2_s_burst_held_9_5_s_across_midnight_stays_on_its_day(tmp_path):
    # Its last frame 9.5 s late, its first 11.5 s. Before (the first past the 10 s of the midnight rule),
    # the burst was put on the next day and the frames after it were taken for a clock that stepped back a
    # day: a clock_step_back note of 86 390 s, those frames moved a day, into a second take.
    lines = _across_midnight(tmp_path, 9.5)
    assert [(x["frames"], x["dropped_frames"], x["restarts"], x["stray_packets"]) for x in lines] == [
        (N, 0, 0, 0)
    ]
    assert _markers(lines[0]) == list(range(N))
    assert not _repairs(lines[0])


def test_a_burst_held_15_s_across_midnight_moves_no_frame_by_a_day(tmp_path):
    # Its last frame 15 s late: past the midnight rule, it is not put back on its day, but no step back of
    # the phone's clock either. Before, the 300 frames after 00:00:10 were moved back a day, into a take
    # after the burst with a clock_step_back note of 86 385 s.
    lines = _across_midnight(tmp_path, 15.0)
    assert not any("clock_step_back" in _repairs(x) for x in lines)
    on_time = [x for x in lines if 0 in _markers(x)]
    assert len(on_time) == 1
    kept = set(_markers(on_time[0]))
    # every frame in place, but the one that arrived with the burst's first, put a day ahead with it (stray)
    assert set(range(BURST.start)) <= kept and len(set(range(BURST.stop, N)) - kept) <= 1
    assert sum(len(_markers(x)) for x in lines) >= N - 1  # the rest of the burst a take of its own
