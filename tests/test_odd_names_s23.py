"""Odd file names through the command lines: a relative name with a colon ("take:1.mov", which FFmpeg read
as a protocol), a name that is not UTF-8 (bytes ``x\\xff\\xfe``, held by Python as surrogate escapes, which
C++ libraries refused or crashed on). JSON outputs show such a name as messages do (``x\\xff\\xfe``), its
bytes in base64 under ``<key>_b64`` (``capture.command.named`` reads them back)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from conftest import ROOT, run_cli, run_here, run_python
from dataset_helpers import write_aligned_set
from test_train_pipeline import TINY

from capture.command import named

NOT_UTF8 = os.fsdecode(b"x\xff\xfe")


def _run_in(cwd: Path, module: str, *args: str) -> subprocess.CompletedProcess:
    """``python -m module args`` run in ``cwd``, as a user does who names files relatively."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=300,
    )


@pytest.fixture(scope="module")
def colon_take(sim_take, tmp_path_factory) -> Path:
    """The simulated take folder, its files named ``take:1.*``, without frame_log.csv (its start then comes
    from the .mov's timecode), and a CSV of its first 5 rows (a render of a few frames)."""
    folder = tmp_path_factory.mktemp("colon") / "t"
    shutil.copytree(sim_take, folder)
    (folder / "frame_log.csv").unlink()
    stem = next(folder.glob("*.mov")).stem
    for p in folder.glob(f"{stem}.*"):
        p.rename(folder / f"take:1{p.suffix}")
    rows = (folder / "take:1.csv").read_text().splitlines(keepends=True)
    (folder / "short.csv").write_text("".join(rows[:6]))
    return folder


def test_a_take_folder_with_a_colon_named_mov_imports_from_inside_it(colon_take):
    proc = _run_in(colon_take, "capture", "import", ".", "-o", "../out", "--json")
    assert proc.returncode == 0, proc.stderr  # was: take:1.mov: ... Protocol not found
    (meta,) = colon_take.parent.glob("out/*/meta.json")
    assert json.loads(meta.read_text())["audio"]["start_source"] == "mov_timecode"


def test_render_reads_a_reference_video_named_relatively_with_a_colon(colon_take, monkeypatch):
    monkeypatch.chdir(colon_take)
    proc = run_here("viewer", "render", "short.csv", "-o", "a.png", "--video", "take:1.mov")
    assert proc.returncode == 0, proc.stderr  # was: take:1.mov: video could not be opened
    assert (colon_take / "a.png").stat().st_size > 1000


def test_render_reads_a_reference_video_named_not_utf8(colon_take):
    odd = colon_take / f"{NOT_UTF8}.mov"
    shutil.copyfile(colon_take / "take:1.mov", odd)
    proc = _run_in(colon_take, "viewer", "render", "short.csv", "-o", "b.png", "--video", odd)
    assert proc.returncode == 0, proc.stderr  # was: OpenCV's segmentation fault (-11)
    assert (colon_take / "b.png").stat().st_size > 1000


def test_render_writes_an_mp4_named_relatively_with_a_colon(colon_take, monkeypatch):
    monkeypatch.chdir(colon_take)
    proc = run_here("viewer", "render", "short.csv", "-o", "take:2.mp4")
    assert proc.returncode == 0, proc.stderr  # was: a traceback, ProtocolNotFoundError
    assert (colon_take / "take:2.mp4").stat().st_size > 1000
    assert not list(colon_take.glob(".*partial*"))


def test_align_reads_a_take_in_a_folder_named_not_utf8(sim_take, tmp_path):
    odd = tmp_path / NOT_UTF8
    run_cli("capture", "import", sim_take, "-o", odd / "takes", check=True)
    proc = run_cli("align", odd / "takes", "-o", odd / "aligned", "--vad", "none", "--json")
    assert proc.returncode == 0, proc.stderr  # was: internal error (UnicodeEncodeError: ... surrogates)
    report = json.loads(proc.stdout.splitlines()[0])
    assert named(report, "path") == str(odd / "takes" / sim_take.name)  # the bytes in base64: "path_b64"
    assert list((odd / "aligned").glob("*/meta.json"))


def test_export_writes_onnx_to_a_name_not_utf8(built, tmp_path):
    from train.config import resolve_config
    from train.fit import fit

    run = tmp_path / "run"
    fit(built, run, resolve_config(sets=[*TINY, "model='ridge'"]), say=lambda _m: None)
    out = tmp_path / f"{NOT_UTF8}.onnx"
    proc = run_here("train", "export", run, "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr  # was: a traceback, TypeError from torch's exporter
    assert named(json.loads(proc.stdout), "onnx") == str(out) and out.stat().st_size > 1000


@pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")
def test_ppg_models_named_not_utf8_are_read(tmp_path):
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnxruntime")

    class Tiny(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.proj = torch.nn.Linear(40, 8)

        def forward(self, fbank):
            return torch.softmax(self.proj(fbank), dim=-1)

    takes = write_aligned_set(tmp_path / "takes", count=1, speakers=1, seconds=1.0)
    model = Tiny().eval()
    ts, onnx_path = tmp_path / f"{NOT_UTF8}.ts", tmp_path / f"{NOT_UTF8}.onnx"
    torch.jit.script(model).save(str(tmp_path / "m.ts"))  # torch's writer takes no such name either
    os.rename(tmp_path / "m.ts", ts)
    with warnings.catch_warnings(), open(onnx_path, "wb") as f:
        warnings.simplefilter("ignore")
        torch.onnx.export(
            model,
            (torch.zeros(1, 10, 40),),
            f,
            input_names=["fbank"],
            output_names=["ppg"],
            dynamic_axes={"fbank": {1: "frames"}, "ppg": {1: "frames"}},
            dynamo=False,
        )
    for backend, path in (("torchscript", ts), ("onnx", onnx_path)):
        out = tmp_path / backend
        proc = run_here(
            "dataset",
            "build",
            takes,
            "-o",
            out,
            "--features",
            "energy",
            "--ppg",
            backend,
            "--ppg-model",
            path,
        )
        assert proc.returncode == 0, proc.stderr  # was: not a TorchScript model / not a usable ONNX model


def test_align_reads_the_motion_of_a_video_named_not_utf8(colon_take):
    """align's clap evidence reads the .mov's motion with OpenCV (a subprocess: it crashed)."""
    odd = colon_take / f"{NOT_UTF8}-motion.mov"
    shutil.copyfile(colon_take / "take:1.mov", odd)
    code = "import sys; from align.transient import video_motion; print(len(video_motion(sys.argv[1])))"
    proc = run_python(code, str(odd))
    assert proc.returncode == 0 and proc.stdout.split() == ["132"], (
        proc.stderr
    )  # was: -11, segmentation fault


def test_a_take_named_with_a_newline_imports(tmp_path, samples):
    """A newline in a take's name (a file system allows it) was an AssertionError traceback: the take's
    name split from its variant suffix (``_cal``) with ``.`` that does not match a newline."""
    from capture.csv_take import split_variant

    assert split_variant("a\nb") == ("a\nb", None)
    assert split_variant("a\nb_cal") == ("a\nb", "cal")
    assert split_variant("MySlate_166_iPhone_cal") == ("MySlate_166_iPhone", "cal")
    assert split_variant("take\n") == ("take\n", None)
    csv = tmp_path / "S07\nsecond line.csv"
    shutil.copy(samples / "livelinkface" / "alexdjulin_S07" / "S07-001.csv", csv)
    proc = run_cli("capture", "import", csv, "-o", tmp_path / "out", "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
