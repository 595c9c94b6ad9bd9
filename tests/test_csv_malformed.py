"""Malformed Live Link Face CSVs: each gets a documented repair (recorded in the take's metadata) or a
clear error naming the file and line — never a traceback."""

from __future__ import annotations

import numpy as np
import pytest

from capture import FrameStatus, InputError, read_livelink_csv, read_take, write_take
from tests.conftest import SAMPLES, run_here


def base_lines() -> tuple[str, list[str]]:
    """Header and six consecutive 60 fps rows of the real NeuroSync take."""
    src = SAMPLES / "paired/neurosync-trainer-lite-testset/testset.csv"
    if not src.is_file():
        pytest.skip("real samples not found")
    lines = src.read_text().splitlines()
    return lines[0], lines[1:7]


def set_field(row: str, index: int, value: str) -> str:
    f = row.split(",")
    f[index] = value
    return ",".join(f)


def with_timecode(row: str, tc: str) -> str:
    return set_field(row, 0, tc)


def case(name):
    h, r = base_lines()
    nl = "\n"
    if name == "truncated_last_line":
        return (h + nl + nl.join(r))[:-40].encode()
    if name == "wrong_field_count":
        r[2] = r[2] + ",0.5"
    elif name == "non_numeric":
        r[1] = set_field(r[1], 19, "abc")
    elif name == "nan":
        r[1] = set_field(r[1], 19, "nan")
    elif name == "inf":
        r[1] = set_field(r[1], 19, "-inf")
    elif name == "backwards":
        r[3] = with_timecode(r[3], r[0].split(",")[0])
        r[3], r[4] = r[3], r[4]
    elif name == "duplicate":
        r.insert(3, r[2])
    elif name == "bad_timecode":
        r[2] = with_timecode(r[2], "10:13:39:xx")
    elif name == "blank_line":
        r.insert(2, "")
    elif name == "bad_count":
        r[1] = set_field(r[1], 1, "60")
    elif name == "garbage_row":
        return (
            (h + nl + nl.join(r[:3]) + nl).encode()
            + b"\xff\xfe\x81garbage\n"
            + (nl.join(r[3:]) + nl).encode()
        )
    elif name == "bom":
        return b"\xef\xbb\xbf" + (h + nl + nl.join(r) + nl).encode()
    elif name == "crlf":
        return ("\r\n".join([h, *r]) + "\r\n").encode()
    elif name == "empty":
        return b""
    elif name == "whitespace_only":
        return b"\n \n"
    elif name == "binary":
        return bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8))
    elif name == "header_only":
        return (h + nl).encode()
    elif name == "wrong_header":
        return ("Time,Count,A,B\n" + nl.join(r) + nl).encode()
    elif name == "midnight":
        r = [with_timecode(r[0], "23:59:59:58.000"), with_timecode(r[1], "23:59:59:59.000")]
        r += [with_timecode(r[0], "00:00:00:00.000"), with_timecode(r[1], "00:00:00:01.000")]
    return (h + nl + nl.join(r) + nl).encode()


# name: (frames, {line: repair kind}) for repairs; name: (error fragment, line) for errors
REPAIRED = {
    "truncated_last_line": (5, {7: "truncated_row"}),
    "wrong_field_count": (6, {4: "wrong_fields"}),
    "non_numeric": (6, {3: "bad_value"}),
    "nan": (6, {3: "bad_value"}),
    "inf": (6, {3: "bad_value"}),
    "duplicate": (6, {5: "duplicate_row"}),
    "bad_timecode": (6, {4: "bad_timecode"}),
    "blank_line": (6, {}),
    "bad_count": (6, {3: "bad_count"}),
    "garbage_row": (6, {5: "wrong_fields"}),
    "bom": (6, {1: "bom"}),
    "crlf": (6, {}),
    "midnight": (4, {}),
}
ERRORS = {
    "empty": ("empty", None),
    "whitespace_only": ("empty", None),
    "binary": ("binary", 1),
    "header_only": ("no data rows", None),
    "wrong_header": ("not a Live Link Face CSV", 1),
    "backwards": ("goes back", 5),
}


@pytest.mark.parametrize("name", sorted(REPAIRED))
def test_repairs_are_recorded(tmp_path, name):
    frames, repairs = REPAIRED[name]
    path = tmp_path / f"{name}.csv"
    path.write_bytes(case(name))
    take = read_livelink_csv(path)
    assert take.time.size == frames
    assert {r["line"]: r["kind"] for r in take.meta.repairs} == repairs
    assert np.all(np.diff(take.time) > 0)
    if name in ("non_numeric", "nan", "inf"):
        assert take.frame_status[1] == FrameStatus.BAD_VALUE and not take.valid[1]
        assert np.isnan(take.channel("jawOpen")[1]) and take.valid.sum() == 5
    if name in ("wrong_field_count", "bad_timecode"):
        assert take.count(FrameStatus.DROPPED) == 1  # the dropped row's slot stays on the grid
    if name == "midnight":
        assert np.allclose(np.diff(take.time), 1 / 60)
    # The repairs travel with the take.
    assert read_take(write_take(take, tmp_path / "out")).meta.repairs == take.meta.repairs
    if repairs:
        with pytest.raises(InputError, match="strict"):
            read_livelink_csv(path, strict=True)


@pytest.mark.parametrize("name", sorted(ERRORS))
def test_errors_name_file_and_line(tmp_path, name):
    fragment, line = ERRORS[name]
    path = tmp_path / f"{name}.csv"
    path.write_bytes(case(name))
    with pytest.raises(InputError, match=fragment) as exc:
        read_livelink_csv(path)
    assert exc.value.path == str(path) and exc.value.line == line


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_livelink_csv(tmp_path / "nope.csv")


@pytest.mark.parametrize("name", ["binary", "backwards", "header_only"])
def test_cli_reports_one_line_and_exit_1(tmp_path, name):
    path = tmp_path / f"{name}.csv"
    path.write_bytes(case(name))
    proc = run_here("capture", "import", path, "-o", tmp_path / "out")
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and str(path) in proc.stderr


def test_cli_keeps_going_past_a_bad_file(tmp_path, samples):
    bad = tmp_path / "in" / "bad.csv"
    bad.parent.mkdir()
    bad.write_bytes(case("binary"))
    good = tmp_path / "in" / "good.csv"
    good.write_bytes((samples / "livelinkface/alexdjulin_S07/S07-001.csv").read_bytes())
    proc = run_here("capture", "import", tmp_path / "in", "-o", tmp_path / "out", "--json")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert (tmp_path / "out" / "good").is_dir() and not (tmp_path / "out" / "bad").exists()


def test_cli_usage_error_exits_2(tmp_path):
    proc = run_here("capture", "import")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
