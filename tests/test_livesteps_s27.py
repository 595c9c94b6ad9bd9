"""Late frames next to a step of the phone's clock in live sessions: frames of one take form one run on the
phone's clock at the take's rate, whatever order the network delivers them in. A burst held back over a
clock step back, over midnight or over a restart keeps every frame in its take, in place; two bursts held
back a second apart are no step of the clock. Sessions written as the recorder logs them (arrival order),
built by ``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import numpy as np
from test_review_live_s25 import START, _markers, _recover

from capture import read_take

FPS = 60
DAY = 86400 * FPS  # frames in a day


def _held(arrivals: np.ndarray, held: slice, late_s: float) -> None:
    """The network holds the frames ``held`` and delivers them together ``late_s`` after the last of them
    was sent."""
    arrivals[held] = arrivals[held.stop - 1] + late_s + np.arange(held.stop - held.start) * 1e-4


def _repairs(line: dict) -> list[str]:
    return [r["kind"] for r in read_take(line["path"]).meta.repairs]


def test_frames_held_over_a_clock_step_back_keep_their_frame_times(tmp_path):
    # 60 s at 60 fps; at 30 s the phone's clock steps back 0.6 s (a re-sync: undone, the frames after it
    # moved by the step). 200 frames sent at 25-28.3 s, before the step, reach the computer 5 s later,
    # after it. Before, they were moved by the step too (taken for frames of the clock after it): the
    # last 36 landed on the slots of the frames after them, 29 were dropped and 36 DROPPED frames left.
    n, at = 60 * FPS, 30 * FPS
    frames = np.arange(n)
    frames[at:] -= 36
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(1500, 1700), 5.0)
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["frames"], x["dropped_frames"], x["stray_packets"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert _repairs(lines[0]) == ["clock_step_back"]


def test_frames_held_back_over_midnight_stay_on_their_day(tmp_path):
    # 40 s at 60 fps from 23:59:40; 18 frames sent at 23:59:58 reach the computer 10.3 s late, after
    # midnight. Before, they took the clock back to the day before for a moment, were put on the next day
    # with the others (a day ahead) and read as a step back of the clock of a day: the take was cut 8 s
    # after midnight, 16 of them lost and 18 DROPPED frames left.
    n = 40 * FPS
    first = DAY - 20 * FPS  # 23:59:40
    frames = (first + np.arange(n)) % DAY - START
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(18 * FPS, 18 * FPS + 18), 10.3)
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["frames"], x["dropped_frames"], x["restarts"], x["stray_packets"]) for x in lines] == [
        (n, 0, 0, 0)
    ]
    assert _markers(lines[0]) == list(range(n))
    assert not _repairs(lines[0])


def test_a_burst_held_back_over_a_restart_fills_its_gap_in_the_take_before(tmp_path):
    # 30 s at 60 fps, then the phone restarts (its clock 75 s back) and sends 30 s more. 12 s of the first
    # part (720 frames) reach the computer 20 s late, after the restart: more than 10 s behind, in a gap of
    # more than 10 s, but filling it from end to end, one run with the frames before and after it. Before,
    # they were a take of their own between the two halves of the first part, and the second part was cut
    # in two, its second take with a false clock_returned note: five takes.
    n, at = 60 * FPS, 30 * FPS
    frames = np.arange(n)
    frames[at:] -= 75 * FPS
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(12 * FPS, 24 * FPS), 20.0)
    lines = _recover(tmp_path, arrivals, frames)
    assert [_markers(x) for x in lines] == [list(range(at)), list(range(at, n))]
    assert [(x["dropped_frames"], x["stray_packets"]) for x in lines] == [(0, 0)] * 2
    assert not any(_repairs(x) for x in lines)


def test_two_bursts_held_back_a_second_apart_are_no_step_of_the_clock(tmp_path):
    # 40 s at 60 fps; the network holds 4 s of it (frames 12-16 s) for 10 s and the 5 s after those
    # (16-21 s) until a second after the first burst came. Before, the second burst was taken for the
    # packets after a Wi-Fi burst right after a step back of the clock: a false clock_step_back, the frames
    # after it moved by it, 33 of them lost and the take cut in three.
    n = 40 * FPS
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(12 * FPS, 16 * FPS), 10.0)
    arrivals[16 * FPS : 21 * FPS] = arrivals[12 * FPS] + 1.001 + np.arange(5 * FPS) * 1e-4
    lines = _recover(tmp_path, arrivals)
    assert [(x["frames"], x["dropped_frames"], x["restarts"], x["stray_packets"]) for x in lines] == [
        (n, 0, 0, 0)
    ]
    assert _markers(lines[0]) == list(range(n))
    assert not _repairs(lines[0])
