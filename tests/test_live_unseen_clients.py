"""Live capture against senders its authors had not seen: what a hostile review found, each fixed. Real UDP
sockets on loopback and a real ``listen`` process."""

from __future__ import annotations

import os
import re
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from live_helpers import Listener, start_recorder

from capture import FrameStatus, build_takes, read_take
from capture.audio_capture import AudioLog, DeviceAudioSource, index_audio_log
from capture.livelink import frame_block, header_bytes
from capture.recorder import PORT_HOPS
from capture.session_clock import SessionClock

DEVICE = "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
START = 10 * 3600 * 60  # 10:00:00 at 60 fps
VALUES = np.full(61, 0.25, np.float32)


def _send(port: int, packets: list[bytes]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for p in packets:
            s.sendto(p, ("127.0.0.1", port))


def _receive_queue_bytes() -> int:
    """What the listener's receive queue holds at most: the 8 MiB it asks for, capped by the system's
    rmem_max, doubled by the kernel for its bookkeeping."""
    try:
        rmem_max = int(Path("/proc/sys/net/core/rmem_max").read_text())
    except (OSError, ValueError):
        pytest.skip("the system does not say how large a receive queue may be")
    return 2 * min(8 << 20, rmem_max)


@pytest.mark.skipif(not Path("/proc/self/net/udp").exists(), reason="Linux tells of socket drops in /proc")
def test_datagrams_dropped_while_listen_was_suspended_are_counted_and_said_once(tmp_path):
    # A burst while listen cannot read (suspended, a laptop lid, an overloaded machine): the system drops
    # what its receive queue cannot hold. Those frames never reach the log; before, the take simply ended
    # early (no dropped frames in it) and nothing said why. Two phones: the session's warning comes once.
    phone, other = header_bytes(DEVICE, "iPhone"), header_bytes("0" * 36, "iPad")
    before = 100
    burst = _receive_queue_bytes() // len(phone + frame_block(0, 0.0, 60, 1, VALUES)) + 2000
    listener = Listener(tmp_path / "out")
    blocks = [frame_block(START + i, 0.0, 60, 1, VALUES) for i in range(before)]
    _send(listener.port, [head + block for block in blocks for head in (phone, other)])
    time.sleep(0.3)
    os.kill(listener.proc.pid, signal.SIGSTOP)
    try:
        packets = [phone + frame_block(START + before + i, 0.0, 60, 1, VALUES) for i in range(burst)]
        _send(listener.port, packets)
    finally:
        os.kill(listener.proc.pid, signal.SIGCONT)
    time.sleep(0.5)
    lines, err, code = listener.stop()
    assert code == 0, err
    assert len(lines) == 2
    drops = lines[0]["receive_queue_drops"]
    assert drops >= 2000 and all(line["receive_queue_drops"] == drops for line in lines)
    # Every datagram sent is a frame of a take or one the system dropped: nothing else went missing.
    assert sum(line["frames"] - line["dropped_frames"] for line in lines) + drops == 2 * before + burst
    assert err.count(f"{drops} datagrams reached this computer but were dropped before listen read them") == 1


def test_rejections_of_other_senders_say_what_the_sender_does_wrong(tmp_path):
    # Four senders of other programs, each rejected whole: before, only the reason's name was printed.
    def little_endian(i: int) -> bytes:  # every field little-endian (a C# BinaryWriter)
        d, s = DEVICE.encode(), b"iPhone"
        return (
            bytes([6])
            + struct.pack("<i", len(d))
            + d
            + struct.pack("<i", len(s))
            + s
            + struct.pack("<ifiiB61f", START + i, 0.0, 60, 1, 61, *VALUES)
        )

    latin1 = bytes([6]) + struct.pack(">i", 4) + b"Jos\xe9" + struct.pack(">i", 6) + b"iPhone"
    good = header_bytes(DEVICE, "Padded")
    packets = []
    for i in range(12):
        block = frame_block(START + i, 0.0, 60, 1, VALUES)
        packets += [little_endian(i), latin1 + block, good + block + bytes(512 - len(good + block))]
        packets.append((header_bytes(DEVICE, "Cut") + block)[:256])
    listener = Listener(tmp_path / "out")
    _send(listener.port, packets)
    time.sleep(0.3)
    lines, err, code = listener.stop()
    assert code == 0, err
    assert [line["path"] for line in lines] == [None]
    assert lines[0]["rejected"] == {"bad_length": 12, "bad_text": 12, "size_mismatch": 12, "short": 12}
    assert "little-endian" in err and "another encoding" in err
    assert "pads its packets" in err and "cuts its packets" in err


def test_a_stop_reads_the_datagrams_already_queued(tmp_path):
    # Ctrl-C reaches a listen that is behind (here: suspended, then resumed with the signal pending): the
    # datagrams the system already holds for it were received before the stop. Before, the loop ended at
    # the next datagram and the rest of the queue was lost unsaid.
    head = header_bytes(DEVICE, "iPhone")
    n = min(3000, _receive_queue_bytes() // 2048)  # well within the receive queue (1.25 KiB a datagram)
    listener = Listener(tmp_path / "out")
    os.kill(listener.proc.pid, signal.SIGSTOP)
    try:
        _send(listener.port, [head + frame_block(START + i, 0.0, 60, 1, VALUES) for i in range(n)])
        os.kill(listener.proc.pid, signal.SIGINT)
    finally:
        os.kill(listener.proc.pid, signal.SIGCONT)
    lines, err, code = listener.stop()
    assert code == 0, err
    (line,) = lines
    assert line["frames"] == n and line["dropped_frames"] == 0
    assert "receive_queue_drops" not in line


def test_a_sender_opening_a_socket_per_packet_is_one_stream(tmp_path):
    # A script that sends every packet from a new socket: each comes from another source port. Before,
    # each packet made a stream of its own: the 512 --max-streams slots filled (the rest rejected as
    # too_many_streams) and building the take compared every stream with every other.
    n = 700
    head = header_bytes(DEVICE, "Script")
    rec, port, runner = start_recorder(tmp_path, "hops")
    values = VALUES.copy()
    for i in range(n):
        values[0] = i  # a marker: each frame of the take traces back to its packet
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(head + frame_block(START + i, 0.0, 60, 1, values), ("127.0.0.1", port))
        if i % 200 == 199:
            time.sleep(0.002)
    time.sleep(0.3)
    rec.request_stop()
    runner.join()
    rec.close()
    assert rec.accepted == n and sum(rec.rejected.values()) == 0
    assert len(rec.stream_packets) == PORT_HOPS
    (line,) = build_takes(rec.session_dir, tmp_path / "out")
    assert line["frames"] == n and line["dropped_frames"] == 0 and not line.get("senders")
    take = read_take(line["path"])
    assert np.array_equal(take.values[take.frame_status == FrameStatus.TRACKED, 0], np.arange(n))


def test_a_subject_with_terminal_escapes_is_printed_escaped(tmp_path):
    # A hostile sender's subject: clear the screen, put text on the clipboard (OSC 52), forge a line with a
    # carriage return. The take lines quoted it raw to the terminal of the person recording.
    subject = "\x1b[2J\x1b]52;c;cm0gLXJmIH4=\x07Evil\rforged line"
    cmd = [sys.executable, "-m", "capture", "listen", "-o", str(tmp_path / "out"), "--port", "0"]
    proc = subprocess.Popen([*cmd, "--duration", "60"], stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stderr.readline()
        port = int(re.search(r"udp://[0-9.]+:(\d+) ", first).group(1))
        head = header_bytes(DEVICE, subject)
        _send(port, [head + frame_block(START + i, 0.0, 60, 1, VALUES) for i in range(30)])
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "30 frames" in err
    assert not any(c in err for c in "\x1b\x07\r")
    assert "\\x1b[2J\\x1b]52;c;cm0gLXJmIH4=\\x07Evil\\rforged line" in err


@pytest.mark.parametrize(
    ("current", "adc", "delay"),
    [
        (100.0, 100.1, 0.1),  # WASAPI before PortAudio's fix: the ADC time after the callback's
        (0.0, 0.0, 0.1),  # DirectSound, WDM-KS: no times at all
        (100.0, -3500.0, 0.1),  # CoreAudio input-only: an ADC time off another rate, an hour away
        (100.0, 99.87, 0.13),  # a plausible estimate (the buffer plus 30 ms of latency) is kept
    ],
)
def test_a_sound_cards_implausible_capture_times_do_not_move_the_audio(tmp_path, current, adc, delay):
    # The stamping of a sound-device buffer with the times other host APIs give (no sound card here: the
    # PortAudio stream is stood in for by its sample rate). Before, a negative delay became 0 and a huge
    # one was believed: the take's audio moved by a buffer (0.1 s) or an hour against its frames.
    rate, frames = 48000, 4800
    log = AudioLog(tmp_path / "audio.log")
    log.start(rate, 1, "PCM_16", "device:test")
    source = DeviceAudioSource.__new__(DeviceAudioSource)  # no sound card: set what the callback reads
    source.log, source.clock, source.index, source.overflows = log, SessionClock(), 0, 0
    source.stream = SimpleNamespace(samplerate=rate)
    before = source.clock.now_ns()
    source._callback(
        np.zeros((frames, 1), np.int16),
        frames,
        SimpleNamespace(currentTime=current, inputBufferAdcTime=adc),
        SimpleNamespace(input_overflow=False),
    )
    after = source.clock.now_ns()
    log.close()
    audio, _ = index_audio_log(tmp_path / "audio.log")
    assert audio.read().frames == frames
    assert before - delay * 1e9 - 1e6 <= audio.first_ns <= after - delay * 1e9 + 1e6
