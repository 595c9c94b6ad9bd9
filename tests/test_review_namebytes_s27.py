"""Review of names not UTF-8 in JSON (test_namebytes_s27): a key ending in ``_b64`` that ``strict_names`` did
not make was read back as the bytes of the key beside it, and dropped: two speakers named ``anna`` and
``anna_b64`` (UTF-8 names) made ``dataset build`` refuse its own manifest (the second speaker's pitch
statistics gone), another tool's ``icon``/``icon_b64`` in a take's meta.json came back as ``icon`` holding
the image's bytes as a name, and a hand-edited ``_b64`` that is no base64 was dropped. And a SIGTERM after
``dataset build`` said a SIGTERM stopped it added a second ``terminated`` line. Real files, real command
lines in subprocesses."""

from __future__ import annotations

import base64
import json
import os

from conftest import run_cli, run_python
from dataset_helpers import make_aligned_take

from capture.errors import loads_names, names_restored, strict_names
from capture.take import read_meta, read_take, write_take
from dataset.manifest import read_manifest

_PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR"  # the first bytes of an image another tool stores in base64


def test_speakers_named_anna_and_anna_b64_build_validate_and_read_back(tmp_path):
    """Both names UTF-8: the toolkit keeps no bytes for them, and reads each back as the speaker it is."""
    for i, who in enumerate(("anna", "anna_b64") * 3):
        write_take(make_aligned_take(f"take{i:02d}", 1.0, subject=who, seed=i), tmp_path / "takes")
    build = run_cli("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds")
    assert build.returncode == 0, build.stderr
    validate = run_cli("dataset", "validate", tmp_path / "ds")
    assert validate.returncode == 0, validate.stdout + validate.stderr
    manifest = read_manifest(tmp_path / "ds")
    assert set(manifest["normalization"]["pitch"]["speakers"]) == {"anna", "anna_b64"}
    assert manifest == json.loads((tmp_path / "ds" / "manifest.json").read_text(encoding="utf-8"))
    stats = run_cli("dataset", "stats", tmp_path / "ds", "--json")
    assert set(json.loads(stats.stdout)["hours_per_speaker"]) == {"anna", "anna_b64"}, stats.stderr


def test_another_tool_s_b64_field_in_a_take_s_meta_is_kept(tmp_path):
    """``extra`` holds what other tools wrote: an image's name and its bytes in base64 read back as they are,
    and so after the take is written again."""
    take = make_aligned_take("take00", 1.0, seed=0)
    mine = {"icon": "icon.png", "icon_b64": base64.b64encode(_PNG).decode()}
    take.meta.extra["other_tool"] = mine
    folder = write_take(take, tmp_path / "a")
    assert read_meta(folder).extra["other_tool"] == mine
    again = write_take(read_take(folder), tmp_path / "b")
    assert read_meta(again).extra["other_tool"] == mine


def test_a_b64_that_is_not_the_bytes_of_the_name_beside_it_is_kept():
    """A hand-edited ``_b64`` (no base64, or the bytes of another name) stays a key of its own, the text
    beside it as it is; bytes that are the name's as ``strict_names`` keeps them are read back as the name."""
    cafe = os.fsdecode(b"caf\xe9")
    for edited in (
        {"speaker": "caf\\xe9", "speaker_b64": "not base64!"},
        {"speaker": "bob", "speaker_b64": "Y2Fm6Q=="},
    ):
        assert loads_names(json.dumps(edited)) == edited
    assert loads_names(json.dumps({"speaker": "caf\\xe9", "speaker_b64": "Y2Fm6Q=="})) == {"speaker": cafe}
    maps = {"hours": {"anna": 1.0}, "hours_keys_b64": {"anna": "YW5uYQ=="}}  # UTF-8 bytes: not strict_names'
    assert names_restored(maps) == maps


def test_names_shown_with_a_count_of_their_own_read_back():
    """A name not UTF-8 ending in `` (3)`` of its own, a key shown alike with `` (2)`` added, in a map inside
    a list inside a map: each read back as the name."""
    own, byte, text = os.fsdecode(b"tak\xe9 (3)"), os.fsdecode(b"a\xff"), "a\\xff"
    value = {"runs": [{"hours": {own: 1.0, text: 2.0, byte: 3.0}, "takes": [own, [byte, "bob"]]}]}
    written = json.dumps(strict_names(value))
    assert "\\udc" not in written and loads_names(written) == value


# This process poses as ``s2a-dataset build``, whose own line (what the build kept) says a SIGTERM stopped it:
# a SIGTERM as the build begins stops it; once its command is over, one more SIGTERM reaches it, and it says
# ``went on`` if it still runs.
STOPPED_BUILD = """
import os, signal, sys, time
sys.argv = ["s2a-dataset", "build", *sys.argv[1:]]
import dataset.cli as cli

def stopped(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(300)  # the SIGTERM's Terminated ends the wait
cli.build_dataset = stopped

code = cli.main()
handler = signal.getsignal(signal.SIGTERM)
os.kill(os.getpid(), signal.SIGTERM)
deadline = time.monotonic() + 60
while signal.getsignal(signal.SIGTERM) is handler and time.monotonic() < deadline:
    time.sleep(0.001)
sys.stderr.write("went on\\n")
sys.exit(code)
"""


def test_a_sigterm_after_build_said_it_was_stopped_ends_it_without_a_second_line(tmp_path):
    """``dataset build`` says its own line when a SIGTERM stops it: the next SIGTERM ends the process
    (it was let go before) with no second ``terminated`` line (it added one)."""
    write_take(make_aligned_take("take00", 1.0, seed=0), tmp_path / "takes")
    proc = run_python(STOPPED_BUILD, str(tmp_path / "takes"), "-o", str(tmp_path / "ds"), timeout=300)
    lines = proc.stderr.splitlines()
    assert proc.returncode == 143 and "Traceback" not in proc.stderr, (proc.returncode, proc.stderr)
    assert len(lines) == 1 and lines[0].startswith("s2a-dataset: terminated (SIGTERM); "), lines
