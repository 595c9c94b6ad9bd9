"""Second review of the steps back of the phone's clock found inside held bursts and of a few frames: a
route that got slower (the arrivals rise as after a step, the frame times go on) is still no step when a
Wi-Fi burst came just before the rise, or when the network delivered the last packets before it again
just after it (copies on their own slots, same values). Sessions written as the recorder logs them, built
by ``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from live_helpers import run_cli
from test_live_leftovers_s22 import write_frames_log
from test_liveleft_s28 import FPS
from test_livesteps_s27 import _held, _repairs
from test_review_live_s25 import START, _markers, _recover


@pytest.mark.parametrize(
    ("slower", "burst", "late"), [(0.36, slice(1758, 1780), 0.2), (0.5, slice(1740, 1780), 0.3)]
)
def test_a_wifi_burst_just_before_a_slower_route_is_no_step(tmp_path, slower, burst, late):
    # 60 s at 60 fps, no step of the clock; from 30 s on every packet comes ``slower`` s later (a route
    # that changed). Just before that, a Wi-Fi burst held ``late`` s came: its frames go back in arrival
    # order. Before, they were taken for frames after a step inside a held burst, on the slots of the
    # frames before it, which were their own: a step of ``slower`` undone that was none, as many DROPPED
    # frames left in the take.
    n = 60 * FPS
    arrivals = 1.0 + np.arange(n) / FPS
    arrivals[30 * FPS :] += slower
    _held(arrivals, burst, late)
    lines = _recover(tmp_path, arrivals)
    assert [(x["frames"], x["dropped_frames"], x["clock_steps_back"]) for x in lines] == [(n, 0, 0)]
    assert _markers(lines[0]) == list(range(n))
    assert not _repairs(lines[0])


@pytest.mark.parametrize(("copies", "slower"), [(5, 0.15), (8, 0.15), (12, 0.15), (12, 0.3)])
def test_copies_of_packets_after_a_slower_route_are_no_step(tmp_path, copies, slower):
    # 60 s at 60 fps, no step of the clock; from 30 s on every packet comes ``slower`` s later, and the
    # network delivers the ``copies`` packets before that again just after it (the same datagrams: same
    # slots, same values). Before, the copies were taken for frames of a clock that stepped back a few
    # frames, on the slots of those before it: a step undone that was none, every frame after it placed
    # that many frames late around DROPPED frames, the copies kept as frames (12 copies with 0.15 s: so
    # already before the steps of a few frames, the copies taken for the third earliest frame after it).
    n, rise = 60 * FPS, 30 * FPS
    arrivals = 1.0 + np.arange(n) / FPS
    arrivals[rise:] += slower
    packets = [(START + i, float(arrivals[i]), np.full(61, i, np.float32)) for i in range(n)]
    packets += [
        (START + i, float(arrivals[rise]) + 1e-3 * (k + 1), packets[i][2])
        for k, i in enumerate(range(rise - copies, rise))
    ]
    session = tmp_path / "live-1.recording"
    write_frames_log(session, sorted(packets, key=lambda p: p[1]))
    r = run_cli("recover", str(session), "--json")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [(x["frames"], x["dropped_frames"], x["duplicates"], x["clock_steps_back"]) for x in lines] == [
        (n, 0, copies, 0)
    ]
    assert _markers(lines[0]) == list(range(n))


def test_a_wifi_burst_from_a_sender_ticking_twice_a_frame_before_a_slower_route_is_no_step(tmp_path):
    # The Wi-Fi burst of the first test, from a sender ticking at 120 Hz on a 60 fps frame clock (each
    # frame time twice, other values; kept spread over the frame period). Before, the burst's frames
    # went back onto the slots of their own twins: a step of 0.36 s undone that was none, 44 DROPPED.
    n = 60 * FPS
    arrivals = 1.0 + np.arange(2 * n) / (2 * FPS)
    arrivals[2 * 30 * FPS :] += 0.36
    _held(arrivals, slice(2 * 1758, 2 * 1780), 0.2)
    packets = [(START + i // 2, float(arrivals[i]), np.full(61, i, np.float32)) for i in range(2 * n)]
    session = tmp_path / "live-1.recording"
    write_frames_log(session, sorted(packets, key=lambda p: p[1]))
    r = run_cli("recover", str(session), "--json")
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [(x["frames"], x["dropped_frames"], x["clock_steps_back"]) for x in lines] == [(2 * n, 0, 0)]
    assert _markers(lines[0]) == list(range(2 * n))


def test_a_restart_logged_faster_than_real_time_keeps_its_frames_out_of_the_take_before(tmp_path):
    # 10 s at 60 fps, then the clock goes back 1.5 s (an NTP correction: a new recording) for 10 s; Wi-Fi
    # jitter of up to 0.5 s mixes the two in arrival order, and the sender (a replay as fast as it could)
    # logged every packet within microseconds. The new recording's frames amid the late ones of the first
    # land on the first's slots, whose frames came before them: taken. Before, any frame on a slot
    # whose frame came less than the clock's tolerance apart counted as free: frames of the new
    # recording were placed into the first take (602 frames).
    rng = np.random.default_rng(5)
    frames = np.concatenate([np.arange(600), 510 + np.arange(600)])
    order = np.argsort(np.arange(1200) / FPS + rng.uniform(0, 0.5, 1200), kind="stable")
    arrivals = np.empty(1200)
    arrivals[order] = 1.0 + np.arange(1200) * 1e-5
    lines = _recover(tmp_path, arrivals, frames)
    assert [(x["frames"], x["dropped_frames"]) for x in lines] == [(600, 0), (600, 0)]
    assert [_markers(x) for x in lines] == [list(range(600)), list(range(600, 1200))]
