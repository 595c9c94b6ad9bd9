"""Live Link Face's realtime stream (``s2a-capture listen --phone``, ``capture.cps_control.PhoneStream``):
zero-loss loopback rate of the relay to the recorder, and its CPU per second of a 60 fps stream, against
the classic stream's recorder alone (``bench_udp``'s trials, same run).

The phone is a separate process: the simulated phone's control server (``capture.simulate.cps_phone``)
and a sender of realtime packets of its ARKit subject (52 controls and the head pose), paced as
``bench_udp``'s sender. In this process the relay (its control session and relay threads) sends each
packet on as a classic packet to a ``LiveRecorder`` on loopback, as ``listen --phone`` runs them. A rate
counts only if every packet was logged to disk (fsync on). CPU is this process's (every thread's) over
the recording, divided by the stream's seconds.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time

from benchmarks.bench_udp import ROOT, recorder_trial, zero_loss_rate
from benchmarks.figure import Figure
from capture.cps_control import PhoneStream
from capture.recorder import LiveRecorder

# The phone: prints its control port; then, given "UDP_PORT N RATE" on stdin once the relay streams,
# sends N realtime packets (frame numbers counting up) to UDP_PORT paced at RATE/s (0: as fast as it
# can), prints the rate achieved, and serves the control session until stdin ends.
PHONE = r"""
import socket, struct, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from capture.realtime_packet import encode_realtime_packet
from capture.simulate.cps_phone import SUBJECT_ID, RealtimeFrames, SimulatedPhone
none = RealtimeFrames(np.zeros(0, int), np.zeros(0, np.float32), (60, 1), np.zeros((0, 52)), np.zeros((0, 6)))
phone = SimulatedPhone(none)  # the control session only: the packets are sent below
print(phone.start()[1], flush=True)
port, n, rate = sys.stdin.readline().split()
port, n, rate = int(port), int(n), float(rate)
controls = np.linspace(0.0, 1.0, 52)
packet = bytearray(encode_realtime_packet(SUBJECT_ID, 0, 0.5, 60, 1, controls, (0.1, -0.2, 0.3, 0, 0, 0)))
at = 4 + len(SUBJECT_ID.encode())
set_frame = struct.Struct("<i").pack_into
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
dest = ("127.0.0.1", port)
burst = 32 if rate == 0 or rate > 2000 else 1
t0 = time.perf_counter()
i = 0
while i < n:
    for _ in range(min(burst, n - i)):
        set_frame(packet, at, 1000 + i)
        s.sendto(packet, dest)
        i += 1
    if rate:
        wait = t0 + i / rate - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
print(n / (time.perf_counter() - t0), flush=True)
sys.stdin.read()
phone.stop()
"""


def relay_trial(n: int, phones: int, rate: float) -> tuple[int, float, float]:
    """Packets the recorder logged to disk (fsync on) of ``n`` realtime packets relayed by ``PhoneStream``,
    the phone's rate, and process CPU seconds over the recording (``bench_udp.recorder_trial``'s shape;
    one phone: a relay streams one)."""
    assert phones == 1, "a PhoneStream relays one phone"
    phone = subprocess.Popen(
        [sys.executable, "-c", PHONE, str(ROOT)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        control_port = phone.stdout.readline()
        if not control_port.strip():
            raise RuntimeError("the simulated phone exited before serving its control session")
        with tempfile.TemporaryDirectory() as d:
            rec = LiveRecorder(d, bind="127.0.0.1", port=0, allow=["127.0.0.1"])
            to = rec.open()
            streaming = threading.Event()

            def note(event: dict) -> None:
                rec.note(event)
                if event.get("kind") == "phone_streaming":
                    streaming.set()

            stream = PhoneStream(
                "127.0.0.1",
                int(control_port),
                to,
                say=lambda _l: None,
                rejected=rec.rejected,
                note=note,
                bind="127.0.0.1",
            )
            try:
                _, udp_port = stream.open()
                stream.start()
                if not streaming.wait(30):  # the session's start is not the stream's cost: before the clock
                    raise RuntimeError("the simulated phone's control session did not start within 30 s")
                achieved = [0.0]

                def send_then_stop() -> None:
                    phone.stdin.write(f"{udp_port} {n} {rate}\n")
                    phone.stdin.flush()
                    achieved[0] = float(phone.stdout.readline() or 0)
                    time.sleep(0.3)
                    rec.request_stop()

                watcher = threading.Thread(target=send_then_stop)
                watcher.start()
                cpu = time.process_time()
                rec.run(600)
                cpu = time.process_time() - cpu
                watcher.join()
                return rec.accepted, achieved[0], cpu
            finally:
                stream.stop()
                rec.close()
    finally:
        phone.stdin.close()  # the phone stops its control server and exits
        phone.wait()


def run(quick: bool = False) -> list[Figure]:
    seconds = 0.5 if quick else 1.5
    relayed = zero_loss_rate(relay_trial, seconds, 1)
    classic = zero_loss_rate(recorder_trial, seconds, 1)
    stream_s = 3.0 if quick else 20.0
    n = int(60 * stream_s)
    cpu_relay = relay_trial(n, 1, 60.0)[2]
    cpu_classic = recorder_trial(n, 1, 60.0)[2]
    note = f"one phone; load average {os.getloadavg()[0]:.1f} at {time.strftime('%H:%M')}"
    return [
        Figure(
            "listen --phone: realtime packets/s relayed and recorded to disk with zero loss",
            relayed,
            "packets/s",
            "classic packets/s recorded, same run",
            classic,
            True,
            None,
            f"= {relayed / 60:.0f}x a 60 fps stream; {note}",
        ),
        Figure(
            "listen --phone: CPU per second of a 60 fps stream (relay + recorder)",
            1e3 * cpu_relay / stream_s,
            "ms/s",
            "classic stream's recorder alone",
            1e3 * cpu_classic / stream_s,
            False,
            None,
            f"{stream_s:g} s of packets; {note}",
        ),
    ]
