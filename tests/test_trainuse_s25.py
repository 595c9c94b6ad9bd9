"""A trainer using ``s2a-train`` on material it had not seen: names whose bytes are not UTF-8 in its JSON
(predict's lines, eval's, compare's lines and compare.json) are strict JSON, the same printable form as
its messages (``caf\\xe9``) with the bytes kept in base64 beside them (``csv_b64``), where they were lone
surrogates (``"\\udce9"``) that jq and JavaScript turn into U+FFFD; a result line naming such a file no
longer dies on a strict stdout; and predict says what it does while it checks long audio for clipping
and measures its bandwidth (silent for 6 s on 30 min). Command lines run as subprocesses on tiny ridge
runs."""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import ROOT
from dataset_helpers import build_take_split, write_aligned_set

_ODD = b"caf\xe9\xff"  # Latin-1 bytes and one that is never UTF-8


def _odd(folder: Path, suffix: str) -> Path:
    """``folder/café\\xff<suffix>``, its name not UTF-8."""
    return Path(os.fsdecode(bytes(folder) + b"/" + _ODD + suffix.encode()))


def _train(*args, strict_stdout: bool = False) -> subprocess.CompletedProcess:
    """``python -m train ARGS`` with its output as bytes (what a reader of the pipe gets). ``strict_stdout``:
    stdout encoded as a UTF-8 locale's is, refusing surrogates (C.UTF-8 lets them through as bytes)."""
    env = dict(os.environ)
    if strict_stdout:
        env["PYTHONIOENCODING"] = "utf-8:strict"
    return subprocess.run(
        [sys.executable, "-m", "train", *map(str, args)], capture_output=True, cwd=ROOT, env=env, timeout=300
    )


def _strict_records(stdout: bytes) -> list[dict]:
    """The JSON lines of ``stdout``, each read from its bytes and checked to be text a strict reader takes
    (no lone surrogate: encoding it as UTF-8 fails on one)."""
    records = [json.loads(line) for line in stdout.splitlines()]
    for r in records:
        json.dumps(r, ensure_ascii=False).encode("utf-8")
    return records


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """Five aligned 2 s takes; a dataset of jawOpen and mouthClose in a folder whose name is not UTF-8,
    one of them and mouthFunnel, a ridge run on each, and a 2 s recording named ``café\\xff.wav``."""
    root = tmp_path_factory.mktemp("trainuse25")
    takes = write_aligned_set(root / "takes", count=5, speakers=2, seconds=2.0)
    build_take_split(takes, _odd(root, "_ds"), channels="jawOpen,mouthClose")
    build_take_split(takes, root / "funnel", channels="jawOpen,mouthClose,mouthFunnel")
    for ds, run in ((_odd(root, "_ds"), _odd(root, "_run")), (root / "funnel", root / "funnel_run")):
        proc = _train("fit", "--data", ds, "--model", "ridge", "-o", run)
        assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    rate = 16000
    t = np.arange(2 * rate) / rate
    voice = 0.3 * np.sin(2 * np.pi * 180 * t) * (0.5 + 0.5 * np.sin(2 * np.pi * 4 * t))
    with open(_odd(root, ".wav"), "wb") as f:  # soundfile refuses the name itself
        sf.write(f, voice, rate, format="WAV", subtype="PCM_16")
    sf.write(root / "plain.wav", voice, rate, subtype="PCM_16")
    return root


def test_predict_json_of_a_file_named_not_utf8_is_strict_and_keeps_its_bytes(work, tmp_path):
    """The lines held ``"caf\\udce9\\udcff.wav"``: jq printed U+FFFD for both bytes, and the CSV written
    could not be found from them."""
    audio = [_odd(work, ".wav"), work / "plain.wav"]
    proc = _train("predict", _odd(work, "_run"), *audio, "-o", tmp_path, "--json")
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    odd, plain = _strict_records(proc.stdout)
    assert odd["audio"].endswith("/caf\\xe9\\xff.wav") and odd["csv"] == f"{tmp_path}/caf\\xe9\\xff.csv"
    assert base64.b64decode(odd["audio_b64"]) == bytes(_odd(work, ".wav"))
    written = Path(os.fsdecode(base64.b64decode(odd["csv_b64"])))
    assert written.is_file() and written.read_bytes().startswith(b"Timecode,")
    assert odd["frames"] == plain["frames"] == 120
    assert plain["csv"] == str(tmp_path / "plain.csv") and "csv_b64" not in plain  # UTF-8: as it was


def test_predict_result_line_naming_a_file_not_utf8_on_a_strict_stdout(work, tmp_path):
    """A UTF-8 locale's stdout refuses surrogates: the line ``OUT.csv: N frames`` was a traceback
    (UnicodeEncodeError) after the CSV had been written."""
    proc = _train("predict", _odd(work, "_run"), _odd(work, ".wav"), "-o", tmp_path, strict_stdout=True)
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    assert b"Traceback" not in proc.stderr
    assert proc.stdout.decode("ascii").strip() == f"{tmp_path}/caf\\xe9\\xff.csv: 120 frames (2.00 s)"


def test_eval_json_of_a_run_and_dataset_named_not_utf8_is_strict(work):
    proc = _train("eval", _odd(work, "_run"), "--data", _odd(work, "_ds"), "--json")
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    (result,) = _strict_records(proc.stdout)
    assert result["run"] == f"{work}/caf\\xe9\\xff_run" and result["dataset"] == f"{work}/caf\\xe9\\xff_ds"
    assert base64.b64decode(result["dataset_b64"]) == bytes(_odd(work, "_ds"))
    assert list(result["per_channel"]) == ["jawOpen", "mouthClose"]


def test_compare_on_a_dataset_of_other_channels_says_so_in_strict_json(work, tmp_path):
    """compare resuming a run trained on another dataset (one of other channels, in a folder named not
    UTF-8) says so in one line; its line and compare.json quoted that folder as lone surrogates."""
    out = tmp_path / "cmp"
    out.mkdir()
    os.symlink(_odd(work, "_run"), out / "ridge")  # the run compare finds and resumes
    proc = _train("compare", "--data", work / "funnel", "-o", out, "--models", "ridge", "--json")
    assert proc.returncode == 1 and b"Traceback" not in proc.stderr
    (row,) = _strict_records(proc.stdout)
    (saved,) = json.loads((out / "compare.json").read_bytes())
    assert row == saved
    json.dumps(saved, ensure_ascii=False).encode("utf-8")
    expected = f"the run was trained on another dataset ({work}/caf\\xe9\\xff_ds), not {work / 'funnel'}"
    assert row["model"] == "ridge" and expected in row["error"] and "its channels differ" in row["error"]
    (line,) = [x for x in proc.stderr.decode().splitlines() if "error:" in x]
    assert line.startswith("s2a-train: error: 1 of 1 systems failed") and expected in line


def test_predict_says_it_checks_the_audio_for_clipping(work, tmp_path):
    """Between the 16 kHz audio and the features, predict read the whole recording twice more (the
    clipping check, then the bandwidth and the level) without a line: 6 s of silence on 30 min."""
    env_interval = {"S2A_PROGRESS_INTERVAL_S": "0"}  # every step says a line at once
    proc = subprocess.run(
        [sys.executable, "-m", "train", "predict", str(work / "funnel_run"), str(work / "plain.wav")]
        + ["-o", str(tmp_path / "plain.csv")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, **env_interval},
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    steps = [line for line in proc.stderr.splitlines() if line.startswith("predict: plain.wav: ")]
    said = " | ".join(steps)
    order = ["16 kHz mono audio", "checking the audio for clipping", "bandwidth and level", "features of"]
    at = [next((i for i, line in enumerate(steps) if part in line), None) for part in order]
    assert None not in at and at == sorted(at), said
    assert any("checking the audio for clipping: done in" in line for line in steps), said


def test_run_config_of_a_dataset_named_not_utf8_is_strict_and_reads_back_as_a_config(work, tmp_path):
    """config.json's ``data`` held ``"\\udce9\\udcff"``; its bytes are now ``data_b64``, which a fit reading
    the file as its ``--config`` leaves aside as it leaves ``data``."""
    config = _odd(work, "_run") / "config.json"
    saved = json.loads(config.read_bytes())
    json.dumps(saved, ensure_ascii=False).encode("utf-8")
    assert saved["data"] == f"{work}/caf\\xe9\\xff_ds"
    assert base64.b64decode(saved["data_b64"]) == bytes(_odd(work, "_ds"))
    proc = _train("fit", "--data", work / "funnel", "--config", config, "-o", tmp_path / "again", "--json")
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    assert json.loads((tmp_path / "again" / "config.json").read_bytes())["data"] == str(work / "funnel")
