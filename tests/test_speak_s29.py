"""``s2a-view speak``'s leftovers: a microphone at its own rate (44.1/48 kHz) resampled to 16 kHz as it
arrives, its input overflows counted, a warm-up before the first hop, frame numbers on a frame's
boundary, and one destination lookup shared with replay."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf
from test_speak_s28 import SPEECH, Receiver, run  # noqa: F401 (run: a fixture)

from capture import livelink as ll
from capture.errors import InputError

SPEECH_44K = "paired/neurosync-trainer-lite-testset/audio.wav"  # real English speech, 44.1 kHz


def speech_at(samples, rate: int) -> np.ndarray:
    """NeuroSync's 20 s of real speech at ``rate`` Hz: its own 44.1 kHz, or resampled offline."""
    from scipy.signal import resample_poly

    x, own = sf.read(samples / SPEECH_44K, dtype="float32")
    assert own == 44100
    if rate == own:
        return x
    g = np.gcd(rate, own)
    return resample_poly(x, rate // g, own // g).astype(np.float32)


@pytest.mark.parametrize("rate", [44100, 48000])
def test_a_microphone_at_its_own_rate_is_resampled_as_offline(samples, rate):
    """Real speech at 44.1/48 kHz handed to the microphone's callback in blocks of 1-4096 samples, taken
    every few blocks: the 16 kHz samples are those of resampling the whole at once, to float32's last
    bit (measured: max difference 0.0), but for the filter's last 9-85 ms held back for the next block;
    were each block resampled on its own, its joins would click (measured: max difference 1.49)."""
    import sounddevice as sd
    import soxr
    from scipy.signal import resample_poly

    from viewer.speak import MicBlocks

    x = speech_at(samples, rate)
    whole = soxr.resample(x, rate, 16000, "VHQ")
    g = np.gcd(rate, 16000)
    mic = MicBlocks(rate)
    rng = np.random.default_rng(7)
    taken, alone, at = [], [], 0
    while at < x.size:
        block = x[at : at + int(rng.integers(1, 4097)), None]  # (frames, channels) as PortAudio's
        at += block.shape[0]
        mic.heard(block, block.shape[0], None, sd.CallbackFlags())
        alone.append(resample_poly(block[:, 0], 16000 // g, rate // g))  # each block alone
        if rng.random() < 0.3:
            taken.append(mic.taken())
    taken.append(mic.taken())
    got = np.concatenate(taken)
    assert 0 <= whole.size - got.size <= 0.06 * 16000, (whole.size, got.size)
    assert np.abs(got - whole[: got.size]).max() <= 1e-6
    assert mic.overflows == 0
    alone = np.concatenate(alone)[: got.size]  # what a filter without state gives: clicks at the joins
    assert np.abs(alone - got[: alone.size]).max() > 0.1


def test_input_overflows_are_counted_and_lose_no_block(samples):
    """Three of the callback's blocks flagged as input overflow (the sound card lost samples before
    them): counted three times, and every sample handed over is still taken."""
    import sounddevice as sd

    from viewer.speak import MicBlocks

    x = speech_at(samples, 16000)[: 16000 * 2]  # 16 kHz: taken as handed over
    mic = MicBlocks(16000)
    blocks = np.array_split(x, 40)
    for k, block in enumerate(blocks):
        status = sd.CallbackFlags()
        status.input_overflow = k in (3, 17, 30)
        mic.heard(block[:, None], block.size, None, status)
    assert mic.overflows == 3
    np.testing.assert_array_equal(mic.taken(), x)


def test_warm_up_leaves_the_stream_as_it_was(run, samples):  # noqa: F811
    """The warm-up runs the features and the model once on silence and changes nothing of the stream:
    the frames of 2 s of real speech after it are bit for bit those without it."""
    from train.predict import load_for_animation
    from train.streaming import LiveAnimator

    x, _ = sf.read(samples / SPEECH, dtype="float32", frames=2 * 16000, start=20 * 16000)
    model, payload, ppg = load_for_animation(run, None)
    frames = []
    for warm in (False, True):
        animator = LiveAnimator(model, payload, 1.0, 0.2, ppg)
        if warm:
            animator.warm_up()
            assert animator.emitted == animator.received == animator.compute_ms.count == 0
            assert animator.level is None
        parts = []
        for block in np.array_split(x, 8):
            animator.add(block)
            parts.append(animator.hop()[1])
        parts.append(animator.finish()[1])
        frames.append(np.concatenate(parts))
    assert frames[0].shape == (120, len(animator.channels))
    np.testing.assert_array_equal(frames[0], frames[1])


def test_frame_numbers_on_a_frame_boundary_neither_repeat_nor_skip():
    """A stream begun on a frame's boundary to the microsecond (10:00:00.100 at 60 fps): the day's
    seconds plus a frame's time land a hair under whole frames, whose sub-frame is 1.0 as float32.
    Carried into the frame number (as replay does), the 240 frames sent (few enough for a small socket
    buffer) are numbered one after the other, each at its time (was: 32 of them sent with the number
    before theirs and a sub-frame of 1.0, which s2a-capture's listener rejects as ``bad_frame_time``)."""
    from viewer.speak import LiveLinkOut

    rx = Receiver()
    out = LiveLinkOut(rx.to, ["jawOpen"], 60.0, "boundary", None, None)
    out.begin()
    out.day_s = 36000.1  # the time of day the stream began
    try:
        for k in range(240):
            out.send(k, np.zeros(ll.BLENDSHAPE_COUNT, np.float32))
    finally:
        out.close()
    frames = rx.frames()
    assert [f for f in frames if isinstance(f, str)] == []  # no packet rejected
    numbers = np.array([f.frame_number for f in frames])
    subs = np.array([f.sub_frame for f in frames])
    assert len(frames) == 240 and np.all((subs >= 0) & (subs < 1))
    assert np.all(np.diff(numbers) == 1), np.flatnonzero(np.diff(numbers) != 1)[:5]
    assert numbers[0] == 36000.1 * 60 and np.allclose(numbers + subs, 36000.1 * 60 + np.arange(240))


def test_speak_and_replay_share_one_destination_lookup(tmp_path):
    """speak's and replay's destination: one lookup (``replay.udp_target``), IPv6 in brackets sent to
    over IPv6, a name that does not resolve one error, the same for both."""
    import socket

    from capture import replay
    from viewer.speak import LiveLinkOut

    with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as rx:
        rx.bind(("::1", 0))
        rx.settimeout(30)
        to = f"[::1]:{rx.getsockname()[1]}"
        out = LiveLinkOut(to, ["jawOpen"], 60.0, "v6", None, None)
        assert (out.target, out.family) == replay.udp_target(*replay.parse_destination(to))
        out.begin()
        out.send(0, np.zeros(ll.BLENDSHAPE_COUNT, np.float32))
        out.close()
        assert ll.decode_packet(rx.recv(4096)).values.shape == (ll.BLENDSHAPE_COUNT,)
    messages = []
    for call in (
        lambda: LiveLinkOut("nosuch.invalid:11111", ["jawOpen"], 60.0, "x", None, None),
        lambda: replay.udp_target("nosuch.invalid", 11111),
    ):
        with pytest.raises(InputError) as exc:
            call()
        messages.append(str(exc.value))
    assert messages[0] == messages[1] and messages[0].startswith("cannot resolve 'nosuch.invalid'")
