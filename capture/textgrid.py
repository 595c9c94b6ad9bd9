"""Praat TextGrid files: the phone and word alignments forced aligners (MFA, Gentle via converters,
WebMAUS) write, and the simulated speaker writes as ground truth. MFA names the tiers ``words`` and
``phones``, or ``<speaker> - words`` and ``<speaker> - phones`` for each speaker of a file with several
(``TextGrid.speaker_tiers``).

Writing produces Praat's long text format (UTF-8). Reading accepts the long and the short text format
in UTF-8 or UTF-16 (Praat's choice for non-ASCII text), with interval tiers and point ("TextTier")
tiers. Both formats are the same sequence of values once labels like ``xmin =`` and indices like
``intervals [3]:`` are ignored, which is how the reader parses them. Times are seconds.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from .errors import InputError

_TOKEN = re.compile(
    r'"(?P<str>(?:[^"]|"")*)"'  # a string; "" inside is an escaped quote
    r"|\[[^\]\"]*\]"  # an index such as [3] or []: not a value
    r"|(?P<flag><exists>|<absent>)"
    r"|(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
    r"|!.*"  # a comment to the end of the line (short format)
)


@dataclass(frozen=True)
class Interval:
    """A labelled stretch of time ``[xmin, xmax)`` in seconds; ``text`` is ``""`` for silence."""

    xmin: float
    xmax: float
    text: str


@dataclass(frozen=True)
class Point:
    """A labelled instant (seconds) of a point tier."""

    time: float
    mark: str


@dataclass
class Tier:
    """An interval tier (``IntervalTier``) or a point tier (``TextTier``)."""

    name: str
    xmin: float
    xmax: float
    intervals: list[Interval] = field(default_factory=list)
    points: list[Point] = field(default_factory=list)
    kind: str = "IntervalTier"


@dataclass
class TextGrid:
    """Tiers over a common time span ``[xmin, xmax]`` (seconds)."""

    xmin: float
    xmax: float
    tiers: list[Tier] = field(default_factory=list)
    path: str | None = field(default=None, compare=False, repr=False)  # the file it was read from

    def tier(self, name: str) -> Tier:
        """The first tier called ``name``."""
        for t in self.tiers:
            if t.name == name:
                return t
        raise InputError(f"TextGrid has no tier {name!r} (tiers: {[t.name for t in self.tiers]})", self.path)

    def speaker_tiers(self, name: str) -> list[Tier]:
        """The tier called ``name``, or else every tier called ``<speaker> - name``: the tiers Montreal
        Forced Aligner writes for each speaker of a file with several (``A - phones``, ``B - phones``)."""
        if any(t.name == name for t in self.tiers):
            return [self.tier(name)]
        return [t for t in self.tiers if t.name.endswith(f" - {name}")] or [self.tier(name)]  # or its error


def interval_tier(name: str, intervals: list[tuple[float, float, str]], xmin: float, xmax: float) -> Tier:
    """An interval tier from ``(start s, end s, label)`` triples; gaps are filled with ``""``."""
    out: list[Interval] = []
    t = xmin
    for a, b, text in intervals:
        if a > t:
            out.append(Interval(t, a, ""))
        out.append(Interval(a, b, text))
        t = b
    if t < xmax:
        out.append(Interval(t, xmax, ""))
    return Tier(name, xmin, xmax, out)


def _num(x: float) -> str:
    # Praat prints integral times without a decimal point; repr keeps every other float exact.
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def _quote(text: str) -> str:
    return '"' + text.replace('"', '""') + '"'


def format_textgrid(tg: TextGrid) -> str:
    """The long text format Praat writes."""
    lines = [
        'File type = "ooTextFile"',
        'Object class = "TextGrid"',
        "",
        f"xmin = {_num(tg.xmin)} ",
        f"xmax = {_num(tg.xmax)} ",
        "tiers? <exists> " if tg.tiers else "tiers? <absent> ",
    ]
    if tg.tiers:
        lines.append(f"size = {len(tg.tiers)} ")
        lines.append("item []: ")
    for k, tier in enumerate(tg.tiers, start=1):
        lines += [
            f"    item [{k}]:",
            f'        class = "{tier.kind}" ',
            f"        name = {_quote(tier.name)} ",
            f"        xmin = {_num(tier.xmin)} ",
            f"        xmax = {_num(tier.xmax)} ",
        ]
        if tier.kind == "IntervalTier":
            lines.append(f"        intervals: size = {len(tier.intervals)} ")
            for i, iv in enumerate(tier.intervals, start=1):
                lines += [
                    f"        intervals [{i}]:",
                    f"            xmin = {_num(iv.xmin)} ",
                    f"            xmax = {_num(iv.xmax)} ",
                    f"            text = {_quote(iv.text)} ",
                ]
        else:
            lines.append(f"        points: size = {len(tier.points)} ")
            for i, pt in enumerate(tier.points, start=1):
                lines += [
                    f"        points [{i}]:",
                    f"            number = {_num(pt.time)} ",
                    f"            mark = {_quote(pt.mark)} ",
                ]
    return "\n".join(lines) + "\n"


def write_textgrid(tg: TextGrid, path: str | Path) -> Path:
    """Write ``tg`` in Praat's long text format (UTF-8, LF line ends)."""
    path = Path(path)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(format_textgrid(tg))
    return path


def _decode(raw: bytes, path: Path) -> str:
    """UTF-16 after its byte-order mark, else UTF-8; ``InputError`` naming the line of the first bytes
    that do not decode (a UTF-16 file cut to an odd length, a lone surrogate)."""
    utf16 = raw.startswith((b"\xff\xfe", b"\xfe\xff"))
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    encoding = "utf-16" if utf16 else "utf-8"
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].decode(encoding, errors="replace").count("\n") + 1
        what = (
            "not UTF-16 text after its UTF-16 byte-order mark" if utf16 else "neither UTF-8 nor UTF-16 text"
        )
        raise InputError(f"TextGrid is {what} ({exc.reason})", path, line) from None


def parse_textgrid(text: str, path: str | Path | None = None) -> TextGrid:
    """Parse the long or short text format; raises ``InputError`` naming what is malformed."""
    values: list[object] = []
    starts: list[int] = []  # where each value starts in ``text``, for the line an error names
    for m in _TOKEN.finditer(text):
        if m.group("str") is not None:
            values.append(m.group("str").replace('""', '"'))
        elif m.group("num") is not None:
            values.append(float(m.group("num")))
        elif m.group("flag") is not None:
            values.append(m.group("flag"))
        else:
            continue
        starts.append(m.start())
    pos = 0

    def malformed(message: str, at: int) -> InputError:
        """The error for value ``at``, naming its line."""
        return InputError(f"malformed TextGrid: {message}", path, text.count("\n", 0, starts[at]) + 1)

    def take(kind: type, what: str) -> object:
        nonlocal pos
        if pos >= len(values):
            raise InputError(f"TextGrid ends early: expected {what}", path)
        v = values[pos]
        if not isinstance(v, kind):
            raise malformed(f"expected {what}, found {v!r}", pos)
        if isinstance(v, float) and not math.isfinite(v):  # 1e999
            raise malformed(f"{what} is out of range", pos)
        pos += 1
        return v

    def count(what: str) -> int:
        """A number of items: whole, not negative, and no more than the values left could hold."""
        n = take(float, what)
        if not (n.is_integer() and 0 <= n <= len(values) - pos):  # type: ignore[attr-defined]
            raise malformed(f"{what} {n:g} is not a count of what follows", pos - 1)
        return int(n)  # type: ignore[call-overload]

    if take(str, "file type") != "ooTextFile" or take(str, "object class") != "TextGrid":
        raise InputError(
            'not a TextGrid (expected File type = "ooTextFile", Object class = "TextGrid")', path
        )
    tg = TextGrid(float(take(float, "xmin")), float(take(float, "xmax")))  # type: ignore[arg-type]
    tg.path = str(path) if path is not None else None
    flag = take(str, "tiers? <exists>")
    if flag == "<absent>":
        return tg
    n_tiers = count("number of tiers")
    for _ in range(n_tiers):
        kind = take(str, "tier class")
        if kind not in ("IntervalTier", "TextTier"):
            raise InputError(f"unknown TextGrid tier class {kind!r}", path)
        name = str(take(str, "tier name"))
        xmin, xmax = float(take(float, "tier xmin")), float(take(float, "tier xmax"))  # type: ignore[arg-type]
        items = count("item count")
        tier = Tier(name, xmin, xmax, kind=str(kind))
        for _ in range(items):
            if kind == "IntervalTier":
                a, b = float(take(float, "interval xmin")), float(take(float, "interval xmax"))  # type: ignore[arg-type]
                if b < a:
                    raise InputError(f"tier {name!r}: interval ends before it starts ({a} > {b})", path)
                tier.intervals.append(Interval(a, b, str(take(str, "interval text"))))
            else:
                tier.points.append(Point(float(take(float, "point time")), str(take(str, "point mark"))))  # type: ignore[arg-type]
        tg.tiers.append(tier)
    return tg


def read_textgrid(path: str | Path) -> TextGrid:
    """Read a TextGrid file (long or short text format, UTF-8 or UTF-16)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError("TextGrid file not found", path) from None
    return parse_textgrid(_decode(raw, path), path)
