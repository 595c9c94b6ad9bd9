"""A Live Link Face CSV re-saved by a spreadsheet with tabs between the fields (Excel's "Text (Tab
delimited)", LibreOffice with Tab, Numbers' TSV export), numbers with ``.`` or ``,``, is read as the
app's CSV with one ``separator`` note, as a ``;`` re-save is. A re-save's text is converted once and
read by pyarrow as the app's CSV is; its messages quote the file's own cells; a drop-frame timecode is
one whose own separator before the frames is ``;``."""

from __future__ import annotations

import pytest
from conftest import run_cli
from test_csvsemi_s25 import app_csv, resaved, same_take

from capture import InputError, read_csv_rows, read_livelink_csv
from capture.take import read_take


def tab_note(mark: str) -> dict:
    message = f"re-saved with tabs between the fields and {mark!r} as the decimal point: read so"
    return {"line": 1, "kind": "separator", "message": message}


def tab_resaved(samples, path, *, decimal=",", timecode_decimal=".", drop_frame=False, line_end="\r\n"):
    """The real take re-saved with tabs between the fields (``;`` before the frames: ``drop_frame``)."""
    resaved(app_csv(samples), path, decimal=decimal, timecode_decimal=timecode_decimal, line_end=line_end)
    lines = path.read_bytes().decode().split(line_end)
    out = [lines[0].replace(";", "\t")]
    for line in lines[1:]:
        timecode, _, rest = line.partition(";")
        if drop_frame and timecode:
            timecode = timecode[:8] + ";" + timecode[9:]
        out.append(timecode + ("\t" if rest else "") + rest.replace(";", "\t"))
    path.write_bytes(line_end.join(out).encode())
    return path


@pytest.mark.parametrize(
    "how",
    [
        {"decimal": ",", "timecode_decimal": ","},  # LibreOffice, a German locale
        {"decimal": ",", "timecode_decimal": "."},  # Excel: timecodes kept as text
        {"decimal": ".", "timecode_decimal": ".", "line_end": "\n"},  # Numbers' TSV, an English locale
    ],
)
def test_a_tab_separated_resave_reads_as_the_apps_csv(tmp_path, samples, how):
    clean = read_livelink_csv(app_csv(samples))
    take = read_livelink_csv(tab_resaved(samples, tmp_path / "t.tsv", **how))
    same_take(take, clean)
    new = [r for r in take.meta.repairs if r not in clean.meta.repairs]
    assert new == [tab_note(how["decimal"])]


def test_import_takes_a_tsv_and_strict_mode_refuses_it(tmp_path, samples):
    path = tab_resaved(samples, tmp_path / "S88-001.txt")
    proc = run_cli("capture", "import", path, "-o", tmp_path / "takes")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    same_take(read_take(tmp_path / "takes" / "S88-001"), read_livelink_csv(app_csv(samples)))
    with pytest.raises(InputError, match=r"re-saved with tabs.*read so \(strict mode\)"):
        read_livelink_csv(path, strict=True)


def test_a_tsv_with_both_decimal_marks_is_refused_in_one_line(tmp_path, samples):
    path = tab_resaved(samples, tmp_path / "t.tsv")
    lines = path.read_bytes().split(b"\r\n")
    lines[40] = lines[40].replace(b",", b".")
    path.write_bytes(b"\r\n".join(lines))
    with pytest.raises(InputError, match=r"re-saved with tabs .*both ',' .* and '\.' .*line 41"):
        read_livelink_csv(path)


@pytest.mark.parametrize("line_end", ["\n", "\r\n"])
def test_a_resave_is_read_by_the_fast_parser_and_its_messages_quote_its_own_cells(
    tmp_path, samples, line_end
):
    path = resaved(samples / "livelinkface/alexdjulin_S07/S07-001.csv", tmp_path / "t.csv", line_end=line_end)
    if line_end == "\n":  # pyarrow's rows: the careful parser keeps each row's line
        assert read_csv_rows(path).lines is None
    lines = path.read_bytes().decode().split(line_end)
    cells = lines[5].split(";")
    cells[4] = "1,5E+40"  # a number out of float32's range
    lines[5] = ";".join(cells)
    cells = lines[9].split(";")
    cells[1] = "6,1"
    lines[9] = ";".join(cells)
    path.write_bytes(line_end.join(lines).encode())
    repairs = {r["line"]: r for r in read_csv_rows(path).repairs}
    assert "('1,5E+40')" in repairs[6]["message"] and repairs[6]["kind"] == "bad_value"
    assert "is '6,1'" in repairs[10]["message"] and repairs[10]["kind"] == "bad_count"


@pytest.mark.parametrize("sep", [";", "\t"])
def test_a_drop_frame_timecode_is_one_written_with_its_own_semicolon(tmp_path, samples, sep):
    """``HH:MM:SS:FF,fff`` is the app's timecode with a decimal comma, ``HH:MM:SS;FF,fff`` a drop-frame
    one (quoted in a ``;`` file, as a spreadsheet writes a cell holding its separator)."""
    plain = resaved(app_csv(samples), tmp_path / "plain.csv", timecode_decimal=",")
    assert not read_csv_rows(plain).drop_frame
    if sep == ";":
        text = plain.read_bytes().decode().split("\r\n")
        text[1:] = [f'"{line[:8]};{line[9:].replace(";", chr(34) + ";", 1)}' for line in text[1:] if line]
        dropped = tmp_path / "df.csv"
        dropped.write_bytes(("\r\n".join(text) + "\r\n").encode())
    else:
        dropped = tab_resaved(samples, tmp_path / "df.tsv", timecode_decimal=",", drop_frame=True)
    rows = read_csv_rows(dropped)
    assert rows.drop_frame and rows.seconds_of_day.size == read_csv_rows(plain).seconds_of_day.size
