"""Second review of the live clock's lateness limit: frames the network held back longer than
``MAX_LATENESS_S`` still fill the gap they left in their take (a gap no longer than the limit), as before
the limit; only frames far behind in a long gap (a clock that stepped forward and back) are not late
frames. Sessions written as the recorder logs them, built by ``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import json

import numpy as np
from live_helpers import run_cli
from test_live_leftovers_s22 import FPS, write_frames_log

from capture import FrameStatus, read_take

START = 10 * 3600 * FPS  # 10:00:00 at 60 fps


def write_session(tmp_path, arrivals: np.ndarray, frames: np.ndarray | None = None):
    """The session log of one phone sending frames ``START + frames[i]`` (``frames``: ``i`` when not
    given; marker ``i`` in the first value) that arrived at ``arrivals[i]`` (s), logged in arrival order."""
    frames = np.arange(arrivals.size) if frames is None else frames
    packets = []
    for i in np.argsort(arrivals, kind="stable").tolist():
        values = np.full(61, 0.25, np.float32)
        values[0] = i
        packets.append((START + int(frames[i]), float(arrivals[i]), values))
    session = tmp_path / "live-1.recording"
    write_frames_log(session, packets)
    return session


def _recover(tmp_path, arrivals: np.ndarray, frames: np.ndarray | None = None) -> list[dict]:
    """The take lines ``recover`` gives for that session (``write_session``)."""
    session = write_session(tmp_path, arrivals, frames)
    r = run_cli("recover", str(session), "--json")
    assert r.returncode == 0, r.stderr
    return [json.loads(x) for x in r.stdout.splitlines()]


def _markers(line: dict) -> list[int]:
    take = read_take(line["path"])
    return take.values[take.frame_status == FrameStatus.TRACKED, 0].astype(int).tolist()


def test_a_burst_the_network_held_15_s_stays_in_its_take(tmp_path):
    # 50 s at 60 fps; two seconds of it (120 packets) held back by the network and delivered together
    # 15 s after the last of them was sent. They fill the 2 s gap they left: one take, every frame in
    # place. With the limit alone they were a recording of their own (restarts 1, a clock_returned note)
    # and the take was cut in three around 120 DROPPED frames.
    arrivals = 1.0 + np.arange(3000) / FPS
    held = slice(1000, 1120)
    arrivals[held] = arrivals[held.stop - 1] + 15.0 + np.arange(120) * 1e-4
    lines = _recover(tmp_path, arrivals)
    assert [(x["frames"], x["dropped_frames"], x["restarts"], x["stray_packets"]) for x in lines] == [
        (3000, 0, 0, 0)
    ]
    assert _markers(lines[0]) == list(range(3000))
    assert not read_take(lines[0]["path"]).meta.repairs


def test_single_frames_11_s_late_fill_their_slots(tmp_path):
    # A flaky path: four single frames arrive 11 s late (their neighbours on time). With the limit alone
    # they were stray and left 4 DROPPED frames in the take.
    arrivals = 1.0 + np.arange(3000) / FPS
    arrivals[[500, 1000, 1500, 2000]] += 11.0
    lines = _recover(tmp_path, arrivals)
    assert [(x["frames"], x["dropped_frames"], x["stray_packets"]) for x in lines] == [(3000, 0, 0)]
    assert _markers(lines[0]) == list(range(3000))


def test_a_step_forward_and_back_of_30_s_is_still_a_recording_of_its_own(tmp_path):
    # The clock steps 30 s forward for 5 s, then back: the frames after the step back lie in the 30 s gap
    # the step left, 30 s behind the clock: a recording of their own, as for the hour the change tested.
    frames = np.arange(2100)
    frames[900:1200] += 30 * FPS
    lines = _recover(tmp_path, 1.0 + np.arange(frames.size) / FPS, frames)
    assert [_markers(x) for x in lines] == [list(range(900)), list(range(900, 1200)), list(range(1200, 2100))]
    kinds = [{r["kind"] for r in read_take(x["path"]).meta.repairs} for x in lines]
    assert kinds == [set(), set(), {"clock_returned"}]
