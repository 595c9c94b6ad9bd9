"""A Live Link Face CSV re-saved by a spreadsheet in a locale with decimal commas (German, French, ...):
``;`` between the fields, ``0,5`` for the numbers, as Excel and LibreOffice write it. Read as the app's
CSV with one ``separator`` note; numbers written with both marks are refused in one line; the app's own
comma-separated CSV is read as before, by pyarrow."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from capture import InputError, read_csv_rows, read_livelink_csv
from capture.take import read_take

SEPARATOR_NOTE = {
    "line": 1,
    "kind": "separator",
    "message": "re-saved with ';' between the fields and ',' as the decimal point: read so",
}


def app_csv(samples: Path) -> Path:
    """The real take with face-lost rows (``<timecode>,0``) among its tracked ones."""
    return samples / "livelinkface/alexdjulin_S88/S88-001.csv"


def resaved(
    source: Path,
    path: Path,
    *,
    decimal: str = ",",
    timecode_decimal: str = ".",
    quote: bool = False,
    bom: bool = False,
    line_end: str = "\r\n",
    trim_zeros: bool = False,
) -> Path:
    """``source`` as a spreadsheet saves it: ``;`` between the fields, numbers with ``decimal``, the
    timecode's sub-frame after ``timecode_decimal``, cells in quotes, a BOM, ``line_end``; ``trim_zeros``:
    numbers as shown (``0,5`` for ``0.5000000000``), as LibreOffice writes its standard format."""
    lines = source.read_text().splitlines()
    out = []
    for number, line in enumerate(lines):
        cells = line.split(",")
        if number:
            cells[0] = cells[0].replace(".", timecode_decimal)
            values = cells[1:]
            if trim_zeros:
                values = [c.rstrip("0").rstrip(".") if "." in c else c for c in values]
            cells[1:] = [c.replace(".", decimal) for c in values]
        out.append(";".join(f'"{c}"' if quote else c for c in cells))
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + (line_end.join(out) + line_end).encode())
    return path


def same_take(take, clean) -> None:
    assert take.meta.channels == clean.meta.channels
    assert np.array_equal(take.time, clean.time)
    assert np.array_equal(take.frame_status, clean.frame_status)
    assert np.array_equal(take.values, clean.values, equal_nan=True)


@pytest.mark.parametrize(
    "how",
    [
        # Excel's "CSV (Trennzeichen-getrennt)": BOM (CSV UTF-8), CRLF, timecodes kept as text
        {"bom": True},
        # ... with the timecode's sub-frame after a comma too, every cell quoted
        {"bom": True, "timecode_decimal": ",", "quote": True},
        # LibreOffice: LF, no BOM, numbers as shown in its standard format
        {"line_end": "\n", "trim_zeros": True},
    ],
)
def test_a_decimal_comma_resave_reads_as_the_apps_csv(tmp_path, samples, how):
    clean = read_livelink_csv(app_csv(samples))
    take = read_livelink_csv(resaved(app_csv(samples), tmp_path / "t.csv", **how))
    same_take(take, clean)
    new = [r for r in take.meta.repairs if r not in clean.meta.repairs]
    assert new == (
        [{"line": 1, "kind": "bom", "message": "UTF-8 byte-order mark before the header ignored"}]
        if how.get("bom")
        else []
    ) + [SEPARATOR_NOTE]


def test_a_semicolon_resave_with_decimal_points_is_read_with_points(tmp_path, samples):
    clean = read_livelink_csv(app_csv(samples))
    take = read_livelink_csv(resaved(app_csv(samples), tmp_path / "t.csv", decimal=".", line_end="\n"))
    same_take(take, clean)
    assert [r for r in take.meta.repairs if r["kind"] == "separator"] == [
        {
            **SEPARATOR_NOTE,
            "message": "re-saved with ';' between the fields and '.' as the decimal point: read so",
        }
    ]


def test_numbers_with_both_decimal_marks_are_refused_in_one_line(tmp_path, samples):
    path = resaved(app_csv(samples), tmp_path / "t.csv")
    lines = path.read_bytes().split(b"\r\n")
    lines[40] = lines[40].replace(b",", b".")  # a row typed in again with points
    path.write_bytes(b"\r\n".join(lines))
    with pytest.raises(
        InputError, match=r"both ',' \('0,.*' on line 2\) and '\.' \('0\..*' on line 41\)"
    ) as err:
        read_livelink_csv(path)
    assert "\n" not in str(err.value) and err.value.line == 41


def test_strict_mode_refuses_the_resave(tmp_path, samples):
    path = resaved(app_csv(samples), tmp_path / "t.csv")
    with pytest.raises(InputError, match=r"re-saved with ';'.*read so \(strict mode\)"):
        read_livelink_csv(path, strict=True)


def test_import_takes_the_resave_as_a_live_link_take(tmp_path, samples):
    path = resaved(app_csv(samples), tmp_path / "S88-001.csv", bom=True)
    proc = run_cli("capture", "import", path, "-o", tmp_path / "takes")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    take = read_take(tmp_path / "takes" / "S88-001")
    same_take(take, read_livelink_csv(app_csv(samples)))
    assert SEPARATOR_NOTE in take.meta.repairs


def test_the_apps_comma_csv_stays_on_pyarrows_path(samples):
    for name in ("alexdjulin_S07/S07-001.csv", "neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"):
        path = samples / "livelinkface" / name
        rows = read_csv_rows(path)
        assert rows.lines is None, path  # pyarrow's rows: the careful parser keeps each row's line
        assert not [r for r in rows.repairs if r["kind"] == "separator"]


def test_a_resaved_header_alone_says_there_are_no_rows(tmp_path, samples):
    """The note of the re-save is no rejected row: the error names what is wrong."""
    path = resaved(app_csv(samples), tmp_path / "t.csv")
    path.write_bytes(path.read_bytes().split(b"\r\n")[0] + b"\r\n")
    with pytest.raises(InputError, match=r"t\.csv: no data rows after the header$"):
        read_livelink_csv(path)
