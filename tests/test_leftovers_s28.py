"""Leftovers of session 27, each measured on the old code: a key of its own ending in ``_b64`` beside a name
not UTF-8 in one JSON object overwrote its bytes (or they overwrote it); benchmarks/paper.py read the
toolkit's JSON without the names' bytes; align printed a confidence of 0.2951 under a bound of 0.3 as
``0.30`` (and audio 0.9996 s long as ``1.000 s, shorter than 1 s``); a damaged bzip2 member of a take
archive was "cannot unpack member" rather than damaged; a SIGTERM as Python tore its modules down after a
stage command's work ended the process by the signal (-15) instead of with the command's exit code."""

from __future__ import annotations

import base64
import importlib
import json
import os
import signal
import sys
import zipfile

import numpy as np
import pytest
from conftest import ROOT, run_here, run_python
from dataset_helpers import make_aligned_take

from align.aligner import _check_audio, _check_range, _name_best_guess
from align.evidence import Evidence, combine
from align.options import AlignOptions
from capture.errors import InputError, loads_names, shown_against, strict_names
from capture.take import read_meta, read_take, write_take

if str(ROOT) not in sys.path:  # benchmarks/ is not an installed package: import it from the checkout
    sys.path.insert(0, str(ROOT))
paper = importlib.import_module("benchmarks.paper")

CAFE = os.fsdecode(b"caf\xe9")  # a name in Latin-1, as another system's file name gives it


@pytest.mark.parametrize(
    "value",
    [
        {"icon": CAFE, "icon_b64": "aGVsbG8="},  # another tool's field beside a name not UTF-8
        {"icon_b64": "aGVsbG8=", "icon": CAFE},  # the same, the other way round
        {"icon": CAFE, "icon_b64": "Y2Fm6Q=="},  # its own holding the very bytes of the name
        {"icon": CAFE, "icon_b64 (3)": "Y2Fm6Q==", "icon_b64": CAFE},  # its own with a count, a name too
        {"hours": {CAFE: 1.0}, "hours_keys_b64": "mine"},  # a map keyed by names beside a key of its own
        {"a": [{CAFE: 1}], "a_keys": [CAFE]},  # the bytes of both kept under one name, a_keys_b64
        {"runs": [{"take": CAFE, "take_b64": CAFE, "take_b64_b64": "x"}]},
    ],
)
def test_a_key_of_its_own_ending_in_b64_beside_a_name_not_utf8_reads_back(value):
    """Each was read back with one of the two lost: the name as its text, or the other key gone."""
    written = json.dumps(strict_names(value))
    assert "\\udc" not in written, written
    assert loads_names(written) == value, written


def test_another_tool_s_b64_field_beside_a_name_not_utf8_in_a_take_s_meta(tmp_path):
    """meta.json's ``extra`` (what other tools wrote) written and read back, then written again: the
    image's bytes overwrote the name's (``icon`` read back as its text) or the name's the image's."""
    take = make_aligned_take("take00", 1.0, seed=0)
    mine = {"icon": CAFE, "icon_b64": base64.b64encode(b"\x89PNG\r\n\x1a\n").decode()}
    take.meta.extra["other_tool"] = mine
    folder = write_take(take, tmp_path / "a")
    assert "\\udc" not in (folder / "meta.json").read_text(encoding="utf-8")
    assert read_meta(folder).extra["other_tool"] == mine
    assert read_meta(write_take(read_take(folder), tmp_path / "b")).extra["other_tool"] == mine


def test_bytes_kept_with_no_key_of_its_own_keep_their_place():
    assert strict_names({"audio": CAFE}) == {"audio": "caf\\xe9", "audio_b64": "Y2Fm6Q=="}


def test_paper_finds_the_takes_of_a_speaker_not_utf8(tmp_path):
    """``make results`` picks a speaker's takes from their meta.json: the subject was read as its text
    (``caf\\xe9``), no take matched the speaker, and it stopped ("no aligned takes of")."""
    folder = write_take(make_aligned_take("take00", 1.0, subject=CAFE, seed=0), tmp_path / "aligned")
    write_take(make_aligned_take("take01", 1.0, subject="bob", seed=1), tmp_path / "aligned")
    assert paper.takes_of(str(tmp_path / "aligned"), [CAFE]) == [str(folder)]


@pytest.mark.parametrize(
    ("value", "bound", "places", "shown"),
    [(0.2951, 0.3, 2, "0.295"), (0.3049, 0.3, 2, "0.305"), (0.3, 0.3, 2, "0.30"), (0.1, 0.3, 2, "0.10")]
    + [(0.29999, 0.3, 2, "0.29999"), (0.9996, 1.0, 3, "0.9996"), (1.0004, 1.0, 3, "1.0004")],
)
def test_a_figure_reads_on_its_side_of_its_bound(value, bound, places, shown):
    assert shown_against(value, bound, places) == shown


def test_align_names_a_confidence_under_the_bound_as_under_it():
    """0.2951 under ``--min-confidence 0.3`` read "(confidence 0.30)" in both warnings that name it."""
    opts = AlignOptions()
    assert opts.min_confidence == 0.3
    outside = {"best_lag_outside_range_s": 2.0, "outside_confidence": 0.2951}
    content = Evidence("content", 0.4, 0.2951, 0.01, outside)
    decision = combine([Evidence("timecode", 0.0, 0.0, 0.0), content], opts.min_confidence, 0.05)
    warnings: list[str] = []
    _name_best_guess("t", decision, opts, warnings)
    assert _check_range("t", content, decision, 0.0, opts, [], warnings)
    assert len(warnings) == 2 and all("(confidence 0.295)" in w for w in warnings), warnings


def test_audio_just_short_of_a_second_reads_short_of_it():
    """15,993 samples at 16 kHz, 0.99956 s: "audio is 1.000 s long, shorter than 1 s"."""
    take = make_aligned_take("t", 1.0, seed=0)
    with pytest.raises(InputError, match=r"audio is 0\.9996 s long, shorter than 1 s"):
        _check_audio(take, np.zeros(15993, np.float32))


def test_a_damaged_bzip2_member_is_named_damaged(sim_take, tmp_path):
    """bz2 says "Invalid data stream" with an OSError, which read as the disk's: "cannot unpack member"."""
    archive = tmp_path / "take.zip"
    mov = next(sim_take.glob("*.mov"))
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_BZIP2) as z:
        z.write(mov, f"{sim_take.name}/{mov.name}")
        info = z.getinfo(f"{sim_take.name}/{mov.name}")
    data = bytearray(archive.read_bytes())
    middle = info.header_offset + 30 + len(info.filename) + info.compress_size // 2
    data[middle : middle + 64] = bytes(64)  # in its compressed bytes
    archive.write_bytes(bytes(data))
    proc = run_here("capture", "import", archive, "-o", tmp_path / "out")
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    assert proc.returncode == 1 and len(errors) == 1, proc.stderr
    assert f"member {sim_take.name}/{mov.name} is damaged (" in errors[0], errors
    assert "copy the archive again" in errors[0], errors


# This process poses as ``s2a-capture`` and runs ``info NOTHING`` (``stopped``: a SIGTERM as its handler
# begins stops it; else its error ends it); an object of this module sends it a SIGTERM as Python tears
# the module down, after Python has set its handlers back to the default.
AT_TEARDOWN = """
import os, signal, sys
where, *args = sys.argv[1:]
sys.argv = ["s2a-capture", *args]
import capture.cli as cli

if where == "stopped":
    real = cli.cmd_info
    def stopped(a):
        os.kill(os.getpid(), signal.SIGTERM)
        return real(a)
    cli.cmd_info = stopped


class Late:
    def __del__(self):
        sys.__stderr__.write("signalled\\n")
        sys.__stderr__.flush()
        os.kill(os.getpid(), signal.SIGTERM)


late = Late()
sys.exit(cli.main())
"""


@pytest.mark.parametrize(("where", "code"), [("over", 1), ("stopped", 143)])
def test_a_sigterm_as_python_tears_down_keeps_the_exit_code(tmp_path, where, code):
    proc = run_python(AT_TEARDOWN, where, "info", str(tmp_path / "none"), timeout=300)
    assert "signalled" in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert ("s2a-capture: error: " in proc.stderr) == (where == "over"), proc.stderr
    assert proc.stderr.count("terminated (SIGTERM)") == (where == "stopped"), proc.stderr


def test_a_program_s_own_sigterm_handling_at_exit_is_left_alone():
    """Outside a stage command's own process nothing changes: the default ends it by the signal."""
    code = "import os, signal, capture.command\nimport atexit\n"
    code += "atexit.register(lambda: os.kill(os.getpid(), signal.SIGTERM))\n"
    proc = run_python(code, timeout=120)
    assert proc.returncode == -signal.SIGTERM, (proc.returncode, proc.stderr)
