"""Align on paired takes a probe found mishandled: frames placed by a time column re-spaced by index, a
wrong --fps that nobody was told about, and paired audio with silence before the speech (or its start
cut away) kept at offset 0 without a flag. Real files, real command lines."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here

from capture import FrameStatus, Take, read_audio, read_take, write_take
from capture.csv_take import read_livelink_csv

NEUROSYNC = "paired/neurosync-trainer-lite-testset"
FACEGOOD = "paired/facegood-audio2face"


def _reports(proc) -> dict[str, dict]:
    return {r["id"]: r for r in map(json.loads, proc.stdout.splitlines())}


def _timed_take(samples: Path, take_id: str, times: np.ndarray, start_source: str) -> Take:
    """The NeuroSync take (frame i with audio i/60 s) as paired data at 30 fps nominal whose frames sit
    at ``times`` (s from the audio's start): its 60 fps values sampled at those times."""
    take = read_livelink_csv(samples / NEUROSYNC / "testset.csv", take_id)
    truth_t = np.arange(take.time.size) / 60.0
    values = np.stack([np.interp(times, truth_t, take.values[:, c]) for c in range(take.values.shape[1])], 1)
    take = Take(
        take.meta, times, values.astype(np.float32), np.full(times.size, FrameStatus.TRACKED, np.uint8)
    )
    take.meta.source_kind, take.meta.fps, take.meta.csv = "paired_matrix", 30.0, {}
    take.meta.start_timecode = None
    take.attach_audio(read_audio(samples / NEUROSYNC / "audio.wav"), 0.0, start_source)
    return take


def _jaw_error(samples: Path, aligned: Path) -> float:
    """Mean |aligned jawOpen - NeuroSync's jawOpen at the same audio time| over the aligned take."""
    truth = read_livelink_csv(samples / NEUROSYNC / "testset.csv")
    jaw = truth.channel("jawOpen")
    take = read_take(aligned, audio=False)
    start = take.meta.extra["align"]["segment_start_s"]
    at = start + take.time
    return float(np.mean(np.abs(take.channel("jawOpen") - np.interp(at, np.arange(jaw.size) / 60.0, jaw))))


def _align_as_hinted(take: Path, out: Path, offset_s: float) -> tuple[dict, dict]:
    """Align ``take`` with the default range: kept at 0, flagged, with a warning naming ``offset_s``
    outside the range; then again into ``out`` with the ``--max-offset-ms`` the warning gives. Returns
    both reports."""
    first = json.loads(
        run_here("align", take, "-o", out.with_name(out.name + "-first"), "--json", "--vad", "none").stdout
    )
    assert first["offset_s"] == 0.0 and "low_confidence" in first["flags"], first
    (hint,) = [w for w in first["warnings"] if "--max-offset-ms" in w]
    assert float(hint.split("at an offset of ")[1].split(" s,")[0]) == pytest.approx(offset_s, abs=0.02)
    again = run_here(
        "align", take, "-o", out, "--json", "--vad", "none", "--max-offset-ms", hint.rsplit(" ", 1)[1]
    )
    return first, json.loads(again.stdout)


def test_frames_placed_by_a_time_column_keep_their_times(samples, tmp_path):
    """A webcam-like clock (steps of 30-37.8 ms, 29.5 fps on average, for "30 fps") and one running at
    30.8 fps: placed by index (as align did with every paired take) the face drifts by 0.3-0.5 s over
    20 s; start_source paired_time_column keeps the times, and the placement counts as paired data's."""
    dur = 20.25
    steps = np.random.default_rng(0).uniform(0.030, 0.0378, 700)
    clocks = {"jitter": np.concatenate([[0.0], np.cumsum(steps)]), "r308": np.arange(0, dur, 1 / 30.8)}
    takes = tmp_path / "takes"
    for name, times in clocks.items():
        times = times[times < dur]
        write_take(_timed_take(samples, f"{name}_time", times, "paired_time_column"), takes)
        write_take(_timed_take(samples, f"{name}_index", times, "paired_frame_convention"), takes)
    proc = run_here("align", takes, "-o", tmp_path / "aligned", "--json", "--vad", "none", "--jobs", "1")
    assert proc.returncode == 0, proc.stderr
    reports = _reports(proc)
    for name in clocks:
        kept, indexed = reports[f"{name}_time"], reports[f"{name}_index"]
        assert kept["frame_clock"]["clock"] == "timecode" and indexed["frame_clock"]["clock"] == "index"
        placement = [e for e in [kept["chosen"], *kept["alternatives"]] if e["source"] == "timecode"]
        assert placement[0]["confidence"] == 0.4 and placement[0]["uncertainty_s"] == 0.05
        assert kept["offset_source"] == "content" and abs(kept["offset_s"]) < 0.5 / 30, kept
        assert not kept["flags"], kept["flags"]
        error = _jaw_error(samples, tmp_path / "aligned" / f"{name}_time")
        drifted = _jaw_error(samples, tmp_path / "aligned" / f"{name}_index")
        assert error < 0.02 and drifted > 3 * error, (name, error, drifted)


def test_a_wrong_fps_is_a_warning_at_import_and_a_flag_in_align(samples, tmp_path):
    """FACEGOOD's 30 fps frames imported at 29 or 31 fps: the audio is 1.6 s shorter or longer than the
    frames. Import noted it in meta.json only, and align wanted 10 % of the take (4.8 s) to flag it."""
    fg = samples / FACEGOOD
    takes = tmp_path / "takes"
    for fps in (29, 30, 31):
        proc = run_here(
            "capture",
            "import",
            "--matrix",
            fg / "bs_value/bs_value_1114_3_16.npy",
            "--names",
            fg / "bs_names.txt",
            "--fps",
            fps,
            "--audio",
            fg / "wav/1114_3_16.wav",
            "--id",
            f"fg{fps}",
            "-o",
            takes,
        )
        assert proc.returncode == 0, proc.stderr
        warned = [line for line in proc.stderr.splitlines() if "warning:" in line]
        if fps == 30:
            assert not warned, proc.stderr
        else:
            (line,) = warned
            assert line.startswith("s2a-capture: warning: ") and "than the frames: check --fps" in line
    proc = run_here("align", takes, "-o", tmp_path / "aligned", "--json", "--vad", "none", "--jobs", "1")
    assert proc.returncode == 0, proc.stderr
    reports = _reports(proc)
    assert "duration_mismatch" not in reports["fg30"]["flags"] and "warnings" not in reports["fg30"]
    assert reports["fg30"]["offset_source"] == "content" and abs(reports["fg30"]["offset_s"]) < 1 / 30
    for fps in (29, 31):
        rep = reports[f"fg{fps}"]
        assert "duration_mismatch" in rep["flags"], rep["flags"]
        assert any("check the frame rate" in w and "--fps" in w for w in rep["warnings"]), rep["warnings"]
    # Without --json the warning reaches the console.
    proc = run_here("align", takes / "fg29", "-o", tmp_path / "again", "--vad", "none", "--force")
    assert "s2a-align: warning: take fg29: the audio is 1." in proc.stderr, proc.stderr


@pytest.mark.parametrize(
    "name, lead_s",
    [("lead1", 1.0), ("lead2", 2.0), ("cut1", -1.0)],
)
def test_paired_audio_not_cut_to_its_frames_is_flagged(samples, tmp_path, name, lead_s):
    """NeuroSync's pair with 1 or 2 s of silence before the speech, or its first second cut away: the
    pairing convention said offset 0 (confidence 0.4) and limited the search to ±0.75 s, so the take was
    aligned a second or two off without a flag. Now the lengths tell that the audio was not cut to the
    frames: the pairing is no evidence, the search covers the length difference, the take is flagged
    with a warning naming the offset, and aligning again with the range it suggests finds it."""
    x, rate = sf.read(samples / NEUROSYNC / "audio.wav", dtype="float64")
    k = int(abs(lead_s) * rate)
    y = np.concatenate([np.zeros(k), x]) if lead_s > 0 else x[k:]
    wav = tmp_path / f"{name}.wav"
    sf.write(wav, y, rate, subtype="PCM_16")
    csv = samples / NEUROSYNC / "testset.csv"
    takes = tmp_path / "takes"
    args = [csv, "--audio", wav, "--audio-pairing", "frame-index", "-o", takes, "--id", name]
    run_here("capture", "import", *args, check=True)
    first, rep = _align_as_hinted(takes / name, tmp_path / "wide", -lead_s)
    assert first["audio_start_source"] == "paired_frame_convention"
    if abs(lead_s) == 1.0:  # a second of speech moved: content finds it
        assert rep["offset_source"] == "content" and rep["offset_s"] == pytest.approx(-lead_s, abs=0.02)
    else:  # two: the correlation peaks there, barely above a lag a syllable away: kept, flagged, and
        # the warning names that offset and how to use it once the user has checked it
        assert rep["offset_s"] == 0.0 and "low_confidence" in rep["flags"]
        (guess,) = [w for w in rep["warnings"] if "--offset-ms" in w]
        assert "the best, content, puts the offset at" in guess
        ms = guess.rsplit(" ", 1)[1]
        assert float(ms) / 1000 == pytest.approx(-lead_s, abs=0.02)
        given = run_here(
            "align", takes / name, "-o", tmp_path / "given", "--json", "--vad", "none", "--offset-ms", ms
        )
        rep = json.loads(given.stdout)
        assert rep["offset_source"] == "given" and rep["offset_s"] == float(ms) / 1000
        assert "low_confidence" not in rep["flags"] and rep["alternatives"][0]["source"] == "timecode"


def test_a_time_column_that_starts_late_is_named_and_found(samples, tmp_path):
    """A time column starting 1.03 s into the audio (the face really starts with it): the audio falls
    0.95 s short of where the frames end, so the pairing is no evidence and the search must reach that
    far. Before, content looked only ±0.75 s, found a wrong peak at +408 ms (confidence 0.08) and the
    take was flagged without a word; now the warning names +1.030 s and its range finds it."""
    take = _timed_take(samples, "late", np.arange(1218) / 60.0, "paired_time_column")
    take.time, take.meta.fps = take.time + 1.03, 60.0  # NeuroSync's frames, their times 1.03 s late
    write_take(take, tmp_path / "takes")
    _, rep = _align_as_hinted(tmp_path / "takes" / "late", tmp_path / "b", 1.03)
    assert rep["offset_source"] == "content" and rep["offset_s"] == pytest.approx(1.03, abs=0.02), rep
    assert _jaw_error(samples, tmp_path / "b" / "late") < 0.02
