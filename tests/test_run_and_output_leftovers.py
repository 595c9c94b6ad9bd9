"""Leftovers of the viewer's output, the train command line and the dataset build: a render that locked
the video the render before it had just renamed into place, an ``-o`` that is a hard link to an input,
an audio file whose name begins with ``-``, a run whose best.pt is damaged while its last.pt is good,
and a raw take the build aligned that fails after alignment."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import soundfile as sf
from conftest import run_cli, run_here
from dataset_helpers import make_aligned_take, write_aligned_set
from test_review_viewer_unseen import _short_csv
from test_train_pipeline import TINY

import capture.file_lock
import viewer.output
import viewer.render
from capture import Audio, write_take
from capture.file_lock import try_lock
from capture.mov import write_reference_mov
from dataset import BuildOptions, build_dataset
from dataset.splits import SplitRule
from train.cli import build_parser
from train.config import resolve_config
from train.fit import fit

# ------------------------------------------------------------------------ a render's partial file


def _finishing_first(monkeypatch, tmp, out) -> None:
    """Between a render's opening of ``tmp`` and its lock, the render before it finishes: it renames
    ``tmp`` into place as ``out`` (and releases its lock). The one lock taken then is a real ``flock``."""
    renamed = []

    def lock_after_the_rename(fd: int, shared: bool = False) -> bool:
        if not renamed:
            os.rename(tmp, out)
            renamed.append(out)
        return try_lock(fd, shared)

    monkeypatch.setattr(capture.file_lock, "try_lock", lock_after_the_rename)


def _locked_by_another(path) -> bool:
    """Whether a lock is held on the file at ``path`` (none there: False; PyAV creates its output file
    only once it writes)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        return not try_lock(fd)
    finally:
        os.close(fd)


def test_a_partial_file_renamed_between_its_open_and_its_lock_is_locked_anew(tmp_path, monkeypatch):
    """A render that opened ``.NAME.partial.mp4`` just as the render before it renamed that file into
    place locked the finished video's inode, and wrote its frames into a new partial file no lock
    guarded (a third render would write into it too). It now locks the file at the partial path."""
    out, tmp = tmp_path / "take.mp4", tmp_path / ".take.mp4.partial.mp4"
    tmp.write_bytes(b"the first render's video")
    _finishing_first(monkeypatch, tmp, out)
    fd = viewer.output.lock_partial(tmp, out)
    try:
        assert os.fstat(fd).st_ino == os.stat(tmp).st_ino  # the partial file is the one locked
        assert _locked_by_another(tmp) and not _locked_by_another(out)
        assert out.read_bytes() == b"the first render's video"
    finally:
        os.close(fd)


def test_write_mp4_writes_its_frames_into_a_locked_partial_file_after_that_race(tmp_path, monkeypatch):
    out, tmp = tmp_path / "take.mp4", tmp_path / ".take.mp4.partial.mp4"
    tmp.write_bytes(b"the first render's video")
    _finishing_first(monkeypatch, tmp, out)
    guarded = []

    def frame(k: int) -> np.ndarray:
        guarded.append(_locked_by_another(tmp))
        return np.zeros((16, 16, 3), np.uint8)

    viewer.render.write_mp4(out, frame, 2, 30.0, None)
    assert guarded == [True, True]


def test_an_output_that_is_a_hard_link_to_the_speech_read_is_written_and_the_speech_kept(samples, tmp_path):
    """``-o`` naming another name (a hard link) of the user's clip given as ``--audio`` was refused as if
    it were the clip: the render is renamed over that name, so the clip keeps its content under its
    own name (said in a note). The clip's own name, however spelled, is still refused."""
    t = np.arange(8000) / 16000
    tone = Audio((8000 * np.sin(2 * np.pi * 440 * t)).astype(np.int16)[:, None], 16000, "PCM_16")
    clip = write_reference_mov(tmp_path / "clip.mp4", 60, 4, tone, size=(16, 16))
    before = clip.read_bytes()
    link = tmp_path / "render.mp4"
    os.link(clip, link)
    csv = _short_csv(samples, tmp_path / "take")
    proc = run_here("viewer", "render", csv, "--audio", clip, "-o", link, "--size", 16)
    assert proc.returncode == 0, proc.stderr
    note = (
        f"note: {link} is a hard link to the speech of {csv} ({clip}): the render replaces it with a new file"
    )
    assert note in proc.stderr, proc.stderr
    assert clip.read_bytes() == before and clip.stat().st_nlink == 1
    assert not os.path.samefile(clip, link) and link.stat().st_size > 0
    proc = run_here("viewer", "render", csv, "--audio", clip, "-o", tmp_path / "." / "clip.mp4", "--size", 16)
    assert proc.returncode == 1 and "read by this command" in proc.stderr, proc.stderr


# ------------------------------------------------------------------------ s2a-train's command line


def test_an_audio_file_named_with_a_leading_dash_gets_told_how_to_give_it(tmp_path, capsys):
    """``s2a-train predict RUN -d.wav`` said only "the following arguments are required: audio" (or
    "unrecognized arguments: -d.wav"): argparse takes the name for an option."""
    proc = run_cli("train", "predict", tmp_path / "run", "-d.wav", "-o", tmp_path / "out.csv")
    assert proc.returncode == 2
    hint = "(-d.wav is taken for an option: for a file of that name, write ./-d.wav, or -- -d.wav after the "
    hint += "options)"
    assert proc.stderr.splitlines()[-1].endswith("required: audio " + hint), proc.stderr
    parser = build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["predict", "RUN", "a.wav", "-d.wav", "-o", "x.csv"])
    assert (
        capsys.readouterr().err.splitlines()[-1] == f"s2a-train: error: unrecognized arguments: -d.wav {hint}"
    )
    for words in (["RUN", "./-d.wav", "-o", "x.csv"], ["RUN", "-o", "x.csv", "--", "-d.wav"]):  # the advice
        assert [str(a) for a in parser.parse_args(["predict", *words]).audio] == ["-d.wav"]
    with pytest.raises(SystemExit):  # an option's value
        parser.parse_args(["predict", "RUN", "a.wav", "--ppg-model", "-m.pt", "-o", "x.csv"])
    assert capsys.readouterr().err.endswith("write ./-m.pt, or --ppg-model=-m.pt)\n")
    assert (
        parser.parse_args(["predict", "RUN", "a.wav", "--ppg-model=-m.pt", "-o", "x"]).ppg_model.name
        == "-m.pt"
    )
    for known in (["--ppg=m.pt"], ["-ox.csv"], ["-1.5"]):  # options (and a number) get no such hint
        with pytest.raises(SystemExit):
            parser.parse_args(["predict", "RUN", *known])
        assert "taken for an option" not in capsys.readouterr().err


@pytest.mark.parametrize(
    "stage, words",
    [
        ("capture", ["import", "-x.csv", "-o", "out"]),
        ("capture", ["info", "-x.csv"]),
        ("align", ["-x", "-o", "out"]),
        ("dataset", ["build", "a", "-x.csv", "-o", "ds"]),
        ("dataset", ["validate", "-x"]),
        ("viewer", ["render", "-x.csv", "-o", "o.mp4"]),
    ],
)
def test_every_stage_says_how_to_give_a_file_named_with_a_leading_dash(
    stage, words, tmp_path, capsys, monkeypatch
):
    """The same hint from every stage's parser and its subcommands' (``capture.command.StageParser``); a
    file of that name on disk counts as a file name even without an extension (``-x``)."""
    import importlib

    (tmp_path / "-x").write_text("")
    monkeypatch.chdir(tmp_path)
    parser = importlib.import_module(f"{stage}.cli").build_parser()
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(words)
    name = next(w for w in words if w.startswith("-x"))
    assert exc.value.code == 2
    assert capsys.readouterr().err.rstrip().endswith(f"write ./{name}, or -- {name} after the options)")


# ------------------------------------------------------------------------ a damaged best.pt


@pytest.fixture(scope="module")
def ridge_run(tmp_path_factory):
    """Three 2 s takes (t1 validates, t2 tests) and a ridge run on them, whose best.pt is cut in half
    (a copy of its last.pt: ridge writes only that) while last.pt is whole."""
    root = tmp_path_factory.mktemp("best")
    write_aligned_set(root / "takes", count=3, speakers=1, seconds=2.0)
    split = SplitRule("take", 0.1, 0.1, 0, ("take01",), ("take02",))
    build_dataset(
        [root / "takes"], root / "ds", BuildOptions(features=("fbank",), split=split), lambda _m: None
    )
    fit(
        root / "ds",
        root / "run",
        resolve_config(sets=[*TINY, "model='ridge'", "prosody=false"]),
        say=lambda _m: None,
    )
    whole = (root / "run" / "last.pt").read_bytes()
    (root / "run" / "best.pt").write_bytes(whole[: len(whole) // 2])
    audio = make_aligned_take("speech", 1.0).audio
    audio_file = root / "speech.wav"
    sf.write(audio_file, audio.samples, audio.sample_rate)
    return root


@pytest.mark.parametrize("command", ["eval", "predict", "export"])
def test_a_damaged_best_pt_is_named_with_how_to_use_last_pt(ridge_run, command):
    """Each said only that best.pt was damaged; never falling back to last.pt (another model), the
    error now says how to ask for it, and that works."""
    run, out = (
        ridge_run / "run",
        ridge_run / {"eval": "none", "predict": "out.csv", "export": "out.onnx"}[command],
    )
    given = {"eval": ["--data", ridge_run / "ds"], "predict": [ridge_run / "speech.wav", "-o", out]}
    given["export"] = ["-o", out]
    proc = run_here("train", command, run, *given[command])
    assert proc.returncode == 1 and not proc.stdout.strip(), proc.stdout + proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith(f"s2a-train: error: {run / 'best.pt'}: not a readable training checkpoint"), line
    assert line.endswith(
        f"to use the run's last checkpoint instead (the last step's weights, not the best on validation), "
        f"give {run / 'last.pt'} in place of the run folder"
    ), line
    assert not out.exists()
    if command == "predict":
        proc = run_here("train", command, run / "last.pt", *given[command])
        assert proc.returncode == 0 and out.is_file(), proc.stderr


# ------------------------------------------------------------------------ the dataset build


def test_a_raw_take_that_fails_after_the_build_aligned_it_is_named_as_the_user_gave_it(tmp_path):
    """An error in a raw take found once the build had aligned it named its copy under
    ``DS/.work/aligned/<sha>/``, no folder of the user's: it names the take the user gave."""
    take = make_aligned_take("t0", 2.0)
    take.meta.source_kind = "livelink_take_folder"  # as s2a-capture import writes it: not aligned yet
    del take.meta.extra["align"]
    take.audio.samples[8000] = 5000.0  # a damaged sample, kept by align, refused by the build
    write_take(take, tmp_path / "takes")
    proc = run_cli("dataset", "build", tmp_path / "takes", "-o", tmp_path / "ds", "--features", "fbank")
    assert proc.returncode == 1
    line = proc.stderr.strip().splitlines()[-1]
    given = (tmp_path / "takes" / "t0").resolve()
    assert line.startswith(f"s2a-dataset: error: {given}: audio holds a sample of 4983 at 0.500 s"), line
    assert ".work" not in line


# ------------------------------------------------------------------------ info on a listen output folder


def test_info_over_a_listen_folder_skips_the_session_log_with_a_word(tmp_path, sim_take):
    """``s2a-capture info live/*`` met the session's log folder first (``NAME.recording`` sorts before
    ``NAME_Ann_...``) and stopped there with "no takes found", printing nothing of the takes beside it."""
    log = tmp_path / "s1.recording"
    log.mkdir()
    proc = run_cli("capture", "info", log, sim_take, "--json")
    assert proc.returncode == 0, proc.stderr
    assert [json.loads(line)["path"] for line in proc.stdout.splitlines()] == [str(sim_take)]
    assert f"warning: {log}: is a listen session's log folder, not a take" in proc.stderr
    proc = run_cli("capture", "info", log)  # alone: an error that says where the takes are
    assert proc.returncode == 1 and f"s2a-capture recover {log} rebuilds them" in proc.stderr
