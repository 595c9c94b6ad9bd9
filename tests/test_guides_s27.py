"""The dataset guide's tables name what the code can say: every flag align can raise is in the flag table,
and the check-code table holds exactly ``dataset.qa.CHECKS``, ``(deep)`` on the codes only ``--deep`` runs.
A flag or check added to the code without a line in the guide fails here, as does a guide that marks a
default check deep (``shard_checksum`` was)."""

from __future__ import annotations

import re

from conftest import ROOT

GUIDE = ROOT / "docs" / "guide-dataset.md"


def table_codes(heading: str) -> dict[str, str]:
    """First-cell code of each row of the table after ``heading``: {code: the rest of the first cell}."""
    text = GUIDE.read_text(encoding="utf-8").split(heading, 1)[1]
    rows = {}
    for line in text.splitlines()[1:]:
        if not line.startswith("|"):
            if rows:
                break
            continue
        cell = line.split("|")[1]
        found = re.match(r"\s*`([a-z_]+)`(.*)", cell)
        if found:
            rows[found[1]] = found[2].strip()
    return rows


def test_flag_table_names_every_flag_align_raises():
    sources = "".join(p.read_text(encoding="utf-8") for p in (ROOT / "align").glob("*.py"))
    raised = set(re.findall(r"flags\.append\(\"([a-z_]+)\"\)", sources))
    raised |= set(re.findall(r"\[\"(no_evidence)\"\]", sources))
    assert {"low_confidence", "clipped_audio", "no_evidence"} <= raised, raised  # the search still finds them
    listed = set(table_codes("Flags (the `flags` list"))
    assert raised <= listed, f"align flags missing from the guide's flag table: {sorted(raised - listed)}"


def test_check_table_is_the_checks_with_their_deep_marks():
    from dataset.qa import CHECKS

    listed = table_codes("Every check code (from `CHECKS`")
    assert set(listed) == {c.code for c in CHECKS}
    wrong = [c.code for c in CHECKS if ("(deep)" in listed[c.code]) != c.deep]
    assert not wrong, f"'(deep)' marks that do not match CHECKS: {wrong}"
