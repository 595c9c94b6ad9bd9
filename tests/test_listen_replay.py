"""listen + replay on loopback with real sockets: faults, exact takes, garbage, audio, CLI contract."""

from __future__ import annotations

import json
import signal
import socket
import time
from pathlib import Path

import numpy as np
from live_helpers import Listener, run_cli, synthetic_take

from capture import FrameStatus, read_livelink_csv, read_take, write_livelink_csv, write_take
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


def test_no_face_packets_become_face_lost_frames(tmp_path):
    """What the app sends while it sees no face comes back as FACE_LOST frames with their own phone time
    and arrival, as its CSV's face-lost rows do; malformed no-face packets are still rejected."""
    take = synthetic_take(600, seed=8)
    lost = np.zeros(600, bool)
    lost[:30] = lost[200:260] = lost[570:] = True  # no face before, for a second during, and after
    take.frame_status[lost] = FrameStatus.FACE_LOST
    take.values[lost] = np.nan
    listener = Listener(tmp_path / "out")
    imp = Impairment(reorder=0.05, duplicate=0.02, seed=5)  # every packet arrives, some twice or late
    report = replay_take(take, "127.0.0.1", listener.port, speed=3.0, impairment=imp)
    header = header_bytes(take.meta.device, "iPhone")
    good = no_face_packet(take.meta.device, "iPhone", 36000 * 60 + 700, 0.3, 60, 1)
    extra = [
        no_face_packet(take.meta.device, "iPhone", 36000 * 60 + 700, 0.3, 0, 1),  # bad_rate
        good[:-1],  # short
        good + b"\0",  # count
        header + frame_block(36000 * 60 + 701, 1.5, 60, 1, take.values[0]),  # bad_frame_time
        no_face_packet("OTHER-PHONE", "iPhone", 5, 0.0, 60, 1),  # a stream without a face: no take
    ]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for data in extra:
            s.sendto(data, ("127.0.0.1", listener.port))
    time.sleep(0.3)
    lines, err, code = listener.stop()
    assert code == 0, err
    assert report.no_face >= 120 and report.lost == 0
    assert len(lines) == 1
    line = lines[0]
    assert line["rejected"] == {"bad_rate": 1, "short": 1, "count": 1, "bad_frame_time": 1}
    assert line["datagrams"] == report.packets_sent + len(extra)
    assert line["accepted"] == report.packets_sent + 1
    assert line["stray_streams"] == 1
    # The take runs from the first to the last frame with a face; the second without one is inside it.
    got = read_take(line["path"])
    assert got.meta.extra["first_frame_number"] == 36000 * 60 + 30
    assert got.time.size == line["frames"] == 540
    expected = take.frame_status[30:570]
    assert np.array_equal(got.frame_status, expected)
    assert line["face_lost_frames"] == 60 and line["dropped_frames"] == 0
    assert line["face_lost_outside_takes"] == 60
    assert got.count(FrameStatus.FACE_LOST) == 60 and got.meta.repairs == []
    assert np.allclose(got.time, take.time[30:570] - take.time[30], atol=1e-6)
    assert np.all(np.isfinite(got.arrival_s))
    assert np.all(np.isnan(got.values[expected == FrameStatus.FACE_LOST]))
    assert np.array_equal(got.values[expected == FrameStatus.TRACKED], take.values[30:570][~lost[30:570]])
    # Written as the app's CSV, the face-lost frames are `<timecode>,0` rows, read back as FACE_LOST.
    csv = write_livelink_csv(got, tmp_path / "live.csv")
    rows = csv.read_text().splitlines()[1:]
    assert sum(len(r.split(",")) == 2 for r in rows) == 60
    back = read_livelink_csv(csv)
    assert np.array_equal(back.frame_status, got.frame_status)
    assert np.allclose(back.time, got.time, atol=1e-3)


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
    if kind < 9:  # other versions, no-face packets, trailing bytes, oversized
        return [
            bytes([int(rng.integers(0, 6))]) + base[1:],
            no_face_packet("x", "y", 5, 0.5, 60, 1),
            base + b"\0",
            base + rng.bytes(int(rng.integers(800, 3000))),
        ][int(rng.integers(0, 4))]
    return base


def _socket_drops(port: int) -> int:
    """Datagrams the kernel dropped at the full receive queue of the UDP socket bound to ``port``
    (Linux ``/proc/net/udp``, last column; 0 elsewhere): they never reach the listener to be counted."""
    try:
        table = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return 0
    return sum(int(f[-1]) for f in map(str.split, table) if int(f[1].split(":")[1], 16) == port)


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
    drops = _socket_drops(listener.port)  # on a loaded machine the listener can fall behind the sender
    lines, err, code = listener.stop()
    assert code == 0, err
    assert "Traceback" not in err
    line = lines[0]
    assert line["datagrams"] + drops == n and drops < n // 100
    assert set(line["rejected"]) <= set(REJECT_REASONS)
    assert line["accepted"] + sum(line["rejected"].values()) == line["datagrams"]
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
        (["listen", "-o", str(tmp_path), "--port", "0", "--audio-device", "0", "--duration", "1"], "audio"),
    ]:
        r = run_cli(*args)
        assert r.returncode == 1, (args, r.stderr)
        assert text in r.stderr and "Traceback" not in r.stderr and len(r.stderr.splitlines()) == 1
    # a start that fails leaves no output folder behind (one that existed stays)
    new = tmp_path / "never-made"
    r = run_cli("listen", "-o", str(new), "--port", "0", "--audio-device", "0", "--duration", "1")
    assert r.returncode == 1 and not new.exists(), r.stderr
