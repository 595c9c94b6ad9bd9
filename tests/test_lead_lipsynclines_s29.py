"""eval's text line of errors by phone class when no scored frame's phone falls in a class."""

from __future__ import annotations

from train.evaluate import _lipsync_lines


def test_no_classified_frame_is_said_not_left_blank():
    # every scored frame's phone outside ARPAbet (unclassified): was "by phone class, rmse/floor (frames): "
    empty = {"rmse": 0.0, "floor": 0.0, "frames": 0}
    result = {
        "per_phone_class": {"classes": {"bilabial": empty, "silence": empty}},
        "bilabial_closure": None,
        "bilabial_closure_note": "no bilabial segment",
        "open_vowel_opening": None,
        "open_vowel_opening_note": "no open-vowel segment",
    }
    first = _lipsync_lines(result)[0]
    assert first == "  by phone class, rmse/floor (frames): no frame's phone in a class"
