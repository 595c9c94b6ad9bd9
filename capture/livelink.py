"""The Live Link Face UDP packet, version 6 (ARKit mode), and why a datagram is not one.

Layout (formats doc §5.1; all multi-byte fields big-endian):

``u8 version=6 | i32 n + n bytes UTF-8 DeviceId | i32 m + m bytes UTF-8 SubjectName |
i32 FrameNumber | f32 SubFrame | i32 RateNumerator | i32 RateDenominator | u8 Count=61 | 61 x f32``

A packet is ``270 + n + m`` bytes (312 for the app's 36-character device id and subject "iPhone").
Frame time in seconds = (FrameNumber + SubFrame) * RateDenominator / RateNumerator.

While the app sees no face it keeps sending packets that end right after the frame time (no count,
no values; formats doc §5.4). They are frames too: the phone's clock ticked and nobody was tracked, so
they decode to a ``LiveLinkFrame`` with ``face`` False and NaN values, the FACE_LOST frames of a take.

Decoding never raises for bad input: ``decode_packet`` returns a ``LiveLinkFrame`` or a rejection
reason (one of ``REJECT_REASONS``), which the listener counts.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from .channels import LIVELINK_ORDER

PACKET_VERSION = 6
BLENDSHAPE_COUNT = len(LIVELINK_ORDER)  # 61
# Largest datagram accepted: the real packet is 312 bytes; this leaves room for long subject names.
MAX_PACKET_BYTES = 1024
# Bytes after the two strings: frame number, sub-frame, rate num/den, count, 61 values.
FRAME_BLOCK_BYTES = 4 + 4 + 4 + 4 + 1 + 4 * BLENDSHAPE_COUNT  # 261
FRAME_TIME_BYTES = 16  # frame number, sub-frame, rate numerator, rate denominator
# Highest frame rate a stream may declare (the app sends 30 or 60 fps): a faster one is "bad_rate", since
# the take builder allocates a frame per frame period in a gap and a hostile rate would make that unbounded.
MAX_RATE_FPS = 1000

_LEN = struct.Struct(">i")
_FRAME_TIME = struct.Struct(">ifii")
_VALUES = struct.Struct(f">{BLENDSHAPE_COUNT}f")
VALUES_DTYPE = np.dtype(">f4")

# Why a datagram was not recorded. Order is the order of the checks.
REJECT_REASONS: tuple[str, ...] = (
    "not_allowed",  # source address not in the listener's allow-list
    "version",  # first byte is not 6 (or no byte at all: "short")
    "oversized",  # longer than MAX_PACKET_BYTES
    "short",  # ends before the field being read
    "bad_length",  # a string length is negative or runs past the datagram
    "bad_text",  # device id or subject is not UTF-8
    "count",  # BlendShapeCount is not 61
    "size_mismatch",  # count is 61 but the datagram is longer than the packet
    "bad_rate",  # rate numerator not positive, denominator negative, or the rate above MAX_RATE_FPS
    "bad_frame_time",  # negative frame number, or sub-frame not in [0, 1)
    "rate_changed",  # a packet or two of a known device/subject at another rate (one that holds is a restart)
    "too_many_streams",  # more distinct device/subject pairs than the listener keeps
)


@dataclass
class LiveLinkFrame:
    """One decoded packet: who sent it, the phone's frame time, and the 61 values in engine order.

    ``face`` is False for a no-face packet (the app saw no face); its values are then NaN."""

    device: str
    subject: str
    frame_number: int
    sub_frame: float
    rate_numerator: int
    rate_denominator: int
    values: np.ndarray  # float32 (61,), LIVELINK_ORDER
    face: bool = True

    @property
    def rate(self) -> float:
        """Frames per second of the frame number."""
        return self.rate_numerator / rate_denominator(self.rate_denominator)

    @property
    def time_s(self) -> float:
        """The phone's frame time in seconds (since its timecode origin)."""
        return (
            (self.frame_number + self.sub_frame)
            * rate_denominator(self.rate_denominator)
            / self.rate_numerator
        )


def encode_packet(frame: LiveLinkFrame) -> bytes:
    """The version-6 packet of ``frame``, byte for byte as the app sends it (a no-face packet when
    ``frame.face`` is False)."""
    if not frame.face:
        return no_face_packet(
            frame.device,
            frame.subject,
            frame.frame_number,
            frame.sub_frame,
            frame.rate_numerator,
            frame.rate_denominator,
        )
    return header_bytes(frame.device, frame.subject) + frame_block(
        frame.frame_number, frame.sub_frame, frame.rate_numerator, frame.rate_denominator, frame.values
    )


def header_bytes(device: str, subject: str) -> bytes:
    """Version byte and the two length-prefixed strings (constant for a stream)."""
    d = device.encode("utf-8")
    s = subject.encode("utf-8")
    return bytes([PACKET_VERSION]) + _LEN.pack(len(d)) + d + _LEN.pack(len(s)) + s


def frame_block(
    frame_number: int, sub_frame: float, rate_numerator: int, rate_denominator: int, values
) -> bytes:
    """Frame time, count and values: the part of a packet that changes every frame."""
    vals = np.asarray(values, dtype=np.float32)
    if vals.shape != (BLENDSHAPE_COUNT,):
        raise ValueError(f"a Live Link packet carries {BLENDSHAPE_COUNT} values, not {vals.shape}")
    return (
        _FRAME_TIME.pack(frame_number, sub_frame, rate_numerator, rate_denominator)
        + bytes([BLENDSHAPE_COUNT])
        + vals.astype(VALUES_DTYPE).tobytes()
    )


def no_face_packet(
    device: str, subject: str, frame_number: int, sub_frame: float, num: int, den: int
) -> bytes:
    """A packet that ends after the frame time, as the app sends while it sees no face (§5.4)."""
    return header_bytes(device, subject) + _FRAME_TIME.pack(frame_number, sub_frame, num, den)


def parse_header(data: bytes | bytearray | memoryview, size: int | None = None) -> tuple[int, str | None]:
    """Offset of the frame-time block after the version and strings, or (-1, reason).

    ``size`` is the datagram length when ``data`` is a larger receive buffer. Never raises.
    """
    n = len(data) if size is None else size
    if n < 1:
        return -1, "short"
    if data[0] != PACKET_VERSION:  # first: says more than the size (MetaHuman Animator packets are 1-2 KB)
        return -1, "version"
    if n > MAX_PACKET_BYTES:
        return -1, "oversized"
    if n < 5:
        return -1, "short"
    (n1,) = _LEN.unpack_from(data, 1)
    if n1 < 0 or 5 + n1 > n:
        return -1, "bad_length"
    if 9 + n1 > n:
        return -1, "short"
    (n2,) = _LEN.unpack_from(data, 5 + n1)
    if n2 < 0 or 9 + n1 + n2 > n:
        return -1, "bad_length"
    return 9 + n1 + n2, None


def check_body(data: bytes | bytearray | memoryview, offset: int, size: int) -> str | None:
    """Rejection reason for the part after the strings, or None when it is a frame block (frame time,
    count, values) or, ``FRAME_TIME_BYTES`` long, the frame time of a no-face packet."""
    rest = size - offset
    if rest < FRAME_TIME_BYTES:
        return "short"
    if rest > FRAME_TIME_BYTES:
        if data[offset + FRAME_TIME_BYTES] != BLENDSHAPE_COUNT:
            return "count"
        if rest < FRAME_BLOCK_BYTES:
            return "short"
        if rest > FRAME_BLOCK_BYTES:
            return "size_mismatch"
    frame_number, sub_frame, num, den = _FRAME_TIME.unpack_from(data, offset)
    if not plausible_rate(num, den):
        return "bad_rate"
    if frame_number < 0 or not (0.0 <= sub_frame < 1.0):
        return "bad_frame_time"
    return None


def rate_denominator(den):
    """The rate denominator to divide by: 0 is read as 1. PyLiveLinkFace, the Python sender many tools
    build on, sends ``int(fps / 60)``, which is 0 at 30 fps (formats doc §5.5); its numerator is the
    rate. Ints or integer arrays."""
    return den + (den == 0)


def plausible_rate(num, den):
    """Whether the rate ``num / den`` (``rate_denominator``) is positive and at most MAX_RATE_FPS (ints or
    integer arrays, compared in integers)."""
    den = rate_denominator(den)
    return (den > 0) & (num > 0) & (num <= MAX_RATE_FPS * den)


def decode_strings(data: bytes | bytearray | memoryview, offset: int) -> tuple[str, str] | None:
    """Device id and subject of a packet whose header parsed to ``offset``; None if not UTF-8."""
    (n1,) = _LEN.unpack_from(data, 1)
    try:
        device = bytes(data[5 : 5 + n1]).decode("utf-8")
        subject = bytes(data[9 + n1 : offset]).decode("utf-8")
    except UnicodeDecodeError:
        return None
    return device, subject


def decode_packet(data: bytes | bytearray | memoryview) -> LiveLinkFrame | str:
    """A ``LiveLinkFrame``, or the rejection reason (a ``REJECT_REASONS`` string). Never raises."""
    size = len(data)
    offset, reason = parse_header(data, size)
    if reason is not None:
        return reason
    reason = check_body(data, offset, size)
    if reason is not None:
        return reason
    names = decode_strings(data, offset)
    if names is None:
        return "bad_text"
    if size - offset == FRAME_TIME_BYTES:
        frame_number, sub_frame, num, den = _FRAME_TIME.unpack_from(data, offset)
        nan = np.full(BLENDSHAPE_COUNT, np.nan, dtype=np.float32)
        return LiveLinkFrame(names[0], names[1], frame_number, sub_frame, num, den, nan, face=False)
    return decode_frame_block(names[0], names[1], data, offset)


def decode_frame_block(device: str, subject: str, data, offset: int = 0) -> LiveLinkFrame:
    """The frame at ``offset`` of ``data`` (a checked frame block: time, count, values)."""
    frame_number, sub_frame, num, den = _FRAME_TIME.unpack_from(data, offset)
    values = np.frombuffer(
        bytes(data[offset + FRAME_TIME_BYTES + 1 : offset + FRAME_BLOCK_BYTES]), dtype=VALUES_DTYPE
    ).astype(np.float32)
    return LiveLinkFrame(device, subject, frame_number, sub_frame, num, den, values)
