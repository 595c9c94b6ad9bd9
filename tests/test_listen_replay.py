"""listen + replay on loopback with real sockets: faults, exact takes, garbage, audio, CLI contract."""

from __future__ import annotations

import json
import signal
import socket
import time

import numpy as np
from live_helpers import Listener, run_cli, synthetic_take

from capture import FrameStatus, read_take, write_take
from capture.livelink import REJECT_REASONS, frame_block, header_bytes, no_face_packet
from capture.replay import Impairment, replay_take


def test_faulty_replay_yields_exactly_the_delivered_frames(tmp_path):
    take = synthetic_take(900, seed=3)
    listener = Listener(tmp_path / "out")
    imp = Impairment(loss=0.05, reorder=0.05, duplicate=0.01, jitter_s=0.020, seed=7)
    report = replay_take(take, "127.0.0.1", listener.port, speed=3.0, impairment=imp)
    lines, err, code = listener.stop()
    assert code == 0, err
    assert report.lost > 0 and report.duplicated > 0 and report.reordered > 0
    assert len(lines) == 1
    line = lines[0]
    assert line["device"] == take.meta.device and line["subject"] == "iPhone"
    assert line["rejected"] == {} and line["datagrams"] == report.packets_sent
    got = read_take(line["path"])
    delivered = report.delivered
    first = delivered[0]
    assert got.meta.extra["first_frame_number"] == first
    assert got.meta.source_kind == "livelink_udp"
    # One frame per phone frame number from the first to the last delivered, gaps marked DROPPED.
    assert got.time.size == delivered[-1] - first + 1 == line["frames"]
    tracked = np.flatnonzero(got.frame_status == FrameStatus.TRACKED)
    assert np.array_equal(tracked, delivered - first)
    assert line["dropped_frames"] == got.time.size - delivered.size
    assert np.all(got.frame_status[got.frame_status != FrameStatus.TRACKED] == FrameStatus.DROPPED)
    original = delivered - 36000 * 60  # synthetic takes start at frame 10:00:00 @ 60 fps
    assert np.array_equal(got.values[tracked], take.values[original])
    assert np.allclose(got.time[tracked], take.time[original] - take.time[original[0]], atol=1e-6)
    assert np.all(np.isnan(got.arrival_s[got.frame_status == FrameStatus.DROPPED]))
    assert np.all(np.isfinite(got.arrival_s[tracked]))
    assert line["duplicates"] == report.duplicated
    # Live takes work with the foundation's commands like imported ones.
    info = run_cli("info", line["path"], "--json")
    assert info.returncode == 0, info.stderr
    csv = run_cli("export-csv", line["path"], "-o", str(tmp_path / "x.csv"))
    assert csv.returncode == 0, csv.stderr
    assert len((tmp_path / "x.csv").read_text().splitlines()) == 1 + delivered.size


def _garbage(rng: np.random.Generator, valid: list[bytes]) -> bytes:
    kind = rng.integers(0, 10)
    base = valid[int(rng.integers(0, len(valid)))]
    if kind < 4:  # a real packet with a few bytes changed
        b = bytearray(base)
        for _ in range(int(rng.integers(1, 5))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        return bytes(b)
    if kind < 6:  # cut short
        return base[: int(rng.integers(0, len(base)))]
    if kind < 8:  # noise of any size, some oversized
        return rng.bytes(int(rng.integers(0, 3000)))
    if kind < 9:  # other versions, no-face packets, trailing bytes
        return [
            bytes([int(rng.integers(0, 6))]) + base[1:],
            no_face_packet("x", "y", 5, 0.5, 60, 1),
            base + b"\0",
        ][int(rng.integers(0, 3))]
    return base


def test_100k_mutated_and_random_datagrams_are_all_counted(tmp_path):
    rng = np.random.default_rng(11)
    take = synthetic_take(60, seed=1)
    valid = []
    for i in range(60):
        valid.append(
            header_bytes(f"dev{i % 3}", "iPhone") + frame_block(1000 + i, 0.1, 60, 1, take.values[i])
        )
    listener = Listener(tmp_path / "out")
    n = 100_000
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(n):
            s.sendto(_garbage(rng, valid), ("127.0.0.1", listener.port))
            if i % 500 == 499:
                time.sleep(0.004)  # pace: loopback drops what the receive queue cannot hold
    time.sleep(0.5)
    lines, err, code = listener.stop()
    assert code == 0, err
    assert "Traceback" not in err
    line = lines[0]
    assert line["datagrams"] == n
    assert set(line["rejected"]) <= set(REJECT_REASONS)
    assert line["accepted"] + sum(line["rejected"].values()) == n
    assert line["rejected"]["version"] > 0 and line["rejected"]["oversized"] > 0


def test_audio_file_session_reenacted_on_one_machine(tmp_path):
    take = synthetic_take(240, seed=2, audio=True)
    wav = tmp_path / "replay.wav"
    listener = Listener(tmp_path / "out", "--audio-file", str(wav), "--audio-start", "first-packet")
    replay_take(take, "127.0.0.1", listener.port, audio_out=wav)
    time.sleep(0.5)  # let the last audio chunk play out
    lines, err, code = listener.stop()
    assert code == 0, err
    got = read_take(lines[0]["path"])
    assert got.audio is not None and got.meta.audio.start_source == "recorder_clock"
    assert got.audio.sample_rate == 16000 and got.audio.frames > 0
    # The first sample sits near take time 0 (the first packet started playback); loose sanity bound.
    assert abs(got.meta.audio.start_s) < 0.5
    n = min(got.audio.frames, take.audio.frames)
    assert np.array_equal(got.audio.samples[:n], take.audio.samples[:n])


def test_allow_list_and_bad_arguments(tmp_path):
    take = synthetic_take(30, seed=4)
    listener = Listener(tmp_path / "out", "--allow", "127.0.0.2")
    folder = write_take(take, tmp_path / "takes")
    r = run_cli("replay", str(folder), "--to", f"127.0.0.1:{listener.port}", "--speed", "10", "--json")
    assert r.returncode == 0, r.stderr
    sent = json.loads(r.stdout)
    assert {k: sent[k] for k in ("frames", "packets_sent", "lost", "duplicated", "reordered")} == {
        "frames": 30,
        "packets_sent": 30,
        "lost": 0,
        "duplicated": 0,
        "reordered": 0,
    }
    lines, err, code = listener.stop(signal.SIGTERM)
    assert code == 0, err
    assert lines[0]["rejected"] == {"not_allowed": 30} and lines[0]["path"] is None
    for args, text in [
        (["listen", "-o", str(tmp_path), "--allow", "phone"], "IP addresses"),
        (["listen", "-o", str(tmp_path), "--port", "70000"], "0..65535"),
        (["listen", "-o", str(tmp_path), "--audio-file", str(tmp_path / "none.wav")], "not found"),
        (["listen", "-o", str(tmp_path), "--serial", "socket://127.0.0.1:1"], "serial port"),
        (["replay", str(tmp_path), "--to", "nowhere"], "HOST:PORT"),
        (["recover", str(tmp_path / "empty")], "no such folder"),
        # Without PortAudio: the libportaudio2 hint; with it but no sound card: the device error.
        (["listen", "-o", str(tmp_path), "--audio-device", "0", "--duration", "1"], "audio"),
    ]:
        r = run_cli(*args)
        assert r.returncode == 1, (args, r.stderr)
        assert text in r.stderr and "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1
