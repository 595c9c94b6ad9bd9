"""The last misplaced frames of live sessions: a step back of the phone's clock inside a burst the network
held back (both sides of it released together, in the order sent) is undone like any other; on-time frames
that arrive among a long burst's packets keep their slots; a step back of a few frames is undone. Sessions
written as the recorder logs them (arrival order), built by ``s2a-capture recover`` (a subprocess); the
generators below also make the sessions the changes were measured on (old and new code)."""

from __future__ import annotations

import numpy as np
import pytest
from test_livesteps_s27 import _held, _repairs
from test_review_live_s25 import _markers, _recover

FPS = 60


def plain_session(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames (offsets from 10:00:00), send and arrival times of a session without late-network
    features: parts joined by a pause, a step of the phone's clock forward or back, or a restart; Wi-Fi
    jitter, lost packets and packets swapped with the next."""
    frames, sent = [], []
    offset, t0 = 0, 0.0
    for k in range(int(rng.integers(1, 4))):
        size = int(rng.integers(300, 1500))
        event = rng.choice(["pause", "forward", "back", "restart"]) if k else None
        if event == "pause":  # frame times and arrivals both jump: the sender stopped
            pause = int(rng.integers(6, 40)) * FPS
            offset, t0 = offset + pause, t0 + pause / FPS
        elif event == "forward":
            offset += int(rng.integers(FPS, 30 * FPS))
        elif event == "back":
            offset -= int(rng.integers(8, 55))
        elif event == "restart":
            offset -= int(rng.integers(30, 100)) * FPS
        frames.append(offset + np.arange(size))
        sent.append(t0 + np.arange(size) / FPS)
        offset, t0 = offset + size, t0 + size / FPS
    frames, sent = np.concatenate(frames), np.concatenate(sent)
    arrivals = 1.0 + sent + rng.uniform(0, rng.choice([0.0, 0.005, 0.03, 0.1]), frames.size)
    swap = np.flatnonzero(rng.uniform(size=frames.size - 1) < 0.01)
    arrivals[swap], arrivals[swap + 1] = arrivals[swap + 1], arrivals[swap].copy()
    keep = rng.uniform(size=frames.size) >= rng.choice([0.0, 0.01, 0.05])
    return frames[keep], sent[keep], arrivals[keep]


def held_session(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ``plain_session`` whose network also held back one to three bursts (0.1-5 s of frames, released
    together 0.2-9 s after the last was sent, in the order sent) and a few single frames (up to 9 s)."""
    frames, sent, arrivals = plain_session(rng)
    for _ in range(int(rng.integers(1, 4))):
        length = int(rng.integers(6, 5 * FPS))
        first = int(rng.integers(0, max(1, frames.size - length)))
        _held(arrivals, slice(first, first + length), float(rng.uniform(0.2, 9.0)))
    single = rng.integers(0, frames.size, int(rng.integers(0, 5)))
    arrivals[single] += rng.uniform(0.1, 9.0, single.size)
    return frames, sent, arrivals


def rising_session(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ``plain_session`` whose packets from some point on all come 0.12-0.9 s later (a route that
    changed: the arrivals rise as after a step back of the clock, the frame times do not go back), with a
    few stray frame numbers (up to an hour off, or a few frames back)."""
    frames, sent, arrivals = plain_session(rng)
    arrivals[int(rng.integers(frames.size // 4, frames.size * 3 // 4)) :] += rng.uniform(0.12, 0.9)
    stray = rng.integers(0, frames.size, int(rng.integers(0, 6)))
    frames[stray] += rng.choice([-3600 * FPS, -9, -7, -5, 3600 * FPS], stray.size)
    return frames, sent, arrivals


def step_in_burst(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """60 s at 60 fps whose clock steps back 0.12-0.95 s between 20 and 40 s, the network holding back
    0-3 s of frames on each side of the step and releasing them together 0.2-8 s after the last was
    sent, in the order sent; light jitter. Frames, send and arrival times."""
    n = 60 * FPS
    at = int(rng.integers(20 * FPS, 40 * FPS))
    step = int(rng.integers(round(0.12 * FPS), round(0.95 * FPS)))
    frames = np.arange(n)
    frames[at:] -= step
    arrivals = 1.0 + np.arange(n) / FPS + rng.uniform(0, 0.004, n)
    held = slice(at - int(rng.integers(1, 3 * FPS)), at + int(rng.integers(1, 3 * FPS)))
    _held(arrivals, held, float(rng.uniform(0.2, 8.0)))
    return frames, np.arange(n) / FPS, arrivals


def test_a_step_back_inside_a_held_burst_is_undone(tmp_path):
    # 60 s at 60 fps; at 30 s the phone's clock steps back 0.6 s (36 frames); the network holds the
    # frames of 28.3-31.7 s, both sides of the step, and releases them together 2 s after the last was
    # sent. Before, the step was not found (the frames after it in the burst came after those before it,
    # no packet on time showed it): 36 frames on the slots of the frames before the step were dropped
    # (same_time_dropped) and every frame after it placed 0.6 s early.
    n, at = 60 * FPS, 30 * FPS
    frames = np.arange(n)
    frames[at:] -= 36
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(at - 100, at + 100), 2.0)
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["frames"], x["dropped_frames"], x["same_time_dropped"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert _repairs(lines[0]) == ["clock_step_back"]


@pytest.mark.parametrize("seed", [15, 63])
def test_generated_steps_inside_held_bursts_keep_every_frame(tmp_path, seed):
    # 15: a step of 41 frames, 146 frames before it and 121 after held 5.6 s, an on-time packet among the
    # burst's; 63: 35 frames, 39 before and 13 after held 7 s, the burst's frames before the step on the
    # slots of the frames after it that came on time. Before, 41 and 35 frames dropped, the rest misplaced.
    frames, _, arrivals = step_in_burst(np.random.default_rng(seed))
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["frames"], x["dropped_frames"], x["same_time_dropped"]) for x in lines] == [
        (frames.size, 0, 0)
    ]
    assert _markers(lines[0]) == list(range(frames.size))


def test_on_time_frames_arriving_amid_a_long_burst_keep_their_slots(tmp_path):
    # 60 s at 60 fps; at 30 s the phone's clock steps back 0.6 s (36 frames, undone). The network holds
    # 5 s of frames (20-25 s) and releases them 4.7 s late, just as frame 1780 (on time, 0.33 s before the
    # step) comes: frames 1780 and 1781 arrive among the burst's packets, off the clock it held, on slots
    # the frames after the step (not yet undone) take. Before, both were stray (2 DROPPED frames).
    n, at = 60 * FPS, 30 * FPS
    frames = np.arange(n)
    frames[at:] -= 36
    arrivals = 1.0 + np.arange(n) / FPS
    _held(arrivals, slice(1200, 1500), arrivals[1780] - 5e-4 - arrivals[1499])
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["frames"], x["dropped_frames"], x["stray_packets"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert _repairs(lines[0]) == ["clock_step_back"]


@pytest.mark.parametrize("step", [7, 9])
def test_a_step_back_of_a_few_frames_is_undone(tmp_path, step):
    # 60 s at 60 fps, every packet on time; at 30 s the phone's clock steps back ``step`` frames (0.12-0.18
    # s). Its frames after the step go back over the slots of the last ones before it, which no late,
    # reordered or stray frame does. Before, a step of fewer than about 12 frames was not found (the sides'
    # third frames compared): ``step`` frames on taken slots dropped (same_time_dropped), every frame after
    # it placed ``step`` frames early.
    n, at = 60 * FPS, 30 * FPS
    frames = np.arange(n)
    frames[at:] -= step
    lines = _recover(tmp_path, 1.0 + np.arange(n) / FPS, frames)
    assert [(x["frames"], x["dropped_frames"], x["same_time_dropped"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert _repairs(lines[0]) == ["clock_step_back"]


def test_a_route_that_got_slower_is_no_step_of_the_clock(tmp_path):
    # What a short step is not: from 30 s on every packet comes 0.15 s later (the arrivals rise as after
    # a step back, the frame times go on), one stray frame number 7 frames back among them: no step undone
    # (the stray one dropped on the slot it repeats, as before).
    n = 60 * FPS
    frames = np.arange(n)
    frames[1850] -= 7
    arrivals = 1.0 + np.arange(n) / FPS
    arrivals[30 * FPS :] += 0.15
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["clock_steps_back"], x["same_time_dropped"]) for x in lines] == [(0, 1)]
    assert _markers(lines[0]) == [i for i in range(n) if i != 1850]
    assert not _repairs(lines[0])
