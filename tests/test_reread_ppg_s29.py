"""A reread of the session's alignment-format reading: a file of a format not read that ``--data`` names
twice (also through its folder) is one file, said as one."""

from __future__ import annotations

import pytest

from capture.errors import InputError
from train.alignments import find_alignments


def test_a_phn_named_twice_is_said_as_one_file(tmp_path):
    """The folder and the .phn in it: one .phn, not "a.phn and 1 more"."""
    (tmp_path / "a.phn").write_text("0 3200 h#\n")
    warnings: list[str] = []
    with pytest.raises(InputError):
        find_alignments([tmp_path, tmp_path / "a.phn"], warnings)
    [line] = [w for w in warnings if "TIMIT .phn" in w]
    assert line.startswith(f"{tmp_path / 'a.phn'}: TIMIT .phn alignments are not read"), line
