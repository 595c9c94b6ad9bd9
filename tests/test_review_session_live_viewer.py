"""Hostile review of the live capture and viewer changes of b2f0f77 and 18e9443: inputs their authors
did not try (a take ending on two frames of one time, a head with a Blender duplicate of a target, a
buffer file whose name holds an encoded colon)."""

from __future__ import annotations

import base64
import os
import threading
import time
from urllib.parse import unquote

import numpy as np
import pytest
import soundfile as sf
from live_helpers import record_packets
from test_live_leftovers import _packet
from test_review_live_stops_and_rates import _listen_in_a_thread
from test_viewer_gltf_robustness import _doc, _write

from capture import ARKIT61, build_takes, read_take
from capture.errors import InputError
from viewer.gltf import load_gltf
from viewer.render import Animation


@pytest.mark.parametrize(
    "times", [[0.0], [0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.5, 0.5, 1.0], [0.0, 0.5, 1.0]]
)
def test_weights_at_any_time_are_those_np_interp_gives_even_for_repeated_frame_times(times):
    """A take whose last two frames share a time was held at its second-last frame after its end
    (``np.interp`` holds the last), so the face's last pose differed from the take's."""
    time = np.array(times)
    weights = np.random.default_rng(len(times)).random((len(time), 61))
    anim = Animation("x", 60.0, time, weights)
    t = np.array([-1.0, *times, 0.25, 0.5, 0.75, 2.0, 2.0])
    want = np.stack([np.interp(t, time, weights[:, k]) for k in range(61)], axis=1)
    np.testing.assert_allclose(anim.at(t), want, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "names, unread",
    [
        (["jawOpen", "jawOpen.001"], ["jawOpen.001"]),
        (["jawOpen.001", "jawOpen"], ["jawOpen.001"]),
        (["jawOpen.002", "jawOpen.001"], ["jawOpen.002"]),
    ],
)
def test_a_blender_duplicate_of_a_target_leaves_the_head_loadable(tmp_path, names, unread):
    """Blender names a copied shape key ``jawOpen.001``; since such numbers were dropped, a head holding
    the key and its copy was refused ("both name jawOpen") where it loaded before: the copy is left
    unread and named, the key itself (or the first copy) drives the channel."""
    targets = [{"POSITION": 2}, {"POSITION": 2}]
    doc = _doc(**{"meshes.0.primitives.0.targets": targets, "meshes.0.extras.targetNames": names})
    model = load_gltf(_write(tmp_path / "head.gltf", doc))
    assert model.extra["mapped"] == ["jawOpen"]
    assert model.extra["unmapped"] == unread
    assert list(model.parts[0].deltas) == [ARKIT61.index("jawOpen")]


@pytest.mark.parametrize("name", ["head%3A1.bin", "./head.bin", "sub/head.bin", "..%2Fhead.bin"])
def test_a_relative_buffer_uri_is_read(tmp_path, name):
    """``head%3A1.bin`` is the file ``head:1.bin`` beside the .gltf (a colon percent-encoded is no
    scheme); it was refused as "not a file beside the .gltf"."""
    folder = tmp_path / "a" / "b"
    (folder / "sub").mkdir(parents=True)
    doc = _doc()
    (folder / unquote(name)).write_bytes(base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1]))
    doc["buffers"][0]["uri"] = name
    model = load_gltf(_write(folder / "head.gltf", doc))
    assert model.extra["mapped"] == ["jawOpen"]


@pytest.mark.parametrize(
    "uri", ["%2Fetc%2Fhostname", "C:head.bin", "file:head.bin", "%5C%5Cserver%5Chead.bin"]
)
def test_a_buffer_uri_outside_the_gltf_folder_tree_is_still_refused(tmp_path, uri):
    path = _write(tmp_path / "head.gltf", _doc(**{"buffers.0.uri": uri}))
    with pytest.raises(InputError, match="buffer 0: .* is not a file beside the .gltf"):
        load_gltf(path)


@pytest.mark.parametrize("old_rate, new_rate, late_by", [(25, 24, 1), (25, 24, 3), (30, 60, 4)])
def test_a_late_packet_of_the_old_setting_goes_to_its_own_take(tmp_path, old_rate, new_rate, late_by):
    """The app's setting changes; the last packet of the old one arrives after ``late_by`` of the new.
    Before: 25 -> 24 late by one lost both mixed packets (a stretch of 2, too short for a take); late by
    three read both settings as one rate jittering at 25 fps (the 24 fps frames 4 % of the day off);
    30 -> 60 late by four was rejected (``rate_changed``) once the change was confirmed."""
    old = [_packet(old_rate * 36000 + i, old_rate, i) for i in range(60)]
    start = 36000 + 60 / old_rate  # the new setting's frames go on from where the old one's end
    new = [_packet(round(new_rate * start) + i, new_rate, 60 + i) for i in range(60)]
    packets = old[:-1] + new[:late_by] + [old[-1]] + new[late_by:]
    lines = build_takes(record_packets(tmp_path, "late", packets).session_dir, tmp_path / "takes")
    assert [(line["frames"], line["rejected"], "rate_jitter_packets" in line) for line in lines] == [
        (60, {}, False),
        (60, {}, False),
    ]
    first, second = (read_take(line["path"]) for line in lines)
    assert (first.meta.fps, second.meta.fps) == (old_rate, new_rate)
    assert first.meta.csv["start_seconds_of_day"] == pytest.approx(36000.0)
    assert second.meta.csv["start_seconds_of_day"] == pytest.approx(round(new_rate * start) / new_rate)
    assert np.array_equal(first.values[:, 0], np.arange(60))
    assert np.array_equal(second.values[:, 0], 60 + np.arange(60))


def test_a_stray_packet_at_another_rate_is_rejected_once_the_stream_passes_it(tmp_path):
    """A corrupt packet declaring 30 fps with a frame time just ahead of a 60 fps stream is held as a
    possible change of setting; the stream's next packets are from before it (late ones, by
    ``LATE_PACKET_S``) and leave it held. Before, only the first of them was checked: it stayed held for
    good, and the app's real change to 30 fps a second later took it as its first packet (logged, its
    rejection uncounted)."""
    stream = [_packet(60 * 36000 + i, 60, i) for i in range(120)]
    stray = _packet(30 * 36000 + 7, 30, 999)  # 36000.233 s: 0.1 s after the 60 fps packet before it
    change = [_packet(30 * 36002 + i, 30, 120 + i) for i in range(60)]
    lines = build_takes(
        record_packets(tmp_path, "stray", stream[:9] + [stray] + stream[9:] + change).session_dir,
        tmp_path / "takes",
    )
    assert [(line["frames"], line["rejected"]) for line in lines] == [
        (120, {"rate_changed": 1}),
        (60, {"rate_changed": 1}),
    ]
    assert np.array_equal(read_take(lines[1]["path"]).values[:, 0], 120 + np.arange(60))


def test_the_set_up_thread_keeps_the_trace_a_coverage_tool_or_debugger_gave_it(tmp_path):
    """``listen``'s set-up step runs under a trace of its calls (so that a stop can end it); that trace
    replaced the one ``threading.settrace`` gives every thread (coverage, a debugger): none of the step's
    code (reading --audio-file) was seen by them."""
    wav = tmp_path / "speech.wav"
    sf.write(wav, np.zeros((4800, 1), np.int16), 48000, subtype="PCM_16")
    seen: set[str] = set()

    def coverage(frame, event, arg):
        if threading.current_thread().name == "listen-set-up":
            seen.add(os.path.basename(frame.f_code.co_filename))

    stop = threading.Event()
    threading.settrace(coverage)
    try:
        thread, ended, _ = _listen_in_a_thread(tmp_path / "out", stop, "--audio-file", str(wav))
        until = time.monotonic() + 10  # until the step has read the file (a loaded machine takes a while)
        while not {"audio_capture.py", "audio_io.py"} <= seen and time.monotonic() < until:
            time.sleep(0.005)
    finally:
        threading.settrace(None)
        stop.set()
    thread.join(10)
    assert not thread.is_alive() and len(ended) == 1
    assert {"audio_capture.py", "audio_io.py"} <= seen, sorted(seen)
