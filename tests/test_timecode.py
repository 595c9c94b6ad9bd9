import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from capture.timecode import Timecode, fixed_width_seconds, unwrap_midnight


def test_frames_are_sixtieths_not_milliseconds():
    tc = Timecode.parse("14:58:02:44.643")
    assert tc.seconds_of_day == pytest.approx(14 * 3600 + 58 * 60 + 2 + 44.643 / 60)
    assert Timecode.parse("10:13:39:01.936").format() == "10:13:39:01.936"


def test_malformed_timecodes_raise_value_error():
    for bad in ("", "10:13:39", "10:13:39:xx", "25:00:00:00.000", "10:61:00:00.0", "10:00:00:60.5"):
        with pytest.raises(ValueError):
            Timecode.parse(bad)


def test_format_carries_instead_of_printing_sixty():
    tc = Timecode.from_seconds(3600 + 59 + 59.9996 / 60)
    assert tc.format() == "01:01:00:00.000"
    assert Timecode.from_seconds(86400 - 1e-7).format() == "00:00:00:00.000"


def test_unwrap_midnight():
    t = np.array([86399.9, 86399.95, 0.0, 0.05])
    assert np.allclose(unwrap_midnight(t), [86399.9, 86399.95, 86400.0, 86400.05])


@given(st.lists(st.floats(0, 86399.99), min_size=1, max_size=50))
def test_fixed_width_parser_agrees_with_the_general_one(seconds):
    texts = [Timecode.from_seconds(s).format() for s in seconds]
    chars = np.frombuffer("".join(texts).encode(), dtype=np.uint8).reshape(-1, 15)
    fast, ok = fixed_width_seconds(chars)
    assert ok.all()
    slow = np.array([Timecode.parse(t).seconds_of_day for t in texts])
    assert np.array_equal(fast, slow)  # to the bit: both parsers give one time for one cell


def test_fixed_width_parser_declines_other_layouts():
    chars = np.frombuffer(b"10:13:39:1.9360", dtype=np.uint8).reshape(1, 15)
    assert not fixed_width_seconds(chars)[1].any()
