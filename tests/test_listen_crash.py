"""A listener killed with SIGKILL at random moments: recover always gets every flushed frame back."""

from __future__ import annotations

import json
import socket
import struct
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from conftest import run_here
from live_helpers import Listener, run_cli, synthetic_take

from capture import FrameStatus, read_take
from capture.livelink import frame_block, header_bytes
from capture.record_log import MAGIC, LogReader, RecordType

RUNS = 10
RATE = 1000.0  # packets per second sent to the listener


def _logged_frame_numbers(session_dir) -> set[int]:
    """Frame numbers of the valid frame records on disk, read independently of session_takes."""
    out = set()
    for payload in LogReader(session_dir / "frames.log"):
        if payload[0] == RecordType.FRAME:
            out.add(struct.unpack_from(">i", payload, 11)[0])
    return out


def test_sigkill_at_random_moments_loses_no_flushed_frame(tmp_path):
    rng = np.random.default_rng(5)
    take = synthetic_take(200, seed=5)
    header = header_bytes("KILLTEST-DEVICE", "iPhone")
    # each run's listener starts (an interpreter's start-up) while the run before it is recovered
    starting = ThreadPoolExecutor(1)
    following = starting.submit(Listener, tmp_path / "run0", "--flush-interval", "0.1")
    try:
        for run in range(RUNS):
            out = tmp_path / f"run{run}"
            listener = following.result()
            kill_after = float(rng.uniform(0.2, 1.5))
            sent_at: list[float] = []
            start = time.monotonic()
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                i = 0
                while time.monotonic() - start < kill_after:
                    s.sendto(
                        header + frame_block(5000 + i, 0.0, 60, 1, take.values[i % 200]),
                        ("127.0.0.1", listener.port),
                    )
                    sent_at.append(time.monotonic())
                    i += 1
                    time.sleep(max(0.0, start + i / RATE - time.monotonic()))
                killed_at = time.monotonic()
                listener.kill()
            if run + 1 < RUNS:
                following = starting.submit(Listener, tmp_path / f"run{run + 1}", "--flush-interval", "0.1")
            on_disk = _logged_frame_numbers(listener.session_dir)
            # the first recover is the command line as a user runs it; the others in this process (what
            # recover does is this test's subject, and each subprocess would add an interpreter's start-up)
            r = (
                run_cli("recover", str(out), "--json")
                if run == 0
                else run_here("capture", "recover", out, "--json")
            )
            assert r.returncode == 0, r.stderr
            lines = [json.loads(x) for x in r.stdout.splitlines()]
            assert len(lines) == 1 and lines[0]["recovered"] is True and lines[0]["clean_end"] is False
            got = read_take(lines[0]["path"])
            first = got.meta.extra["first_frame_number"]
            recovered = set((first + np.flatnonzero(got.frame_status == FrameStatus.TRACKED)).tolist())
            assert recovered == on_disk, f"run {run}"
            # Flushed every 0.1 s: everything sent a second before the kill is on disk (generous bound).
            early = {5000 + k for k, t in enumerate(sent_at) if t < killed_at - 1.0}
            assert early <= recovered, f"run {run}: {len(early - recovered)} early frames missing"
            assert recovered <= {5000 + k for k in range(len(sent_at))}
            lost = len(sent_at) - len(recovered)
            sent = len(sent_at)
            print(f"run {run}: kill at {kill_after:.2f} s, sent {sent}, on disk {len(on_disk)}, lost {lost}")
            if run > 0:
                continue
            # A second recover has nothing left to do; --all rebuilds the same take.
            nothing = run_cli("recover", str(out))
            assert nothing.returncode == 0 and "nothing to recover" in nothing.stderr
            again = run_cli("recover", str(out), "--all", "--json")
            assert (
                again.returncode == 0
                and json.loads(again.stdout.splitlines()[0])["frames"] == lines[0]["frames"]
            )
    finally:  # a listener started for a run that a failure stopped: not left to run out its duration
        last = following.result()
        if last.proc.poll() is None:
            last.kill()


def _killed_session(tmp_path, seed: int):
    """A listener that recorded 120 replayed frames and was then killed: its frames.log."""
    from capture.replay import replay_take

    listener = Listener(tmp_path / "out")
    replay_take(synthetic_take(120, seed=seed), "127.0.0.1", listener.port, speed=20)
    time.sleep(0.3)
    listener.kill()
    return listener.session_dir / "frames.log"


def test_recover_reports_a_torn_tail(tmp_path):
    log = _killed_session(tmp_path, seed=6)
    with open(log, "ab") as f:
        f.write(struct.pack("<II", 272, 12345) + b"\x03" + bytes(100))  # a record cut short by a crash
    r = run_cli("recover", str(tmp_path / "out"), "--json")
    assert r.returncode == 0, r.stderr
    line = json.loads(r.stdout.splitlines()[0])
    assert line["torn_tail"]["reason"] == "incomplete_record"
    assert line["torn_tail"]["bytes_discarded"] == 109
    assert line["frames"] == 120


def test_recover_skips_a_damaged_record_mid_log(tmp_path):
    """A flipped bit in one frame record mid-session costs that frame, not the rest of the take."""
    log = _killed_session(tmp_path, seed=8)
    data = bytearray(log.read_bytes())
    at, frames, damaged = len(MAGIC), 0, None
    while at < len(data):
        (length,) = struct.unpack_from("<I", data, at)
        if data[at + 8] == RecordType.FRAME:
            frames += 1
            if frames == 60:
                damaged = at
                data[at + 8 + 100] ^= 0x10
        at += 8 + length
    log.write_bytes(bytes(data))
    r = run_cli("recover", str(tmp_path / "out"), "--json")
    assert r.returncode == 0, r.stderr
    line = json.loads(r.stdout.splitlines()[0])
    assert line["log_damage"] == [{"offset": damaged, "bytes_discarded": 8 + 272, "reason": "checksum"}]
    damage = "1 damaged stretch(es) of the frame log skipped (280 bytes)"
    assert f"s2a-capture: warning: {line['path']}: {damage}" in r.stderr.splitlines(), r.stderr
    assert "torn_tail" not in line
    assert line["frames"] == 120 and line["valid_frames"] == 119 and line["dropped_frames"] == 1
    back = read_take(line["path"])
    assert back.meta.extra["log_damage"] == line["log_damage"]
