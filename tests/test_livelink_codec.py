"""The Live Link v6 packet codec: the real app packet, no-face packets, round trips, and rejection by
reason."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capture import livelink as ll

# A packet captured from the Live Link Face app (formats doc §5.3; hex dump from markandre13's
# makehuman.js-backend test/facecap/livelink.spec.cc).
REAL_PACKET_HEX = """
06 00 00 00 24 35 39 30 34 41 41 34 42 2d 41 44 39 44 2d 34 33 45 35 2d 39 38 41 42 2d 38 39 41
41 45 42 38 41 42 32 37 37 00 00 00 06 69 50 68 6f 6e 65 00 0a 3f d9 3f 07 02 80 00 00 00 3c 00
00 00 01 3d 00 00 00 00 00 00 00 00 3e c9 b8 6a 00 00 00 00 3e d7 96 e6 3e b5 13 eb 3e b3 47 98
00 00 00 00 00 00 00 00 00 00 00 00 3e 97 ab 08 3e da 44 3d 3e b5 0f 2f 3e b3 3f 63 3c e3 c7 5e
3b b0 00 94 00 00 00 00 3d 40 80 09 3d 48 0c 85 3d 59 1b 19 3d a4 59 92 3d 09 46 e1 00 00 00 00
3d a7 f2 d7 3d 51 d7 20 00 00 00 00 00 00 00 00 3d 62 4d 76 3d 43 58 68 3e 3e 4e 89 3e 30 ca d7
3d b9 7b 00 3c d0 49 06 3e 06 f9 f0 3d a6 c3 de 3d a9 2d 8f 3d af c4 7d 3d 87 9d 09 3d 6e e3 a3
3c ab aa a7 3c 85 38 1d 3e 8a 65 4d 3e 8a 65 8d 3d de e4 e4 00 00 00 00 00 00 00 00 3c d7 3e e1
3d fa 6c e0 3d e0 ae af 3d f9 90 0b 3d bf 04 08 32 5e 53 9a bd 39 d0 a6 3e 62 75 a2 3d a6 2c 00
3e 36 11 16 be 41 8f 99 bd 0a 89 a9 3e 72 38 60 be 41 97 25 bd 37 89 78
"""
REAL_PACKET = bytes.fromhex("".join(REAL_PACKET_HEX.split()))


def test_real_packet_decodes_to_the_documented_values_and_reencodes_exactly():
    assert len(REAL_PACKET) == 312
    frame = ll.decode_packet(REAL_PACKET)
    assert isinstance(frame, ll.LiveLinkFrame)
    assert frame.device == "5904AA4B-AD9D-43E5-98AB-89AAEB8AB277"
    assert frame.subject == "iPhone"
    assert frame.frame_number == 671705
    assert frame.sub_frame == pytest.approx(0.527382, abs=1e-6)
    assert (frame.rate_numerator, frame.rate_denominator) == (60, 1)
    named = dict(zip(ll.LIVELINK_ORDER, frame.values.tolist()))
    assert named["EyeLookInLeft"] == pytest.approx(0.394, abs=5e-4)
    assert named["JawOpen"] == pytest.approx(0.047, abs=5e-4)
    assert named["HeadYaw"] == pytest.approx(-0.045, abs=5e-4)
    assert named["HeadPitch"] == pytest.approx(0.221, abs=5e-4)
    assert named["HeadRoll"] == pytest.approx(0.081, abs=5e-4)
    assert frame.values[60] == np.float32(-0.044808835)
    assert frame.time_s == pytest.approx((671705 + 0.527382) / 60)
    assert ll.encode_packet(frame) == REAL_PACKET


def _packet(device="dev", subject="iPhone", fn=100, sf=0.25, num=60, den=1, values=None) -> bytes:
    values = np.arange(61, dtype=np.float32) / 61 if values is None else values
    return ll.encode_packet(ll.LiveLinkFrame(device, subject, fn, sf, num, den, values))


def test_rejections_are_counted_by_reason_never_raised():
    good = _packet()
    cases = {
        "version": bytes([5]) + good[1:],
        "short": good[:3],
        "bad_length": good[:1] + struct.pack(">i", 10_000) + good[5:],
        "count": good[: len(good) - 245] + bytes([52]) + good[len(good) - 244 :],
        "size_mismatch": good + b"\x00\x00\x00\x00",
        "oversized": good + bytes(2000),
        "bad_rate": _packet(num=0),
        "bad_frame_time": _packet(fn=-5),
        "bad_text": bytes([6]) + struct.pack(">i", 2) + b"d\xff" + good[8:],
    }
    for reason, data in cases.items():
        assert ll.decode_packet(data) == reason, reason
    assert ll.decode_packet(good[:-1]) == "short"
    assert ll.decode_packet(b"") == "short"
    for reason in cases:
        assert reason in ll.REJECT_REASONS


def test_no_face_packet_is_a_frame_without_a_face_and_malformed_ones_are_rejected():
    data = ll.no_face_packet("dev", "iPhone", 100, 0.5, 60, 1)
    assert len(data) == len(_packet()) - 1 - 4 * 61  # ends after the frame time
    frame = ll.decode_packet(data)
    assert isinstance(frame, ll.LiveLinkFrame) and frame.face is False
    assert (frame.device, frame.subject, frame.frame_number, frame.sub_frame) == ("dev", "iPhone", 100, 0.5)
    assert frame.time_s == pytest.approx(100.5 / 60)
    assert frame.values.shape == (61,) and frame.values.dtype == np.float32 and np.isnan(frame.values).all()
    assert ll.encode_packet(frame) == data
    assert ll.decode_packet(_packet()).face is True
    # A no-face packet is checked like any other: its frame time, and nothing after it but a frame block.
    for reason, bad in {
        "bad_rate": ll.no_face_packet("dev", "iPhone", 100, 0.5, 60, -1),
        "bad_frame_time": ll.no_face_packet("dev", "iPhone", -1, 0.5, 60, 1),
        "short": data[:-1],
        "count": data + b"\0",
        "version": bytes([7]) + data[1:],
    }.items():
        assert ll.decode_packet(bad) == reason, reason
    # PyLiveLinkFace at 30 fps sends denominator int(30 / 60) = 0: read as 30/1.
    quirk = ll.decode_packet(ll.no_face_packet("dev", "iPhone", 90, 0.0, 30, 0))
    assert quirk.rate == 30 and quirk.time_s == pytest.approx(3.0)


@settings(max_examples=300, deadline=None)
@given(
    device=st.text(max_size=40),
    subject=st.text(max_size=20),
    fn=st.integers(0, 2**31 - 1),
    sf=st.floats(0, 0.5, width=32),
    num=st.integers(1, 240),
    den=st.integers(1, 1001),
    values=st.lists(st.floats(width=32, allow_nan=False), min_size=61, max_size=61),
)
def test_round_trip(device, subject, fn, sf, num, den, values):
    frame = ll.LiveLinkFrame(device, subject, fn, sf, num, den, np.array(values, np.float32))
    data = ll.encode_packet(frame)
    if len(data) > ll.MAX_PACKET_BYTES:
        assert ll.decode_packet(data) == "oversized"
        return
    back = ll.decode_packet(data)
    assert isinstance(back, ll.LiveLinkFrame)
    assert (back.device, back.subject, back.frame_number, back.rate_numerator) == (device, subject, fn, num)
    assert np.array_equal(back.values, frame.values)
    assert ll.encode_packet(back) == data


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=1200))
def test_random_bytes_never_raise(data):
    out = ll.decode_packet(data)
    assert isinstance(out, ll.LiveLinkFrame) or out in ll.REJECT_REASONS
