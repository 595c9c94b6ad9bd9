"""Second review of late frames in live sessions: a Wi-Fi burst right after a real step back of the
phone's clock comes as fast as a burst the network held back, but the packets after it stay behind by
the step (the step is undone, no frame lost); a stretch after a step back cut where the clock comes back
up to where it was is not a held burst when its frames land on slots the take has; a packet logged days
late costs nothing for the days between. Sessions written as the recorder logs them (arrival order),
built by ``s2a-capture recover`` (a subprocess)."""

from __future__ import annotations

import json
import resource
import subprocess
import sys

import numpy as np
import pytest
from test_review_live_s25 import _markers, _recover, write_session

from capture import read_take

FPS = 60


def _recover_step_back_with_burst(tmp_path, n, step_s, burst, held_s):
    """Recover a session of ``n`` packets at ``FPS`` whose clock steps back ``step_s`` halfway through,
    the first ``burst`` packets after the step held ``held_s`` and delivered together."""
    at = n // 2
    frames = np.arange(n)
    frames[at:] -= round(step_s * FPS)
    arrivals = 1.0 + np.arange(n) / FPS
    arrivals[at : at + burst] = arrivals[at + burst - 1] + held_s + np.arange(burst) * 1e-4
    return _recover(tmp_path, arrivals, frames)


@pytest.mark.parametrize(("step_s", "burst"), [(1.0, 60), (0.5, 60)])
def test_a_wifi_burst_right_after_a_clock_step_back_leaves_the_step_undone(tmp_path, step_s, burst):
    # 60 s at 60 fps; at 30 s the phone's clock steps back ``step_s`` (a re-sync) and Wi-Fi holds the
    # first ``burst`` packets after the step for 0.3 s, then delivers them together. The packets after
    # the burst are as late against their frame times as the step: a step back, undone (its note), every
    # frame kept. Read as a burst the network held back, the frames after the step were left on the slots
    # of the frames before it, and 30-59 of them were dropped as sharing their frame times.
    n = 60 * FPS
    lines = _recover_step_back_with_burst(tmp_path, n, step_s, burst, held_s=0.3)
    assert len(lines) == 1
    markers = _markers(lines[0])
    assert len(markers) >= n - 1  # the one packet right at the step may be stray, as before the change
    assert markers == sorted(markers)  # each frame in its place: those after the step moved by it
    assert lines[0]["frames"] == n and lines[0]["dropped_frames"] <= 1
    assert [r["kind"] for r in read_take(lines[0]["path"]).meta.repairs] == ["clock_step_back"]


@pytest.mark.parametrize(("step_s", "burst"), [(0.5, 80), (0.3, 70)])
def test_a_burst_after_a_clock_step_back_that_ends_where_the_clock_was_keeps_every_frame(
    tmp_path, step_s, burst
):
    # As above, a longer burst: the stretch of the clock after the step is cut where it comes back up to
    # where it was before the step, at the burst's end. Its frames land on slots of the frames before the
    # step: not a burst the network held back into the gap it left (those fill it) but a clock that gave
    # these frame times twice, kept apart as before the change (two takes, every frame in one). Taken for
    # late frames of the take, 17-59 of them were dropped as sharing their frame times.
    n = 60 * FPS
    lines = _recover_step_back_with_burst(tmp_path, n, step_s, burst, held_s=0.2)
    kept = sorted(m for x in lines for m in _markers(x))
    assert kept == list(range(n))
    assert sum(x["stray_packets"] for x in lines) == 0


def test_a_packet_logged_days_late_costs_no_memory_for_the_days_between(tmp_path):
    # A held burst makes the clock ask how fast the recording runs (``_typical_pace``); one packet whose
    # arrival was logged ~285 years on (a corrupt or skewed arrival stamp). The pace was taken over a grid
    # of seconds across the whole span: 67 GiB asked for, and the take not written (its 3600 frames lost,
    # exit 1); an arrival 1e7 s on cost 3 s and 0.5 GB. Now one take, every frame.
    n = 60 * FPS
    arrivals = 1.0 + np.arange(n) / FPS
    arrivals[1200:1800] = arrivals[1799] + 2.0 + np.arange(600) * 1e-4
    arrivals[-1] = 9e9
    session = write_session(tmp_path, arrivals)

    def limit_memory():  # so that a machine with the memory to spare fails too
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    cmd = [sys.executable, "-m", "capture", "recover", str(session), "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, preexec_fn=limit_memory)
    assert r.returncode == 0, r.stderr
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [x["frames"] for x in lines] == [n]
    assert _markers(lines[0]) == list(range(n))
