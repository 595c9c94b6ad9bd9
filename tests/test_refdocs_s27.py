"""The reference pages' tables of limits, thresholds and report fields match the code.

docs/align.md, docs/viewer.md and docs/simulate.md state option ranges, outlier thresholds and the
fields of align's JSON report in prose; these tests read the numbers and names out of the pages and
compare them with the constants the code uses (and, for align's report, with a real report), so a
change on either side without the other fails here.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys

import pytest
from conftest import ROOT

DOCS = ROOT / "docs"
BIN = ROOT / ".venv" / "bin"


def _page(name: str) -> str:
    """The page with its line breaks folded into spaces (claims wrap across lines)."""
    return re.sub(r"\s*\n\s*", " ", (DOCS / name).read_text(encoding="utf-8"))


def _number(text: str) -> float:
    return float(text.replace(",", "").replace("−", "-"))


def test_align_option_ranges_match_align_options():
    from align.options import RANGES

    page = _page("align.md")
    sentence = re.search(r"The numbers have ranges: (.*?); a value outside", page)
    assert sentence, "docs/align.md lost its sentence 'The numbers have ranges: ...; a value outside'"
    documented = {
        opt: (_number(lo), _number(hi))
        for opt, lo, hi in re.findall(r"`(--[a-z-]+)` ([-−\d.,]+)\.\.([-−\d.,]+)", sentence.group(1))
    }
    in_code = {opt: (lo, hi) for opt, _name, _unit, lo, hi in RANGES if opt.startswith("--")}
    assert documented == in_code


# (what docs/align.md says, as a regex whose group is the number; the constant; scale: page -> code)
ALIGN_CONSTANTS = [
    (r"reaches ([\d.]+) \(`AlignOptions\.min_confidence`\)", ("align.options", "AlignOptions"), 1.0),
    (
        r"also looked at ([\d.]+) s past `--max-offset-ms` \(`align\.aligner\.BEYOND_RANGE_S`\)",
        ("align.aligner", "BEYOND_RANGE_S"),
        1.0,
    ),
    (
        r"more than half \(`align\.grid\.MOSTLY_INTERPOLATED_SHARE`",
        ("align.grid", "MOSTLY_INTERPOLATED_SHARE"),
        None,
    ),
    (
        r"more than ([\d.]+) % \(`align\.clipping\.CLIPPED_AUDIO_SHARE`\)",
        ("align.clipping", "CLIPPED_AUDIO_SHARE"),
        0.01,
    ),
    (
        r"quieter than [−-]([\d.]+) dBFS \(`align\.aligner\.QUIET_SPEECH_DBFS`",
        ("align.aligner", "QUIET_SPEECH_DBFS"),
        -1.0,
    ),
    (r"more than ([\d.]+) s \(`align\.evidence\.PAIRED_SLACK_S`", ("align.evidence", "PAIRED_SLACK_S"), 1.0),
    (
        r"more than ([\d.]+) s \(`capture\.paired\.LENGTH_MISMATCH_S`",
        ("capture.paired", "LENGTH_MISMATCH_S"),
        1.0,
    ),
    (
        r"speech level of [−-]([\d.]+) dBFS \(`align\.vad\.VAD_LEVEL_DBFS`",
        ("align.vad", "VAD_LEVEL_DBFS"),
        -1.0,
    ),
    (r"high-pass at ([\d.]+) Hz \(`align\.resample\.HIGHPASS_HZ`", ("align.resample", "HIGHPASS_HZ"), 1.0),
    (
        r"more than ([\d.]+) dB below the loudest \(`IDLE_CHANNEL_DB`",
        ("align.resample", "IDLE_CHANNEL_DB"),
        1.0,
    ),
    (
        r"more than ([\d.]+) dB below the loudest of them \(`CANCELLED_MIX_DB`",
        ("align.resample", "CANCELLED_MIX_DB"),
        1.0,
    ),
]


@pytest.mark.parametrize(
    "pattern, where, scale", ALIGN_CONSTANTS, ids=[w[1] for _p, w, _s in ALIGN_CONSTANTS]
)
def test_align_constants_named_on_the_page_have_its_values(pattern, where, scale):
    import importlib

    page = _page("align.md")
    m = re.search(pattern, page)
    assert m, f"docs/align.md no longer says {pattern!r}"
    module, name = where
    value = getattr(importlib.import_module(module), name)
    if name == "AlignOptions":
        value = value().min_confidence
    if scale is None:  # "more than half"
        assert value == 0.5
    else:
        assert math.isclose(float(m.group(1)) * scale, value), (name, m.group(1), value)


def test_viewer_option_ranges_match_the_parser(capsys):
    from viewer.cli import build_parser

    page = _page("viewer.md")
    ranges = dict(re.findall(r"`((?:render|stream) --[a-z-]+)` ([\d.]+\.\.[\d.]+)", page))
    assert set(ranges) == {"render --size", "stream --speed"}, ranges
    parser = build_parser()
    base = {"render": ["render", "t.csv", "-o", "x.png"], "stream": ["stream", "t.csv", "--to", "h:1"]}

    def accepted(cmd: str, option: str, value: str) -> bool:
        try:
            parser.parse_args([*base[cmd], option, value])
        except SystemExit as exc:
            assert exc.code == 2
            return False
        return True

    for key, text in ranges.items():
        cmd, option = key.split()
        lo, hi = (_number(v) for v in text.split(".."))
        cast = int if lo.is_integer() and hi.is_integer() else float
        assert accepted(cmd, option, str(cast(lo))) and accepted(cmd, option, str(cast(hi))), key
        step = 1 if cast is int else lo / 2
        assert not accepted(cmd, option, str(cast(lo - step))), key
        assert not accepted(cmd, option, str(cast(hi + step))), key
    capsys.readouterr()


def test_viewer_report_outlier_thresholds_match_viewer_report():
    from viewer import report

    page = _page("viewer.md")
    m = re.search(
        r"offset confidence below ([\d.]+), \|offset\| above (\d+) ms, align flags, under (\d+)% usable "
        r"frames, or a mouth channel's 95th percentile more than ([\d.]+) robust deviations \(and ([\d.]+)\)",
        page,
    )
    assert m, "docs/viewer.md lost its list of the report's outlier rules"
    conf, offset_ms, usable_pct, z, gap = (float(g) for g in m.groups())
    assert conf == report.MIN_CONFIDENCE
    assert math.isclose(offset_ms / 1000, report.MAX_OFFSET_S)
    assert math.isclose(usable_pct / 100, report.MIN_USABLE)
    assert z == report.ROBUST_Z
    assert gap == report.MIN_LEVEL_GAP
    limit = re.search(r"`--limit N` \(default (\d+)", page)
    assert limit and int(limit.group(1)) == report.gather.__defaults__[-1]


def test_simulate_limits_match_the_simulator():
    from capture.simulate.artifacts import ARTIFACT_NAMES
    from capture.simulate.session import MAX_SECONDS, MAX_TAKES, SAMPLE_RATES

    page = _page("simulate.md")
    takes = re.search(r"N takes in all \(1\.\.([\d,]+) per run\)", page)
    seconds = re.search(r"each about S seconds \(2\.\.(\d+)\)", page)
    assert takes and seconds
    assert _number(takes.group(1)) == MAX_TAKES
    assert _number(seconds.group(1)) == MAX_SECONDS
    rates = re.search(r"--sample-rate ([\d|]+)\]", page)
    assert rates and tuple(int(r) for r in rates.group(1).split("|")) == tuple(SAMPLE_RATES)
    without = re.search(r"`--without` switches capture artifacts off: `([^`]+)`", page)
    assert without
    assert [w.strip() for w in without.group(1).split(",")] == [n for n in ARTIFACT_NAMES if n != "all"]


def test_simulate_and_align_json_fields_are_the_documented_ones(tmp_path):
    """`s2a-capture simulate --json` and a real align report of a clean simulated take hold exactly the
    fields docs/simulate.md and docs/align.md list (align.md's conditional ones,
    `audio_mix`, `audio_dc` and `warnings`, do not appear for such a take)."""
    page = _page("align.md")
    section = re.search(
        r"## Report \(`--json`, one line per take\) `([^`]+)`; each `segment_list` entry holds `([^`]+)`",
        page,
    )
    assert section, "docs/align.md lost its list of report fields"
    top = {re.sub(r"\s*\(.*", "", f).strip() for f in re.split(r",\s*(?![^()]*\))", section.group(1))}
    entry = {f.strip() for f in section.group(2).split(",")}
    level = set(re.search(r"audio_level \(([^)]+)\)", section.group(1)).group(1).replace(" ", "").split(","))

    def run(*args: str) -> str:
        done = subprocess.run(args, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        return done.stdout

    sim = run(
        *(str(BIN / "s2a-capture"), "simulate", "-o", str(tmp_path / "sim"), "--seconds", "4"),
        *("--without", "all", "--json"),
    )
    fields = re.search(r"with `--json` one line on stdout with `([^`]+)`", _page("simulate.md"))
    assert fields, "docs/simulate.md lost its list of the --json summary's fields"
    (summary,) = [json.loads(line) for line in sim.splitlines()]
    assert list(summary) == [f.strip() for f in fields.group(1).split(",")]
    run(str(BIN / "s2a-capture"), "import", str(tmp_path / "sim"), "-o", str(tmp_path / "raw"))
    out = run(
        sys.executable,
        "-m",
        "align",
        str(tmp_path / "raw"),
        "-o",
        str(tmp_path / "al"),
        "--vad",
        "none",
        "--json",
    )
    (report,) = [json.loads(line) for line in out.splitlines()]
    assert set(report) == top
    assert set(report["audio_level"]) == level
    assert report["segment_list"] and all(set(s) == entry for s in report["segment_list"])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
