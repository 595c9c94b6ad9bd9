"""The realtime packet of Live Link Face's newer stream (the Unreal Engine 5.6+ "Live Link Face" source,
formats doc §5.6), how an ARKit subject's packet becomes the classic version-6 packet, and how another
subject's (MetaHuman Animator's) becomes a CONTROLS record of the session log (``controls_record``).

Layout, read field by field with Unreal's ``FArrayReader`` (no byte swapping: little-endian)::

    u16 version | u16 n + n bytes UTF-8 subject id | i32 frame number | f32 sub-frame |
    i32 rate numerator | i32 rate denominator | u16 count | count x u16 control value |
    6 x f32 head pose (roll, pitch, yaw, x, y, z)

Bytes after the head pose are read past, as Unreal's reader reads past them. A control value is
``u16 / 65535``; the control names and their order are the subject's, told by the phone over the control
session (``cps_control``), not by the packet. Sources: Unreal Engine 5.8
``MetaHumanLiveLink/Source/LiveLinkFaceSource/Private/LiveLinkFacePacket.cpp`` (the reader) and
``LiveLinkFaceSource.cpp`` (scaling, head pose order).

Decoding never raises for bad input: ``decode_realtime_packet`` returns a ``RealtimePacket`` or a
rejection reason (one of ``REALTIME_REJECT_REASONS``).
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass

import numpy as np

from . import livelink as ll
from .channels import LIVELINK_ORDER, is_known, udp_index
from .record_log import RecordType, encode_record

# The largest datagram accepted. Unreal's receiver says "in reality the packets are between 1KB and 2KB";
# a subject of 4,000 controls (MetaHuman Animator's are a few hundred) still fits.
MAX_REALTIME_PACKET_BYTES = 8192
CONTROL_SCALE = 65535.0  # a control value is u16 / 65535
HEAD_POSE = ("roll", "pitch", "yaw", "x", "y", "z")
# The head rotation as a take's channels, in the classic stream's order (LIVELINK_ORDER), and where each is
# in the packet's head pose. Unreal passes the pose on as HeadRoll, HeadPitch, HeadYaw (and
# HeadTranslationX/Y/Z) unchanged: its units and signs are not stated in its source.
HEAD_CHANNELS = {"HeadYaw": 2, "HeadPitch": 1, "HeadRoll": 0}
# The most bytes of UTF-8 a classic packet's device id and subject name may take together: the rest of a
# version-6 packet (version, two lengths, frame block) and they stay within livelink.MAX_PACKET_BYTES.
CLASSIC_NAME_BYTES = ll.MAX_PACKET_BYTES - len(ll.header_bytes("", "")) - ll.FRAME_BLOCK_BYTES
_HASH_MARK = "~"  # a shortened name ends in this and 8 hex digits of its whole text's SHA-1

_ID_LEN = struct.Struct("<HH")  # version, subject id length
_FRAME_TIME = struct.Struct("<ifii")  # frame number, sub-frame, rate numerator, rate denominator
_COUNT = struct.Struct("<H")
_HEAD_POSE = struct.Struct("<6f")
_CONTROLS_PREFIX = struct.Struct("<BHq")  # record type, stream id, arrival ns (as a FRAME record's)

# Why a realtime datagram was not recorded (beside the classic packet's checks the recorder makes).
REALTIME_REJECT_REASONS: tuple[str, ...] = (
    "not_allowed",  # not from the phone of the control session (nor from an --allow address)
    "oversized",  # longer than MAX_REALTIME_PACKET_BYTES
    "short",  # ends before the field being read
    "bad_text",  # the subject id is not UTF-8
    "not_streaming",  # came while no subject was streaming (before the control session, between two)
    "unknown_subject",  # a subject id the phone is not streaming to us
    "control_count",  # a count other than the subject's number of controls
)


@dataclass
class RealtimePacket:
    """One decoded realtime packet; ``controls`` are 0..1 (u16 / 65535), in the subject's control order."""

    version: int
    subject_id: str
    frame_number: int
    sub_frame: float
    rate_numerator: int
    rate_denominator: int
    controls: np.ndarray  # float32 (count,)
    head_pose: np.ndarray  # float32 (6,): roll, pitch, yaw, x, y, z


def encode_realtime_packet(
    subject_id: str,
    frame_number: int,
    sub_frame: float,
    rate_numerator: int,
    rate_denominator: int,
    controls,
    head_pose=(0.0,) * 6,
    version: int = 1,
) -> bytes:
    """The realtime packet (as the phone sends it); ``controls`` 0..1 are rounded to u16, clipped."""
    sid = subject_id.encode("utf-8")
    raw = np.rint(np.clip(np.asarray(controls, dtype=np.float64), 0.0, 1.0) * CONTROL_SCALE)
    return (
        _ID_LEN.pack(version, len(sid))
        + sid
        + _FRAME_TIME.pack(frame_number, sub_frame, rate_numerator, rate_denominator)
        + _COUNT.pack(raw.size)
        + raw.astype("<u2").tobytes()
        + _HEAD_POSE.pack(*head_pose)
    )


def decode_realtime_packet(data: bytes | bytearray | memoryview) -> RealtimePacket | str:
    """A ``RealtimePacket``, or the rejection reason (a ``REALTIME_REJECT_REASONS`` string). Never raises."""
    n = len(data)
    if n > MAX_REALTIME_PACKET_BYTES:
        return "oversized"
    if n < _ID_LEN.size:
        return "short"
    version, id_len = _ID_LEN.unpack_from(data, 0)
    at = _ID_LEN.size + id_len
    if at + _FRAME_TIME.size + _COUNT.size > n:
        return "short"
    try:
        subject_id = bytes(data[_ID_LEN.size : at]).decode("utf-8")
    except UnicodeDecodeError:
        return "bad_text"
    frame_number, sub_frame, num, den = _FRAME_TIME.unpack_from(data, at)
    at += _FRAME_TIME.size
    (count,) = _COUNT.unpack_from(data, at)
    at += _COUNT.size
    if at + 2 * count + _HEAD_POSE.size > n:
        return "short"
    # bytes after the head pose are read past, as Unreal's reader does (a later packet version's fields)
    controls = np.frombuffer(data, dtype="<u2", count=count, offset=at).astype(np.float32) / CONTROL_SCALE
    head = np.array(_HEAD_POSE.unpack_from(data, at + 2 * count), dtype=np.float32)
    return RealtimePacket(version, subject_id, frame_number, sub_frame, num, den, controls, head)


def _shortened(text: str, limit: int) -> str:
    """``text`` in at most ``limit`` bytes of UTF-8: itself when it fits, else cut at a character boundary
    and ended by ``~`` and 8 hex digits of its whole text's SHA-1 (long names that differ only past the
    cut stay apart)."""
    raw = text.encode("utf-8")
    if len(raw) <= limit:
        return text
    mark = _HASH_MARK + hashlib.sha1(raw).hexdigest()[:8]
    return raw[: limit - len(mark)].decode("utf-8", "ignore") + mark


def classic_names(device: str, subject: str) -> tuple[str, str]:
    """The device id and subject name a classic packet can carry (``CLASSIC_NAME_BYTES`` together): the
    same when they fit, else each longer than its share (half, and what the other leaves) shortened
    (``_shortened``), the same every time for the same names."""
    device_bytes, subject_bytes = len(device.encode("utf-8")), len(subject.encode("utf-8"))
    if device_bytes + subject_bytes <= CLASSIC_NAME_BYTES:
        return device, subject
    half = CLASSIC_NAME_BYTES // 2
    device_share = max(half, CLASSIC_NAME_BYTES - subject_bytes)
    device = _shortened(device, device_share)
    return device, _shortened(subject, CLASSIC_NAME_BYTES - len(device.encode("utf-8")))


class ArkitMapping:
    """Where an ARKit subject's controls and head pose go among the classic packet's 61 values.

    Controls are matched by name in any spelling ``capture.channels`` accepts (``EyeBlinkLeft``,
    ``eyeBlinkLeft``); the head pose's roll, pitch and yaw fill HeadRoll, HeadPitch and HeadYaw unless the
    subject has controls of those names. Channels the subject does not carry (the eyes' rotations, as a
    rule) are 0, as the app sends a channel it does not track; ``unmatched`` lists the subject's controls
    that are no Live Link channel, ``missing`` the channels it lacks."""

    def __init__(self, controls: list[str] | tuple[str, ...]):
        self.count = len(controls)
        slots = [udp_index(c) if is_known(c) else -1 for c in controls]
        self.unmatched = [c for c, s in zip(controls, slots, strict=True) if s < 0]
        keep = np.array([s >= 0 for s in slots], dtype=bool)
        self._from = np.flatnonzero(keep)
        self._to = np.array([s for s in slots if s >= 0], dtype=np.intp)
        taken = set(self._to.tolist())
        pose_slots = [
            (udp_index(name), k) for name, k in HEAD_CHANNELS.items() if udp_index(name) not in taken
        ]
        self._pose_to = np.array([slot for slot, _ in pose_slots], dtype=np.intp)
        self._pose_from = np.array([k for _, k in pose_slots], dtype=np.intp)
        taken |= set(self._pose_to.tolist())
        self.missing = [name for i, name in enumerate(LIVELINK_ORDER) if i not in taken]

    def values(self, packet: RealtimePacket) -> np.ndarray:
        """The 61 values (``LIVELINK_ORDER``) of ``packet``, a packet of this subject."""
        out = np.zeros(ll.BLENDSHAPE_COUNT, dtype=np.float32)
        out[self._to] = packet.controls[self._from]
        out[self._pose_to] = packet.head_pose[self._pose_from]
        return out

    def classic_packet(self, device: str, subject: str, packet: RealtimePacket) -> bytes:
        """The version-6 packet of ``packet`` from ``device`` / ``subject``: what the classic stream sends."""
        return ll.header_bytes(device, subject) + ll.frame_block(
            packet.frame_number,
            packet.sub_frame,
            packet.rate_numerator,
            packet.rate_denominator,
            self.values(packet),
        )


def head_channels(controls: list[str]) -> tuple[list[str], np.ndarray]:
    """The head rotation's channels a subject with ``controls`` is recorded with beside them (those of
    ``HEAD_CHANNELS`` it has no control of, case ignored) and where their values are in the head pose."""
    named = {c.lower() for c in controls}
    kept = [name for name in HEAD_CHANNELS if name.lower() not in named]
    return kept, np.array([HEAD_CHANNELS[name] for name in kept], dtype=np.intp)


def controls_record(
    stream: int, arrival_ns: int, packet: RealtimePacket, head_from: np.ndarray | None = None
) -> bytes:
    """The frames-log record (``RecordType.CONTROLS``) of a packet of a subject recorded with its own
    controls: stream id, arrival, the frame time as a classic packet's, the control values and then the
    head pose's values at ``head_from`` (``head_channels``)."""
    head = b"" if head_from is None else packet.head_pose[head_from].astype(">f4").tobytes()
    return encode_record(
        _CONTROLS_PREFIX.pack(RecordType.CONTROLS, stream, arrival_ns)
        + ll._FRAME_TIME.pack(
            packet.frame_number, packet.sub_frame, packet.rate_numerator, packet.rate_denominator
        )
        + packet.controls.astype(">f4").tobytes()
        + head
    )
