"""The simulated phone of the realtime stream numbers its frames as replay and speak do."""

from __future__ import annotations

import numpy as np
import pytest
from live_helpers import synthetic_take

from capture.replay import frame_times, rate_of
from capture.simulate.cps_phone import RealtimeFrames
from capture.take import FrameStatus


@pytest.mark.parametrize("day_s", [36000.1, 43200.2])
def test_the_simulated_phone_numbers_a_boundary_start_as_replay(day_s):
    """A take begun on a frame's boundary (10:00:00.100 at 60 fps): consecutive frame numbers, sub-frames
    in [0, 1), replay's numbers (was: 32 and 80 of 240 frames sent with the number before theirs and a
    sub-frame clamped just under 1)."""
    take = synthetic_take(240)
    take.frame_status[:] = FrameStatus.TRACKED
    take.meta.csv = {"start_seconds_of_day": day_s}
    frames = RealtimeFrames.of_take(take)
    assert np.all(np.diff(frames.frame_number) == 1)
    assert np.all((frames.sub_frame >= 0) & (frames.sub_frame < 1))
    number, sub = frame_times(day_s + take.time, *rate_of(take.meta.fps))
    np.testing.assert_array_equal(frames.frame_number, number)
    np.testing.assert_array_equal(frames.sub_frame, sub)
