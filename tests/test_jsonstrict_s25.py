"""Names whose bytes are not UTF-8 in every stage's output: its JSON lines are strict JSON (the name as
messages show it, ``caf\\xe9\\xff``, its bytes in base64 beside it under ``<key>_b64``), where they held
lone surrogates (``"\\udce9\\udcff"``) that jq and JavaScript mangle and a strict encoder refuses; a
result line printed to a strict stdout (a UTF-8 locale's) naming one is no traceback after the work was
done. Real command lines in subprocesses, on folders named ``caf\\xe9\\xff``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT
from live_helpers import Listener, synthetic_take
from test_trainuse_s25 import _strict_records

from capture import read_take
from capture.command import named
from capture.replay import replay_take

_ODD = b"caf\xe9\xff"  # Latin-1 bytes and one that is never UTF-8
SHOWN = "caf\\xe9\\xff"  # as messages and the JSON lines show it


def _odd(folder: Path, suffix: str = "") -> Path:
    """``folder/caf\\xe9\\xff<suffix>``, its name not UTF-8."""
    return Path(os.fsdecode(bytes(folder) + b"/" + _ODD + suffix.encode()))


def _stage(module: str, *args, strict_stdout: bool = False) -> subprocess.CompletedProcess:
    """``python -m module ARGS``, its output as bytes; ``strict_stdout``: stdout refusing surrogates, as a
    UTF-8 locale's does (C.UTF-8 lets them through as bytes)."""
    env = {**os.environ, "PYTHONIOENCODING": "utf-8:strict"} if strict_stdout else None
    proc = subprocess.run(
        [sys.executable, "-m", module, *map(str, args)], capture_output=True, cwd=ROOT, env=env, timeout=300
    )
    assert proc.returncode == 0 and b"Traceback" not in proc.stderr, proc.stderr.decode(errors="replace")
    return proc


def _lines(module: str, *args) -> list[dict]:
    """The JSON lines of ``module args --json``, each checked to be strict (``_strict_records``)."""
    return _strict_records(_stage(module, *args, "--json").stdout)


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> tuple[Path, dict[str, bytes]]:
    """A folder named ``caf\\xe9\\xff``: a simulated take in ``sim``, imported to ``takes``, aligned to
    ``aligned``, built into dataset ``ds``; and each command's stdout with ``--json``."""
    folder = _odd(tmp_path_factory.mktemp("jsonstrict"))
    folder.mkdir()
    commands = {
        "simulate": ("capture", "simulate", "-o", folder / "sim", "--seconds", 2, "--mov"),
        "import": ("capture", "import", folder / "sim", "-o", folder / "takes"),
        "align": ("align", folder / "takes", "-o", folder / "aligned", "--vad", "none"),
        "build": ("dataset", "build", folder / "aligned", "-o", folder / "ds"),
    }
    return folder, {name: _stage(*args, "--json").stdout for name, args in commands.items()}


@pytest.fixture(scope="module")
def odd(made) -> Path:
    return made[0]


@pytest.mark.parametrize(
    "command, key, folder",
    [
        ("simulate", "path", "sim"),
        ("import", "path", "takes"),
        ("align", "path", "takes"),
        ("build", "dataset", "ds"),
    ],
)
def test_pipeline_lines_name_the_folder_as_shown_with_its_bytes(made, command, key, folder):
    odd, stdout = made
    (record,) = _strict_records(stdout[command])
    assert record[key].startswith(f"{odd.parent}/{SHOWN}/{folder}")
    assert named(record, key).startswith(str(odd / folder)) and Path(named(record, key)).exists()


def test_capture_info_export_csv_replay_and_remote_lines_are_strict(odd, tmp_path):
    take = next((odd / "takes").iterdir())
    (info,) = _lines("capture", "info", odd / "takes")
    assert info["path"] == f"{odd.parent}/{SHOWN}/takes" and named(info, "path") == str(odd / "takes")
    (csv,) = _lines("capture", "export-csv", take, "-o", odd / "x.csv")
    assert named(csv, "path") == str(odd / "x.csv") and (odd / "x.csv").is_file()
    (sent,) = _lines("capture", "replay", take, "--to", "127.0.0.1:9", "--audio-out", odd / "replay.wav")
    assert sent["audio_out"].endswith(f"{SHOWN}/replay.wav") and named(sent, "audio_out") == str(
        odd / "replay.wav"
    )
    phone = os.fsdecode(b"phone\xff")  # refused as it is resolved: one JSON line with its error
    proc = subprocess.run(
        [sys.executable, "-m", "capture", "remote", phone, "battery", "--json", "--timeout", "1"],
        capture_output=True,
        cwd=ROOT,
        timeout=120,
    )
    assert proc.returncode == 1 and b"Traceback" not in proc.stderr, proc.stderr
    (failed,) = _strict_records(proc.stdout)
    assert failed["phone"] == "phone\\xff:8000" and named(failed, "phone") == f"{phone}:8000"


def test_dataset_validate_and_stats_lines_are_strict(odd):
    for command in ("validate", "stats"):
        (record,) = _lines("dataset", command, odd / "ds")
        assert record["dataset"] == f"{odd.parent}/{SHOWN}/ds" and named(record, "dataset") == str(odd / "ds")


def test_viewer_lines_are_strict(odd):
    csv = next(p for p in (odd / "sim").glob("*/*.csv") if p.name != "frame_log.csv")
    short = odd / "short.csv"
    short.write_text("".join(csv.read_text().splitlines(keepends=True)[:6]))
    (render,) = _lines("viewer", "render", short, "-o", odd / "r.png")
    assert named(render, "input") == str(short) and named(render, "output") == str(odd / "r.png")
    (plot,) = _lines("viewer", "plot", short, "-o", odd / "p.png")
    assert plot["output"].endswith(f"{SHOWN}/p.png") and (odd / "p.png").is_file()
    (face,) = _lines("viewer", "export-face", "-o", odd / "face.glb")
    assert named(face, "output") == str(odd / "face.glb") and (odd / "face.glb").is_file()


def test_listen_and_recover_lines_of_a_folder_named_not_utf8_are_strict(tmp_path):
    out = _odd(tmp_path, "_live")
    listener = Listener(out)
    replay_take(synthetic_take(120, seed=2), "127.0.0.1", listener.port, speed=4.0)
    lines, err, code = listener.stop()
    assert code == 0 and len(lines) == 1, err
    for record in lines:  # read from text by the helper: strict once it encodes as UTF-8
        json.dumps(record, ensure_ascii=False).encode("utf-8")
    for record in [*lines, *_lines("capture", "recover", out, "--all")]:
        assert record["path"].startswith(f"{tmp_path}/{SHOWN}_live/"), record
        assert read_take(named(record, "path")).time.size == record["frames"] > 0


@pytest.mark.parametrize(
    "module, args",
    [
        ("capture", ["info", "{odd}/takes"]),
        ("dataset", ["build", "{odd}/aligned", "-o", "{odd}/ds2"]),
        ("dataset", ["validate", "{odd}/ds"]),
        ("dataset", ["stats", "{odd}/ds"]),
    ],
)
def test_result_lines_naming_a_folder_not_utf8_on_a_strict_stdout(odd, module, args):
    """The line naming the folder was a traceback (UnicodeEncodeError) once the work was done."""
    proc = _stage(module, *(a.format(odd=odd) for a in args), strict_stdout=True)
    assert f"{SHOWN}/".encode() in proc.stdout
