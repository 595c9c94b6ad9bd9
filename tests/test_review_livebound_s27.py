"""Second review of the live clock's bounds over midnight: a re-sync of the phone's clock right after
midnight is still undone, once, when a burst from before midnight comes too late to go back on its day
(no step back of the clock is taken from that burst); a long burst held back over midnight is judged by
its last frames, however late its first. Sessions written as the recorder logs them (arrival order), built
by ``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import numpy as np
from test_livesteps_s27 import _held, _repairs
from test_review_live_s25 import START, _markers, _recover

FPS = 60
DAY = 86400 * FPS  # frames in a day
N = 40 * FPS


def _from(before_midnight_s: int, n: int) -> np.ndarray:
    """Frame numbers (``START`` subtracted, as ``_recover`` adds it) of ``n`` frames from that many
    seconds before midnight."""
    return (DAY - before_midnight_s * FPS + np.arange(n)) % DAY - START


def test_a_re_sync_after_midnight_is_undone_once_beside_a_burst_held_15_s_too_long(tmp_path):
    # 40 s at 60 fps from 23:59:40; 5 s after midnight the clock steps back 0.4 s (a re-sync, undone);
    # the second before midnight reaches the computer 15.5 s late (too late to go back on its day: a take
    # of its own), half a frame period off the frames then coming (none of them inside the burst).
    # Before, the frames after the burst were also taken for a clock that stepped back about a day: a
    # second clock_step_back note, and those frames in a take of their own.
    frames = _from(20, N)
    frames[25 * FPS :] -= 24
    arrivals = 1.0 + np.arange(N) / FPS
    burst = range(19 * FPS, 20 * FPS)
    _held(arrivals, slice(burst.start, burst.stop), 15.5 + 0.5 / FPS)
    lines = _recover(tmp_path, arrivals, frames)
    assert sum(_repairs(x).count("clock_step_back") for x in lines) == 1
    main = next(x for x in lines if 0 in _markers(x))
    assert _repairs(main) == ["clock_step_back"]
    assert sorted(_markers(x) for x in lines) == [
        list(range(burst.start)) + list(range(burst.stop, N)),
        list(burst),
    ]


def test_a_15_s_burst_held_back_over_midnight_stays_on_its_day_by_its_last_frames(tmp_path):
    # 80 s at 60 fps from 23:59:20; the 15 s of frames sent from 23:59:43 to 23:59:58 reach the computer
    # together 5 s after the last of them was sent: 3 s after midnight, its first 20 s late. Before (judged
    # by its first), they were put a day ahead: a take of their own, and 299 DROPPED frames in the take.
    n = 80 * FPS
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(23 * FPS, 38 * FPS), 5.0)
    lines = _recover(tmp_path, arrivals, _from(40, n))
    assert [(x["frames"], x["dropped_frames"], x["restarts"], x["stray_packets"]) for x in lines] == [
        (n, 0, 0, 0)
    ]
    assert _markers(lines[0]) == list(range(n))
    assert not _repairs(lines[0])
