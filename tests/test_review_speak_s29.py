"""Second review of speak's microphone at its own rate and its frame numbers: the callback in a thread of
its own, blocks of no or one sample, rates other than 44.1/48 kHz; speak numbers its frames as replay
numbers a take's (one ``frame_times``), checked against the real ``s2a-capture replay``."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from conftest import run_cli
from live_helpers import synthetic_take
from test_speak_s28 import Receiver
from test_speak_s29 import speech_at

from capture import ARKIT61
from capture.replay import values_in_engine_order
from capture.take import write_take


@pytest.mark.parametrize("rate", [8000, 22050, 96000])
def test_a_microphone_heard_in_its_own_thread_is_resampled_as_offline(samples, rate):
    """Real speech at 8/22.05/96 kHz: first a block of one sample, a take of nothing, a block of no
    sample, then blocks of 0-4096 samples handed over by a thread of their own (as PortAudio's) while
    this one takes what has arrived. Whatever the interleaving, the 16 kHz samples are those of
    resampling the whole at once, bit for bit, but for the filter's last samples held back (measured:
    up to 111 ms at 8 kHz, 85 ms at 44.1)."""
    import sounddevice as sd
    import soxr

    from viewer.speak import MicBlocks

    x = speech_at(samples, rate)[: 3 * rate]
    whole = soxr.resample(x, rate, 16000, "VHQ")
    mic = MicBlocks(rate)
    parts = []
    for block in (x[:1], x[1:1]):  # one sample, then none: taken alone, and a take of nothing between
        mic.heard(block[:, None], block.size, None, sd.CallbackFlags())
        parts += [mic.taken(), mic.taken()]

    def callback_thread():
        rng = np.random.default_rng(11)
        at = 1
        while at < x.size:
            block = x[at : at + int(rng.choice([0, 1, 2, 441, 1024, 4096]))]
            at += block.size
            mic.heard(block[:, None], block.size, None, sd.CallbackFlags())
            time.sleep(0.0002)  # a sound card's pace: a block at a time, the other thread runs between

    heard = threading.Thread(target=callback_thread)
    heard.start()
    while heard.is_alive():
        parts.append(mic.taken())
        time.sleep(0.0002)  # as speak's hops: taken between the callbacks, not in one go after them
    heard.join()
    parts.append(mic.taken())
    assert all(p.dtype == np.float32 and p.ndim == 1 for p in parts)
    got = np.concatenate(parts)
    assert 0 <= whole.size - got.size <= 0.15 * 16000, (whole.size, got.size)
    np.testing.assert_array_equal(got, whole[: got.size])


@pytest.mark.parametrize("day_s", [36000.1, 43200.2])
def test_speak_numbers_its_frames_as_replay_does(tmp_path, day_s):
    """A take begun on a frame's boundary (10:00:00.100, 12:00:00.200 at 60 fps) sent by the real
    ``s2a-capture replay``, and the same frames sent by speak at the same time of day: the same frame
    numbers, sub-frames and values, none rejected (was: speak sent 32 and 80 of the 240 with the frame
    number before theirs and a sub-frame of 1.0, which the decoder rejects as ``bad_frame_time``)."""
    from viewer.speak import LiveLinkOut

    take = synthetic_take(240)
    take.meta.csv = {"start_seconds_of_day": day_s}
    folder = write_take(take, tmp_path)
    rx = Receiver()
    proc = run_cli("capture", "replay", folder, "--to", rx.to, "--speed", 100)
    replayed = rx.frames()
    assert proc.returncode == 0, proc.stderr

    rx = Receiver()
    out = LiveLinkOut(rx.to, list(ARKIT61), 60.0, "review", None, None)
    out.begin()
    out.day_s = day_s  # the time of day the stream began
    try:
        for k, row in enumerate(values_in_engine_order(take)):
            out.send(k, row)
    finally:
        out.close()
    spoken = rx.frames()

    assert len(spoken) == len(replayed) == 240
    for frames in (replayed, spoken):
        assert [f for f in frames if isinstance(f, str)] == []  # none rejected
    assert [f.frame_number for f in spoken] == [f.frame_number for f in replayed]
    assert [f.sub_frame for f in spoken] == [f.sub_frame for f in replayed]
    np.testing.assert_array_equal([f.values for f in spoken], [f.values for f in replayed])
