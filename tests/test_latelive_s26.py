"""Late frames around pauses and bursts of a live session: frames of one take form one run on the phone's
clock, whatever order the network delivers them in. The last frames before a long pause delivered after
it, a take's first frame overtaken by the next ones, a burst of 10 s the network held back: each stays
in its take, in place. Sessions written as the recorder logs them (arrival order), built by
``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import numpy as np
import pytest
from test_review_live_s25 import _markers, _recover

from capture import read_take

FPS = 60
PART = 30 * FPS  # frames of each part (30 s)


def _lines_of_parts(tmp_path, pause_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Frames (offsets from 10:00:00) and on-time arrivals of two 30 s parts ``pause_s`` apart."""
    frames = np.concatenate([np.arange(PART), PART + round(pause_s * FPS) + np.arange(PART)])
    return frames, 1.0 + frames / FPS


@pytest.mark.parametrize("held", [5, 30])
@pytest.mark.parametrize("pause_s", [20.0, 60.0])
def test_the_last_frames_before_a_pause_delivered_after_it_stay_in_their_take(tmp_path, held, pause_s):
    # The network holds the last ``held`` frames before the pause until the first 30 frames after it have
    # come. They go on from the frames before them on the phone's clock: before, 5 of them were stray,
    # and 30 made a recording of their own (a false clock_returned) that cut the next take in two.
    frames, arrivals = _lines_of_parts(tmp_path, pause_s)
    arrivals[PART - held : PART] = arrivals[PART + 30] + 1e-3 + np.arange(held) * 1e-4
    lines = _recover(tmp_path, arrivals, frames)
    assert [_markers(x) for x in lines] == [list(range(PART)), list(range(PART, 2 * PART))]
    assert [(x["dropped_frames"], x["restarts"], x["stray_packets"]) for x in lines] == [(0, 0, 0)] * 2
    assert not any(read_take(x["path"]).meta.repairs for x in lines)


@pytest.mark.parametrize("late", [1, 3])
def test_a_takes_first_frames_11_s_late_are_its_first(tmp_path, late):
    # The first ``late`` frames of each take (the stream's first, and the first after a 30 s pause) arrive
    # 11 s late, after the take's next frames: before, they were stray (more than 10 s behind, in no
    # gap of the recording's no longer than that), and each take began without them.
    frames, arrivals = _lines_of_parts(tmp_path, 30.0)
    for first in (0, PART):
        arrivals[first : first + late] += 11.0
    lines = _recover(tmp_path, arrivals, frames)
    assert [_markers(x) for x in lines] == [list(range(PART)), list(range(PART, 2 * PART))]
    assert [(x["dropped_frames"], x["stray_packets"]) for x in lines] == [(0, 0)] * 2


@pytest.mark.parametrize("after_s", [0.5, 2.0, 15.0])
def test_a_10_s_burst_held_back_fills_its_gap_in_place(tmp_path, after_s):
    # 60 s at 60 fps; 10 s of it (600 packets) held back by the network and delivered together ``after_s``
    # after the last of them was sent. Before, 15 s after: the gap they left (10 s and a frame) was over
    # the limit, and they made a recording of their own (a false clock_returned) that cut the take in
    # four; 2 s after: the burst was taken for the phone's clock stepping back 11 s, its frames placed
    # where they arrived, among the frames after it (a false clock_step_back); 0.5 s after: the burst and
    # the frames after it, one stretch of the clock going back and on past where it was, made a restart
    # (the 30 frames that came before the burst a take of their own).
    arrivals = 1.0 + np.arange(3600) / FPS
    held = slice(1200, 1800)
    arrivals[held] = arrivals[held.stop - 1] + after_s + np.arange(600) * 1e-4
    lines = _recover(tmp_path, arrivals)
    assert [(x["frames"], x["dropped_frames"], x["restarts"], x["stray_packets"]) for x in lines] == [
        (3600, 0, 0, 0)
    ]
    assert _markers(lines[0]) == list(range(3600))
    assert not read_take(lines[0]["path"]).meta.repairs


def test_a_clock_stepping_back_into_the_gap_it_left_is_still_a_recording_of_its_own(tmp_path):
    # What the burst and the held frames are not: the clock steps 30 s forward for 5 s and back, a second
    # after where it was (the frames after the step back go on from none of the take's). A recording of
    # its own with its clock_returned note, as before.
    frames = np.arange(2100)
    frames[900:1200] += 30 * FPS
    frames[1200:] -= 4 * FPS  # back to one second after frame 899
    lines = _recover(tmp_path, 1.0 + np.arange(frames.size) / FPS, frames)
    assert [_markers(x) for x in lines] == [list(range(900)), list(range(900, 1200)), list(range(1200, 2100))]
    kinds = [{r["kind"] for r in read_take(x["path"]).meta.repairs} for x in lines]
    assert kinds == [set(), set(), {"clock_returned"}]
