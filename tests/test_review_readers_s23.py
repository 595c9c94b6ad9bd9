"""Review of the s23 reader leftovers (5817d03) on inputs built from the documented formats (formats doc §2):
with a channel empty on every row left out, the warning that most frames are damaged quoted that channel's
blank cell, though the rows' own notes no longer name it."""

from __future__ import annotations

import pytest
from test_readers_review_s22 import rows, write_csv

from capture import read_livelink_csv
from capture.channels import CSV_ORDER


def with_cell(line: str, name: str, text: str) -> str:
    cells = line.split(",")
    cells[2 + CSV_ORDER.index(name)] = text
    return ",".join(cells)


# 1. Every row with values damaged in a kept channel (none tracked again once EyeBlinkLeft, blank on every
# row, is left out): bad_values_widespread quoted EyeBlinkLeft's blank cell, with the hint "empty cells?",
# not the damaged channel's text (and its hint "a decimal comma?").
@pytest.mark.parametrize(("text", "hint"), [("n/a", ""), ('"0,5 x"', ": a decimal comma?")])
def test_the_widespread_warning_quotes_a_kept_channel(tmp_path, text, hint):
    lines = [with_cell(with_cell(line, "EyeBlinkLeft", ""), "JawOpen", text) for line in rows(60)]
    take = read_livelink_csv(write_csv(tmp_path / "take.csv", lines))
    assert "EyeBlinkLeft" not in take.meta.channels and not take.valid.any()
    notes = {r["kind"]: r["message"] for r in take.meta.repairs}
    shown = repr(text.strip('"'))
    assert (
        notes["bad_values_widespread"]
        == f"60 of 60 frames have non-numeric values ({shown} in JawOpen on line 2){hint}"
    )
    assert notes["bad_value"].startswith(
        f"non-numeric, non-finite or out-of-range value in JawOpen ({shown})"
    )
