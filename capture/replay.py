"""The simulated iPhone: sends a take's frames as Live Link packets in real time (or faster).

Network faults come from a seeded generator so a test can ask for the same session twice: packet
loss, reordering (a packet held back by 1.5 frame periods), duplication (a second copy shortly after)
and jitter (each packet delayed by a uniform 0..jitter seconds, real time, not scaled by speed).
The first frame is always sent on time and intact, so a listener that starts its audio file at the
first packet (``listen --audio-file F --audio-start first-packet``) lines audio up with it.

Frames: TRACKED frames are sent with their values, FACE_LOST frames as no-face packets (ending after
the frame time, as the app sends them), DROPPED frames not at all. BAD_VALUE frames (and any frame with
a NaN or infinite value) are sent as no-face packets too, never as NaN weights, and counted. Frame
numbers come from the take's start timecode plus frame time at the take's rate.
"""

from __future__ import annotations

import re
import socket
import time
import uuid
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from . import livelink as ll
from .audio_io import Audio, write_audio
from .channels import ARKIT61, canonical, is_known
from .csv_take import start_seconds_of_day
from .errors import InputError
from .take import FrameStatus, Take, make_out_dir


@dataclass
class Impairment:
    """Seeded network faults. Probabilities per packet; ``jitter_s`` in seconds."""

    loss: float = 0.0
    reorder: float = 0.0
    duplicate: float = 0.0
    jitter_s: float = 0.0
    seed: int = 0

    def check(self) -> None:
        for name in ("loss", "reorder", "duplicate"):
            p = getattr(self, name)
            if not 0.0 <= p < 1.0:
                raise InputError(f"--{name} must be a probability in [0, 1), not {p}")
        if not 0.0 <= self.jitter_s <= 10.0:
            raise InputError(f"jitter must be in 0..10 s, not {self.jitter_s}")
        if not 0 <= self.seed < 2**63:
            raise InputError(f"--seed must be a non-negative integer below 2**63, not {self.seed}")


@dataclass
class ReplayReport:
    """What reached the wire. ``delivered`` holds the distinct frame numbers sent (with values)."""

    frames: int = 0  # distinct frames (with values) that reached the wire
    packets_sent: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0  # packets sent after a packet with a higher frame number
    no_face: int = 0  # no-face packets sent: for FACE_LOST frames and for frames with bad values
    face_lost: int = 0  # of them, those for FACE_LOST frames
    bad_values: int = 0  # frames with NaN/inf values (BAD_VALUE), sent as no-face packets
    skipped: int = 0  # frames that fell on an already used frame number
    duration_s: float = 0.0
    device: str = ""
    subject: str = ""
    rate: tuple[int, int] = (60, 1)
    delivered: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def to_json(self) -> dict:
        return {
            "frames": self.frames,
            "packets_sent": self.packets_sent,
            "lost": self.lost,
            "duplicated": self.duplicated,
            "reordered": self.reordered,
            "no_face": self.no_face,
            "face_lost": self.face_lost,
            "bad_values": self.bad_values,
            "skipped": self.skipped,
            "duration_s": round(self.duration_s, 3),
            "device": self.device,
            "subject": self.subject,
            "rate": list(self.rate),
        }


def format_destination(host: str, port: int) -> str:
    """``HOST:PORT``, IPv6 addresses in brackets (``[::1]:11111``): what ``parse_destination`` reads."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def parse_destination(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6]:PORT`` for IPv6) → (host, port); ``InputError`` when malformed."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(f"destination must be HOST:PORT, not {text!r}")
    return host, int(port)


def udp_target(host: str, port: int) -> tuple[tuple, socket.AddressFamily]:
    """The socket address to send ``host:port`` datagrams to and its family (an IPv6 address when
    ``host`` holds a colon); ``InputError`` when the name does not resolve."""
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        infos = socket.getaddrinfo(host, port, family, socket.SOCK_DGRAM)
    except (OSError, UnicodeError) as exc:  # socket.gaierror; a name that is no text (non-UTF-8 argv)
        raise InputError(f"cannot resolve {host!r}: {exc}") from None
    return infos[0][4], infos[0][0]


def frame_times(seconds_of_day: np.ndarray, num: int, den: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame numbers (int64) and sub-frames (float32, in [0, 1)) of times in seconds of the day at the
    rate ``num``/``den``: a sub-frame within float32's rounding under 1 (a time a hair before a frame's
    boundary, as float64 sums of the day's seconds and a frame's time land) is 1.0 as float32 and is
    carried into the next frame number, so that consecutive frames never share a number."""
    x = np.asarray(seconds_of_day, np.float64) * num / den
    number = np.floor(x).astype(np.int64)
    sub = (x - number).astype(np.float32)
    carry = sub >= 1.0
    number[carry] += 1
    sub[carry] = 0.0
    return number, sub


def rate_of(fps: float) -> tuple[int, int]:
    if abs(fps - round(fps)) < 1e-6:
        return int(round(fps)), 1
    f = Fraction(fps).limit_denominator(1001)
    return f.numerator, f.denominator


def values_in_engine_order(take: Take) -> np.ndarray:
    """frames x 61 float32 in Live Link order; channels the take lacks are 0."""
    out = np.zeros((take.time.size, ll.BLENDSHAPE_COUNT), dtype=np.float32)
    index = {canonical(c): j for j, c in enumerate(take.meta.channels) if is_known(c)}
    for i, name in enumerate(ARKIT61):
        j = index.get(name)
        if j is not None:
            out[:, i] = take.values[:, j]
    return out


# An Apple model identifier (``iPhone13,3``, ``iPad8,1``): what take.json's ``deviceModel`` holds, which
# the take folder reader keeps as ``meta.device``. It names a model, not a phone: the app streams a UUID.
_MODEL_ID = re.compile(r"^[A-Za-z]+\d+,\d+$")


def default_device(take: Take) -> str:
    """The device id the take was streamed with (a take recorded from the live stream), else a stable
    upper-case UUID derived from the take's id, 36 characters like the app's. A device model (take.json's
    ``deviceModel``) is no device id: two phones of one model would share it, and listeners key their
    streams on it."""
    device = take.meta.device
    if device and not _MODEL_ID.match(device):
        return device
    return str(uuid.uuid5(uuid.NAMESPACE_URL, "s2a-take:" + take.meta.id)).upper()


def check_speed(speed: float) -> None:
    if not 0.01 <= speed <= 1000:  # also rejects NaN
        raise InputError(f"--speed must be in 0.01..1000, not {speed}")


def packet_names(take: Take, device: str | None = None, subject: str | None = None) -> tuple[str, str]:
    """The device id and subject to send (defaults from the take); ``InputError`` when a packet with
    them would be over the datagram limit listeners enforce (``livelink.MAX_PACKET_BYTES``)."""
    device = device or default_device(take)
    subject = subject or take.meta.subject or "iPhone"
    try:
        size = len(ll.header_bytes(device, subject)) + ll.FRAME_BLOCK_BYTES
    except UnicodeEncodeError:
        raise InputError("device id and subject must be valid UTF-8 text") from None
    if size > ll.MAX_PACKET_BYTES:
        room = ll.MAX_PACKET_BYTES - ll.FRAME_BLOCK_BYTES - 9  # version byte, two string lengths
        raise InputError(
            f"device id and subject are too long: packets would be {size} bytes, over the "
            f"{ll.MAX_PACKET_BYTES}-byte datagram limit (at most {room} UTF-8 bytes together)"
        )
    return device, subject


def write_audio_out(path: str | Path, audio: Audio) -> None:
    """Write ``--audio-out``, creating its folder; ``InputError`` when that cannot be done."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder: --audio-out needs a file name", path)
    make_out_dir(path.parent)
    try:
        write_audio(path, audio)
    except OSError as exc:
        raise InputError(f"cannot write --audio-out ({exc.strerror or exc})", path) from None


def rebased_audio(take: Take) -> Audio | None:
    """The take's audio shifted so that its first sample is take time 0 (pad or trim at the start)."""
    if take.audio is None:
        return None
    a = take.audio
    start = take.meta.audio.start_s if take.meta.audio else 0.0
    shift = int(round(start * a.sample_rate))
    if shift > 0:
        samples = np.concatenate([np.zeros((shift, a.channels), dtype=a.samples.dtype), a.samples])
    else:
        samples = a.samples[-shift:]
    if samples.shape[0] == 0:
        return None
    return Audio(samples, a.sample_rate, a.subtype)


def replay_take(
    take: Take,
    host: str,
    port: int,
    speed: float = 1.0,
    impairment: Impairment | None = None,
    device: str | None = None,
    subject: str | None = None,
    audio_out: str | Path | None = None,
) -> ReplayReport:
    """Send ``take`` to ``host:port`` as Live Link packets; blocks for the take's duration / speed."""
    imp = impairment or Impairment()
    imp.check()
    check_speed(speed)
    if audio_out is not None and speed != 1.0:
        raise InputError("--audio-out re-enacts a session in real time: use it with --speed 1")
    device, subject = packet_names(take, device, subject)
    num, den = rate_of(take.meta.fps)
    t0 = start_seconds_of_day(take)
    status = take.frame_status
    send = status != FrameStatus.DROPPED
    idx = np.flatnonzero(send)
    fn, sf = frame_times(t0 + take.time[idx], num, den)
    unique = np.concatenate([[True], np.diff(fn) > 0]) if fn.size else np.zeros(0, bool)
    report = ReplayReport(device=device, subject=subject, rate=(num, den), skipped=int((~unique).sum()))
    idx, fn, sf = idx[unique], fn[unique], sf[unique]
    if idx.size == 0:
        raise InputError(f"take {take.meta.id} has no frames to send")
    values = values_in_engine_order(take)
    header = ll.header_bytes(device, subject)
    rng = np.random.default_rng(imp.seed)
    n = idx.size
    lost = rng.random(n) < imp.loss
    dup = rng.random(n) < imp.duplicate
    held = rng.random(n) < imp.reorder
    jitter = rng.uniform(0.0, imp.jitter_s, n) if imp.jitter_s > 0 else np.zeros(n)
    jitter_dup = rng.uniform(0.0, imp.jitter_s, n) if imp.jitter_s > 0 else np.zeros(n)
    lost[0] = dup[0] = held[0] = False
    jitter[0] = 0.0
    period = den / num / speed
    nominal = (take.time[idx] - take.time[idx[0]]) / speed
    due = nominal + jitter + np.where(held, 1.5 * period, 0.0)
    schedule: list[tuple[float, int, int]] = []  # (due s, order, position in idx)
    for k in range(n):
        if lost[k]:
            continue
        schedule.append((due[k], len(schedule), k))
        if dup[k]:
            schedule.append((due[k] + 0.25 * period + jitter_dup[k], len(schedule), k))
    schedule.sort()
    packets = []
    face_lost = status[idx] == FrameStatus.FACE_LOST
    bad = ~face_lost & ((status[idx] == FrameStatus.BAD_VALUE) | ~np.isfinite(values[idx]).all(axis=1))
    report.bad_values = int(bad.sum())
    no_face = face_lost | bad
    for _, _, k in schedule:
        i = idx[k]
        if no_face[k]:
            packets.append(ll.no_face_packet(device, subject, int(fn[k]), float(sf[k]), num, den))
        else:
            packets.append(header + ll.frame_block(int(fn[k]), float(sf[k]), num, den, values[i]))
    target, family = udp_target(host, port)  # before --audio-out: an unknown name writes nothing
    if audio_out is not None:
        audio = rebased_audio(take)
        if audio is None:
            raise InputError(f"take {take.meta.id} has no audio for --audio-out")
        write_audio_out(audio_out, audio)
    sent_frames: set[int] = set()
    max_fn = -1
    with socket.socket(family, socket.SOCK_DGRAM) as sock:
        start = time.monotonic()
        for (when, _, k), packet in zip(schedule, packets):
            wait = start + when - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            try:
                sock.sendto(packet, target)
            except OSError as exc:
                raise InputError(f"cannot send to {format_destination(host, port)}: {exc}") from None
            report.packets_sent += 1
            f = int(fn[k])
            if f < max_fn:
                report.reordered += 1
            max_fn = max(max_fn, f)
            if no_face[k]:
                report.no_face += 1
                report.face_lost += int(face_lost[k])
            else:
                sent_frames.add(f)
        report.duration_s = time.monotonic() - start
    report.lost = int(lost.sum())
    report.duplicated = report.packets_sent - (n - report.lost)
    report.frames = len(sent_frames)
    report.delivered = np.array(sorted(sent_frames), dtype=np.int64)
    return report
