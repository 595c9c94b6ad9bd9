"""Praat TextGrid reading and writing (capture.textgrid)."""

from __future__ import annotations

import pytest

from capture.errors import InputError
from capture.textgrid import (
    Interval,
    Point,
    TextGrid,
    Tier,
    interval_tier,
    read_textgrid,
    write_textgrid,
)

# As Montreal Forced Aligner / Praat write it (long text format), hand-written for this test.
_LONG = """File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 1.25
tiers? <exists>
size = 2
item []:
    item [1]:
        class = "IntervalTier"
        name = "words"
        xmin = 0
        xmax = 1.25
        intervals: size = 3
        intervals [1]:
            xmin = 0
            xmax = 0.31
            text = ""
        intervals [2]:
            xmin = 0.31
            xmax = 0.92
            text = "say ""hi"" [2]"
        intervals [3]:
            xmin = 0.92
            xmax = 1.25
            text = ""
    item [2]:
        class = "TextTier"
        name = "events"
        xmin = 0
        xmax = 1.25
        points: size = 1
        points [1]:
            number = 0.5
            mark = "click"
"""


def _with_praat_spaces(text: str) -> str:
    """Praat ends each value line (and ``item []:``) with a space; the literal above leaves them out."""
    out = []
    for line in text.splitlines():
        value = "=" in line or "<" in line or line.endswith("[]:")
        out.append(line + " " if value and not line.startswith(("File type", "Object class")) else line)
    return "\n".join(out) + "\n"


LONG = _with_praat_spaces(_LONG)

SHORT = """File type = "ooTextFile"
Object class = "TextGrid"

0
2.5
<exists>
1
"IntervalTier"
"phones"
0
2.5
2
0
1.5e-1
"sil"
0.15
2.5
"AA1"
"""


def test_round_trip_keeps_every_value(tmp_path):
    words = interval_tier("words", [(0.125, 0.5, 'quote " in'), (0.75, 1.1, "naïve")], 0.0, 1.5)
    phones = Tier("phones", 0.0, 1.5, [Interval(0.0, 0.1 + 0.2, "p"), Interval(0.1 + 0.2, 1.5, "")])
    points = Tier("events", 0.0, 1.5, points=[Point(0.25, "blink")], kind="TextTier")
    tg = TextGrid(0.0, 1.5, [words, phones, points])
    path = write_textgrid(tg, tmp_path / "a.TextGrid")
    back = read_textgrid(path)
    assert back == tg
    # Gaps between the given intervals became silence intervals.
    assert [iv.text for iv in back.tier("words").intervals] == ["", 'quote " in', "", "naïve", ""]
    assert back.tier("phones").intervals[0].xmax == 0.1 + 0.2  # floats survive exactly


def test_reads_hand_written_long_format(tmp_path):
    path = tmp_path / "mfa.TextGrid"
    path.write_text(LONG, encoding="utf-8")
    tg = read_textgrid(path)
    assert (tg.xmin, tg.xmax) == (0.0, 1.25)
    words = tg.tier("words")
    assert words.intervals == [
        Interval(0.0, 0.31, ""),
        Interval(0.31, 0.92, 'say "hi" [2]'),
        Interval(0.92, 1.25, ""),
    ]
    events = tg.tier("events")
    assert events.kind == "TextTier" and events.points == [Point(0.5, "click")]


def test_reads_short_format_in_utf16(tmp_path):
    path = tmp_path / "short.TextGrid"
    path.write_bytes(SHORT.encode("utf-16"))
    tg = read_textgrid(path)
    assert tg.tier("phones").intervals == [Interval(0.0, 0.15, "sil"), Interval(0.15, 2.5, "AA1")]


def test_malformed_textgrid_is_an_input_error(tmp_path):
    path = tmp_path / "bad.TextGrid"
    path.write_text(LONG.replace("intervals: size = 3", "intervals: size = 4"), encoding="utf-8")
    with pytest.raises(InputError, match="bad.TextGrid"):
        read_textgrid(path)
    path.write_text("hello", encoding="utf-8")
    with pytest.raises(InputError, match="TextGrid"):
        read_textgrid(path)
    with pytest.raises(InputError, match="no tier"):
        TextGrid(0.0, 1.0).tier("words")


def test_missing_tier_error_names_the_file(tmp_path):
    path = write_textgrid(TextGrid(0.0, 1.0, [interval_tier("words", [], 0.0, 1.0)]), tmp_path / "a.TextGrid")
    with pytest.raises(InputError) as err:
        read_textgrid(path).tier("phones")
    assert str(err.value) == f"{path}: TextGrid has no tier 'phones' (tiers: ['words'])"
