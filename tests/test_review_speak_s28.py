"""Review of ``s2a-view speak``: what the stream does where its first tests did not look."""

from __future__ import annotations

import json

import numpy as np
import soundfile as sf
from conftest import run_here
from live_helpers import wait_until
from test_speak_s28 import SPEECH, Receiver, offline, run, speak_cli  # noqa: F401 (run: a fixture)

from capture import livelink as ll


def test_a_pause_longer_than_the_context_keeps_the_face_still(run, samples, tmp_path):  # noqa: F811
    """3 s of real speech, 8 s of a room's noise (-55 dBFS), the speech again: in the pause the context
    holds no speech, and the features keep the speech's level (predict's, measured over the file); were
    the noise raised to the level of speech (its own level measured over the context), the face would
    move in the pause (measured: RMSE 0.039 against predict there, 0.006 with the speech's level)."""
    x, rate = sf.read(samples / SPEECH, dtype="float32", frames=3 * 16000, start=20 * 16000)
    noise = np.random.default_rng(1).normal(0, 10 ** (-55 / 20), 8 * rate).astype(np.float32)
    wav = tmp_path / "pause.wav"
    sf.write(wav, np.concatenate([x, noise, x]), rate)
    rx = Receiver()
    proc = speak_cli(run, "--to", rx.to, "--audio", wav, "--speed", 4)
    out, err = proc.communicate(timeout=300)
    frames = rx.frames()
    assert proc.returncode == 0, err
    want = offline(run, wav, tmp_path)
    got = np.stack([f.values for f in frames])
    assert got.shape == want.shape == (840, 61) and json.loads(out)["frames"] == 840
    pause = slice(5 * 60, 11 * 60)  # the frames whose contexts hold the noise alone
    rmse = float(np.sqrt(np.mean((got[pause] - want[pause]) ** 2)))
    assert rmse < 0.015, rmse


def test_a_long_stream_keeps_no_memory_per_frame():
    """The pacer's account of a stream (frames sent, late, the latency achieved) stays the same size
    however long the stream: a microphone left on for a day sends 5 million frames (a list of each
    frame's latency held 7 MB an hour at 60 fps)."""
    import socket
    import time
    import tracemalloc

    from viewer.speak import LiveLinkOut, Pacer

    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))  # never read: the kernel drops what overflows its buffer
    out = LiveLinkOut(f"127.0.0.1:{sink.getsockname()[1]}", ["jawOpen"], 60.0, "long", None, None)
    out.begin()
    values = np.zeros(61, np.float32)
    pacer = Pacer(out, time.monotonic(), 1.0, 1 / 60)
    pacer.start()

    def send(frames: range) -> None:
        for k in frames:
            pacer.frames.put((k, values, 0.0))  # all due already: sent at once
        wait_until(lambda: pacer.sent == frames.stop or pacer.error is not None, "the frames sent")

    try:
        tracemalloc.start()
        send(range(0, 1000))
        before = tracemalloc.get_traced_memory()[0]
        send(range(1000, 60_000))
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
        pacer.frames.put(None)
        pacer.join()
        out.close()
        sink.close()
    assert pacer.error is None and pacer.sent == 60_000
    assert grown < 300_000, grown  # a float a frame: 1.9 MB


def test_the_receiver_keeps_the_packets_it_had_not_read_yet():
    """The tests' receiver counts every datagram sent to it, also when asked right after the sender is
    done (measured before: 1,102-1,904 of 2,000), so that a summary's count compares exactly."""
    import socket

    rx = Receiver()
    host, port = rx.to.split(":")
    packet = ll.header_bytes("device", "subject") + ll.frame_block(1, 0.0, 60, 1, np.zeros(61, np.float32))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for _ in range(2000):
            tx.sendto(packet, (host, int(port)))
    assert len(rx.frames()) == 2000


def test_audio_shorter_than_half_a_frame_is_one_line(run, tmp_path):  # noqa: F811
    """100 samples (a third of a 60 fps frame): no frame to send, one line as predict says it, exit 1
    (was: a stream of 0 frames, exit 0)."""
    wav = tmp_path / "click.wav"
    sf.write(wav, np.random.default_rng(0).normal(0, 0.1, 100).astype(np.float32), 16000)
    proc = run_here("viewer", "speak", run, "--to", "127.0.0.1:11111", "--audio", wav, "--json")
    assert proc.returncode == 1 and not proc.stdout, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "s2a-view: error: audio is shorter than half an animation frame"
    ], proc.stderr
