"""Names whose bytes are not UTF-8 in JSON: two keys of a map shown alike (``a\\xff`` the text and the byte)
were merged into one, the other lost; a map keyed by names inside a list kept no bytes of its keys; the
manifest and the shards' per-sample JSON stored such a speaker as a lone surrogate (``"\\udce9"``), which
jq and other readers mangle or refuse. And a second SIGTERM as a command whose work is over ends: after a
SIGTERM that stopped it, it was let go as if it were the first. Real files, real command lines in
subprocesses."""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT
from dataset_helpers import make_aligned_take

import capture.command as command
from capture.errors import names_restored, strict_names
from capture.take import read_meta, write_take
from dataset.manifest import load_manifest, read_manifest
from dataset.shards import ShardReader, decode_json_object

_CAFE = b"caf\xe9"  # a speaker named in Latin-1, as another system's file name gives it
SPEAKER = os.fsdecode(_CAFE)


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode()


def test_two_keys_shown_alike_are_both_kept():
    """``a\\xff`` as text (a backslash, x, f, f) and ``a`` then the byte 0xff: one key was left."""
    byte, text = os.fsdecode(b"a\xff"), "a\\xff"
    for hours in ({byte: 1.0, text: 2.0}, {text: 2.0, byte: 1.0}):
        record = json.loads(json.dumps(strict_names({"hours": hours})))
        assert len(record["hours"]) == 2 and record["hours"][text] == 2.0, record
        assert list(record["hours_keys_b64"].values()) == [_b64(b"a\xff")], record
        assert command.named_keys(record, "hours") == {byte: 1.0, text: 2.0}
        assert names_restored(record) == {"hours": hours}


def test_two_keys_shown_alike_keep_the_bytes_of_their_values():
    """A dict keyed by names whose values are names too: each value's bytes beside its own key."""
    first, second = os.fsdecode(b"a\xff"), "a\\xff"
    value = {first: os.fsdecode(b"x\xfe"), second: os.fsdecode(b"y\xfd")}
    record = json.loads(json.dumps(strict_names({"outputs": value})))
    assert len(record["outputs"]) == 4, record
    assert names_restored(record) == {"outputs": value}


def test_a_map_keyed_by_names_inside_a_list_keeps_their_bytes():
    maps = [{"bob": 1}, {SPEAKER: 2, "eve": 3}]
    record = json.loads(json.dumps(strict_names({"per_split": maps})))
    assert record["per_split"] == [{"bob": 1}, {"caf\\xe9": 2, "eve": 3}]
    assert record["per_split_keys_b64"] == [None, {"caf\\xe9": _b64(_CAFE)}]
    assert names_restored(record) == {"per_split": maps}


def test_maps_in_a_list_all_utf8_get_no_bytes_beside_them():
    value = {"per_split": [{"bob": 1}, {"Zoë": 2}], "names": ["a", "b"]}
    assert strict_names(value) == value and names_restored(value) == value


def _stage(module: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)], capture_output=True, cwd=ROOT, timeout=600
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A dataset of six 1 s takes (pitch normalised per speaker), half of them of the speaker ``caf\\xe9``,
    half of ``bob``."""
    root = tmp_path_factory.mktemp("namebytes27")
    for i, who in enumerate((SPEAKER, "bob") * 3):
        write_take(make_aligned_take(f"take{i:02d}", 1.0, subject=who, seed=i), root / "takes")
    proc = _stage("dataset", "build", root / "takes", "-o", root / "ds")
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    return root / "ds"


def _strict(raw: bytes) -> object:
    """JSON read as a strict reader does: UTF-8, no lone surrogate (escaped or not)."""
    text = raw.decode("utf-8")
    assert "\\udc" not in text.lower(), text[:200]
    return json.loads(text)


def test_the_manifest_is_strict_json_and_reads_back_the_speaker(dataset):
    data = _strict((dataset / "manifest.json").read_bytes())
    assert {s["speaker"] for s in data["samples"]} == {"caf\\xe9", "bob"}
    assert {s.get("speaker_b64") for s in data["samples"]} == {_b64(_CAFE), None}
    manifest = read_manifest(dataset)
    assert {s["speaker"] for s in manifest["samples"]} == {SPEAKER, "bob"}
    assert set(manifest["normalization"]["pitch"]["speakers"]) == {SPEAKER, "bob"}
    for entry in manifest["stats"].values():
        assert set(entry["hours_per_speaker"]) <= {SPEAKER, "bob"}
    assert "_b64" not in json.dumps(manifest)


def test_the_shards_json_is_strict_and_reads_back_the_speaker(dataset):
    speakers = set()
    for shard in sorted(dataset.glob("*.tar")):
        for _key, members in ShardReader(shard):
            _strict(members["json"])
            speakers.add(decode_json_object(members["json"])["speaker"])
    assert speakers == {SPEAKER, "bob"}


def test_a_dataset_written_before_reads_as_it_did(dataset, tmp_path):
    """A manifest holding the speaker as a lone surrogate (as the toolkit wrote it before) reads back as
    the same name."""
    old = tmp_path / "manifest.json"
    old.write_text(json.dumps(read_manifest(dataset)) + "\n", encoding="utf-8")
    assert "\\udce9" in old.read_text()
    assert load_manifest(old) == read_manifest(dataset)
    assert decode_json_object(json.dumps({"speaker": SPEAKER}).encode()) == {"speaker": SPEAKER}


def test_validate_and_stats_read_the_dataset(dataset):
    for what in ("validate", "stats"):
        proc = _stage("dataset", what, dataset, "--json")
        assert proc.returncode == 0 and b"Traceback" not in proc.stderr, proc.stderr
    record = json.loads(proc.stdout)
    assert set(command.named_keys(record, "hours_per_speaker")) == {SPEAKER, "bob"}


def test_a_take_s_metadata_is_strict_json_and_reads_back_the_subject(tmp_path):
    """meta.json of a take whose subject is not UTF-8 (a CSV named ``MySlate_1_caf\\xe9.csv``)."""
    folder = write_take(make_aligned_take("take00", 1.0, subject=SPEAKER, seed=0), tmp_path)
    data = _strict((folder / "meta.json").read_bytes())
    assert data["subject"] == "caf\\xe9" and data["subject_b64"] == _b64(_CAFE)
    assert read_meta(folder).subject == SPEAKER


def test_training_reads_the_speaker_back_as_the_same_name(dataset, tmp_path):
    """build -> validate -> fit (speaker styles) -> eval: the run's styles are the speakers' names, its
    config.json strict JSON; eval read the manifest's speaker and the shards' alike."""
    run = tmp_path / "run"
    fit = subprocess.run(
        [sys.executable, "-m", "train", "fit", "--data", dataset, "--model", "blstm", "-o", run]
        + ["--max-steps", "2", "--set", "speaker_style=true"],
        capture_output=True,
        cwd=ROOT,
        timeout=600,
    )
    assert fit.returncode == 0, fit.stderr.decode(errors="replace")
    config = _strict((run / "config.json").read_bytes())
    assert names_restored(config)["inputs"]["styles"] == ["bob", SPEAKER]
    proc = _train_eval(run, dataset)
    assert proc.returncode == 0 and b"Traceback" not in proc.stderr, proc.stderr.decode(errors="replace")


def _train_eval(run: Path, dataset: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "train", "eval", run, "--data", dataset],
        capture_output=True,
        cwd=ROOT,
        timeout=600,
    )


# This process poses as ``s2a-capture`` and runs ``info NOTHING``. ``stopped``: a SIGTERM as its handler
# begins stops it; else its work is over, with its error. As it has printed the line that says so, ``SENT``
# more SIGTERMs reach it, each once the one before was handled; then it says ``went on`` if it still runs.
POSING = """
import os, signal, sys, time
where, sent, *args = sys.argv[1:]
sys.argv = ["s2a-capture", *args]
import capture.cli as cli
import capture.command as command

if where == "stopped":
    real = cli.cmd_info
    def stopped(a):
        os.kill(os.getpid(), signal.SIGTERM)
        return real(a)
    cli.cmd_info = stopped


class Signalling:
    def __init__(self, stream):
        self.stream, self.seen, self.sent = stream, False, False
    def write(self, text):
        self.stream.write(text)
        self.seen = self.seen or "error:" in text or "terminated" in text
        if self.seen and text.endswith("\\n") and not self.sent:  # the line written whole
            self.sent = True
            for _ in range(int(sent)):
                handler = signal.getsignal(signal.SIGTERM)
                os.kill(os.getpid(), signal.SIGTERM)
                deadline = time.monotonic() + 60
                while signal.getsignal(signal.SIGTERM) is handler and time.monotonic() < deadline:
                    time.sleep(0.001)
    def __getattr__(self, name):
        return getattr(self.stream, name)


sys.stderr = Signalling(sys.stderr)
code = cli.main()
sys.stderr.stream.write("went on\\n")
sys.exit(code)
"""


@pytest.mark.parametrize(("where", "sent"), [("stopped", 1), ("over", 2)])
def test_a_second_sigterm_as_a_command_ends_ends_it_with_its_line(tmp_path, where, sent):
    """``stopped``: the SIGTERM after the one that stopped the command was let go (it went on). ``over``:
    of two SIGTERMs as its error is printed, the second ended it by the signal, with no line."""
    proc = subprocess.run(
        [sys.executable, "-c", POSING, where, str(sent), "info", str(tmp_path / "none")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    lines = proc.stderr.splitlines()
    assert proc.returncode == 143 and "Traceback" not in proc.stderr, (proc.returncode, proc.stderr)
    assert lines[-1] == "s2a-capture: terminated (SIGTERM)" and lines.count(lines[-1]) == 1, lines
    assert ("s2a-capture: error: " in proc.stderr) == (where == "over"), lines


def test_one_sigterm_as_a_command_ends_is_let_go(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-c", POSING, "over", "1", "info", str(tmp_path / "none")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert proc.returncode == 1 and proc.stderr.splitlines()[-1] == "went on", proc.stderr
