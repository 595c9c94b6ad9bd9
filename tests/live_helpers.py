"""Shared helpers of the live-capture tests: a synthetic take and a ``listen`` subprocess on loopback."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from capture import ARKIT61, Audio, FrameStatus, LiveRecorder, Take, TakeMeta
from capture.record_log import LogReader, RecordType

START_S = 10 * 3600 + 0.3 / 60  # 10:00:00 plus 0.3 frames at 60 fps


def synthetic_take(n: int = 600, fps: float = 60.0, seed: int = 0, audio: bool = False) -> Take:
    """``n`` tracked frames of random (unclamped) values on a clean grid starting at 10:00:00."""
    rng = np.random.default_rng(seed)
    values = rng.uniform(-0.6, 1.05, (n, len(ARKIT61))).astype(np.float32)
    meta = TakeMeta(
        id=f"synthetic{seed}",
        source_kind="simulated",
        fps=fps,
        channels=list(ARKIT61),
        subject="iPhone",
        device=f"00000000-0000-0000-0000-00000000000{seed % 10}",
        csv={"start_seconds_of_day": START_S},
    )
    take = Take(meta, np.arange(n) / fps, values, np.full(n, FrameStatus.TRACKED, np.uint8))
    if audio:
        sr = 16000
        t = np.arange(int(sr * n / fps)) / sr
        take.attach_audio(Audio((0.3 * np.sin(2 * np.pi * 220 * t)).astype(np.float32), sr), 0.0)
    return take


def _raw_line(fd: int) -> str:
    """One line of a pipe, read byte by byte from its descriptor: ``readline`` on the text stream read
    ahead into its buffer, which ``communicate`` (reading the descriptor itself) never returned, so a
    line said a moment after the address line was lost."""
    line = bytearray()
    while not line.endswith(b"\n"):
        byte = os.read(fd, 1)
        if not byte:
            break
        line += byte
    return line.decode("utf-8", "replace")


class Listener:
    """``s2a-capture listen`` in a subprocess on 127.0.0.1, any free port; always bounded in time."""

    def __init__(self, out: Path, *extra: str, duration: float = 60.0):
        cmd = [sys.executable, "-m", "capture", "listen", "-o", str(out), "--port", "0", "--json"]
        cmd += ["--duration", str(duration), *extra]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        m = None
        line = ""
        for _ in range(50):  # the address line comes first, after any warnings Python prints
            line = _raw_line(self.proc.stderr.fileno())
            m = re.search(r"udp://([0-9.]+):(\d+) -> (.*)$", line.strip())
            if m or not line:
                break
        if not m:
            self.proc.kill()
            raise AssertionError(f"listener did not start: {line}{self.proc.communicate()[1]}")
        self.port = int(m.group(2))
        self.session_dir = Path(m.group(3))

    def stop(self, sig: int = signal.SIGINT, timeout: float = 60.0) -> tuple[list[dict], str, int]:
        """Signal the listener and return its JSON lines, stderr and exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=timeout)
        return [json.loads(x) for x in out.splitlines() if x.strip()], err, self.proc.returncode

    def kill(self) -> None:
        self.proc.kill()
        self.proc.communicate(timeout=30)


def ipv6_loopback() -> bool:
    """Whether this machine can bind ::1 (some CI containers have no IPv6)."""
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
            s.bind(("::1", 0))
        return True
    except OSError:
        return False


def record_phone(out: Path, frames, **phone) -> tuple[list[dict], str, int, Path]:
    """``listen --phone`` into ``out`` of a simulated realtime phone (``SimulatedPhone(frames, **phone)``)
    until every frame it sent is logged: the listener's summaries, stderr, exit code and session folder."""
    from capture.simulate.cps_phone import SimulatedPhone

    with SimulatedPhone(frames, **phone) as sim:
        listener = Listener(out, "--phone", "{}:{}".format(*sim.start()))
        try:
            wait_until(sim.finished, "all frames sent")
            wait_for_logged_frames(listener.session_dir, frames.frame_number.size)
        finally:
            summaries, err, code = listener.stop()
    return summaries, err, code, listener.session_dir


def wait_for_logged_frames(session_dir: Path, frames: int, timeout: float = 60.0) -> None:
    """Wait until the frames log of a recording session holds ``frames`` frame records (a listener
    writes them a moment after they arrive: on a loaded machine, longer)."""
    deadline = time.monotonic() + timeout
    logged = 0
    while time.monotonic() < deadline:
        logged = sum(p[0] == RecordType.FRAME for p in LogReader(session_dir / "frames.log"))
        if logged >= frames:
            return
        time.sleep(0.05)
    raise AssertionError(f"{logged} of {frames} frames logged in {timeout} s")


def listen_while_the_audio_file_changes(
    tmp_path: Path, wav: Path, records: int, change
) -> tuple[list[dict], str, int, Path]:
    """``listen --audio-file wav`` on loopback: 60 frames of one phone; once the audio log holds ``records``
    audio records (0.1 s each), ``change()`` (the file rewritten or cut short) and, once the audio log
    notes it, 60 frames more; all 120 logged, the listener stopped: its JSON lines, stderr, exit code and
    audio log."""
    from capture.livelink import frame_block, header_bytes
    from capture.recorder import AUDIO_LOG

    listener = Listener(tmp_path / "out", "--audio-file", str(wav))
    audio_log = listener.session_dir / AUDIO_LOG
    header = header_bytes("PHONE-1", "Ann")
    values = np.linspace(-0.5, 1.0, 61).astype(np.float32)

    def logged(kind: RecordType) -> int:
        return sum(p[0] == kind for p in LogReader(audio_log)) if audio_log.exists() else 0

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(60):
            s.sendto(header + frame_block(1000 + i, 0.0, 60, 1, values), ("127.0.0.1", listener.port))
        wait_until(lambda: logged(RecordType.AUDIO) >= records, f"{records / 10} s of audio logged")
        change()
        wait_until(lambda: logged(RecordType.NOTE) >= 1, "the audio's failure noted")
        for i in range(60, 120):
            s.sendto(header + frame_block(1000 + i, 0.0, 60, 1, values), ("127.0.0.1", listener.port))
    wait_for_logged_frames(listener.session_dir, 120)  # all of them in the take, however busy the machine
    return (*listener.stop(), audio_log)


def wait_until(condition, what: str, timeout: float = 60.0) -> None:
    """Wait until ``condition()`` holds (an assertion naming ``what`` after ``timeout`` s)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"no {what} within {timeout} s"
        time.sleep(0.05)


def run_cli(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "capture", *args], capture_output=True, text=True, timeout=timeout
    )


def start_recorder(tmp_path, session_id: str, **options) -> tuple[LiveRecorder, int, threading.Thread]:
    """A recorder running on loopback (a free port, at most 30 s): (recorder, its port, its thread)."""
    rec = LiveRecorder(tmp_path, port=0, session_id=session_id, **options)
    _, port = rec.open()
    runner = threading.Thread(target=rec.run, kwargs={"duration_s": 30})
    runner.start()
    return rec, port, runner


def record_packets(
    tmp_path, session_id: str, packets: list[bytes | None], rate: float | None = None
) -> LiveRecorder:
    """Run a recorder on loopback, send it ``packets``, stop it and return it. Without ``rate`` they go
    as fast as loopback takes them (paced every 200); with it, at ``rate`` packets per second in real
    time (arrival times matter), None standing for a packet lost on the way: its time passes."""
    rec, port, runner = start_recorder(tmp_path, session_id)
    start = time.perf_counter()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i, p in enumerate(packets):
            if rate is not None:
                time.sleep(max(0.0, start + i / rate - time.perf_counter()))
            elif i % 200 == 199:
                time.sleep(0.002)  # pace: loopback drops what the receive queue cannot hold
            if p is not None:
                s.sendto(p, ("127.0.0.1", port))
    time.sleep(0.5 if rate is None else 0.3)
    rec.request_stop()
    runner.join()
    rec.close()
    return rec


def udp_receiver() -> socket.socket:
    """A UDP socket on loopback (a free port the system picks), reads time out after 0.5 s."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    return sock


def datagrams(sock: socket.socket) -> list[bytes]:
    """Every datagram that arrives until the socket has been quiet for its timeout."""
    out = []
    try:
        while True:
            out.append(sock.recv(4096))
    except TimeoutError:
        return out


def listen_with_sync_box(tmp_path, lines: list[bytes]) -> tuple[list[dict], str, int]:
    """``listen --serial socket://...`` on loopback while a simulated sync box sends ``lines`` 0.3 s apart
    and a phone replays 150 frames: the listener's JSON lines, stderr and exit code."""
    from capture.replay import replay_take

    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    server.settimeout(20)

    def sync_box():
        conn, _ = server.accept()
        with conn:
            for line in lines:
                time.sleep(0.3)
                conn.sendall(line)
            time.sleep(0.5)

    box = threading.Thread(target=sync_box, daemon=True)
    box.start()
    listener = Listener(tmp_path / "out", "--serial", f"socket://127.0.0.1:{server.getsockname()[1]}")
    replay_take(synthetic_take(150, seed=8), "127.0.0.1", listener.port, speed=1.0)
    box.join(timeout=20)
    try:
        return listener.stop()
    finally:
        server.close()
