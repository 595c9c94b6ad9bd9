"""What a probe of ``s2a-dataset`` found and this file keeps fixed: takes naming no speaker split by
speaker (a recording is the assumed speaker, never one of its segments), a channel named twice,
normalisation statistics that validate never checked, messages that named the wrong option or no
take, warnings said twice, malformed align metadata read as absent, samples shorter than a frame and a
NaN neutral pose dropped without a word. Commands run in-process (``run_here``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import run_here
from dataset_helpers import make_aligned_take

from capture import write_take
from dataset import validate

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

QUICK = ("--features", "energy,fbank")  # no pitch tracker where pitch is not the subject


def _segment(take_id: str, recording: str, seed: int, **kw):
    """An aligned segment that align cut from the raw take ``recording``."""
    take = make_aligned_take(take_id, 1.0, seed=seed, **kw)
    take.meta.extra["align"]["parent"] = {"id": recording, "source_kind": "livelink_csv"}
    return take


def _build(takes: Path | list[Path], out: Path, *options: str) -> dict:
    inputs = takes if isinstance(takes, list) else [takes]
    proc = run_here("dataset", "build", *inputs, "-o", out, "--json", *options)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def _refused(proc, *needles: str) -> str:
    """The one-line error of a refused command (its stderr), checked for ``needles``."""
    assert proc.returncode == 1, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def _codes(report, code: str) -> list:
    return [p for p in report.problems if p.code == code]


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("probe")


@pytest.fixture(scope="module")
def takes(root) -> Path:
    """Two aligned takes of two speakers: input for the commands refused before any take is processed."""
    folder = root / "takes"
    for i in range(2):
        write_take(make_aligned_take(f"t{i}", 1.0, subject=f"Spk{i}", seed=i), folder)
    return folder


@pytest.fixture(scope="module")
def segmented(root) -> tuple[Path, dict]:
    """Four recordings naming no speaker, each cut into two segments, split by speaker: a dataset and
    its manifest."""
    folder = root / "segments"
    for r in range(4):
        for s in (1, 2):
            write_take(_segment(f"rec{r}.seg0{s}", f"rec{r}", seed=10 * r + s, subject=None), folder)
    ds = root / "ds_segments"
    options = ("--split-by", "speaker", "--val-fraction", "0.25", "--test-fraction", "0.25")
    _build(folder, ds, *options, "--features", "pitch,energy,fbank")
    return ds, json.loads((ds / "manifest.json").read_text())


# 1. an assumed speaker is a recording, never one of its segments


def test_takes_without_a_speaker_split_by_speaker_keep_each_recording_on_one_side(segmented):
    ds, m = segmented
    split_of = {src["take"]: src["split"] for src in m["sources"]}
    for r in range(4):
        assert split_of[f"rec{r}.seg01"] == split_of[f"rec{r}.seg02"], split_of
    assert {src["speaker"] for src in m["sources"]} == {f"rec{r}" for r in range(4)}
    assert set(m["normalization"]["pitch"]["speakers"]) == {f"rec{r}" for r in range(4)}  # pitch follows
    assert {"train", "val", "test"} == set(split_of.values())
    assert any("each recording (a raw take with the segments" in w for w in m["warnings"])
    assert validate(ds, deep=True).valid


def test_validate_flags_a_recording_in_two_splits_whatever_the_rule(root, monkeypatch):
    # subject-less segments of one recording, built as older builds did: each segment its own speaker
    # (its take id), so a speaker split parted them
    import dataset.build as build

    merge = build._one_spelling_per_speaker

    def speaker_is_take_id(takes):
        for t in takes:
            if t.speaker_assumed:
                t.speaker = t.id
        return merge(takes)

    monkeypatch.setattr(build, "_one_spelling_per_speaker", speaker_is_take_id)
    folder = root / "old_segments"
    write_take(_segment("rec.seg01", "rec", seed=1, subject=None), folder)
    write_take(_segment("rec.seg02", "rec", seed=2, subject=None), folder)
    write_take(make_aligned_take("other", 1.0, subject=None, seed=3), folder)
    ds = root / "ds_old_segments"
    _build(folder, ds, "--split-by", "speaker", "--test", "rec.seg02", "--val-fraction", "0", *QUICK)
    m = json.loads((ds / "manifest.json").read_text())
    assert {src["take"]: src["speaker"] for src in m["sources"]}["rec.seg02"] == "rec.seg02"
    leaks = _codes(validate(ds), "split_leakage")
    assert [p.location for p in leaks] == ["recording rec"], leaks


# 2. a channel named twice


@pytest.mark.parametrize("spec", ["jawOpen,JAWOPEN,jaw_open", "jawOpen,jawOpen"])
def test_a_channel_named_twice_is_refused_naming_the_repeat(takes, root, spec):
    first, second = spec.split(",")[:2]
    proc = run_here("dataset", "build", takes, "-o", root / "ds_twice", "--channels", spec, *QUICK)
    _refused(proc, "--channels names one channel twice", f"{first!r} and {second!r}")


# 4. normalisation statistics checked


@pytest.fixture(scope="module")
def edited(segmented, root):
    """A copy of the segmented dataset with its normalisation and stats edited; validate, then deep."""
    ds = root / "ds_edited"
    shutil.copytree(segmented[0], ds)
    m = json.loads((ds / "manifest.json").read_text())
    channels = m["channels"]
    jaw = channels.index("jawOpen")
    m["normalization"]["animation"]["scale"][jaw] = 0.3
    m["normalization"]["features"]["fbank"]["mean"][0] = 99.0
    m["stats"]["train"]["channels"]["jawOpen"]["mean"] = 5.0
    speaker = sorted(m["normalization"]["pitch"]["speakers"])[0]
    m["normalization"]["pitch"]["speakers"][speaker]["std"] *= 2
    (ds / "manifest.json").write_text(json.dumps(m))
    return validate(ds), validate(ds, deep=True), jaw, speaker


def test_validate_finds_a_scale_that_is_not_a_power_of_two(edited):
    quick, _, jaw, _ = edited
    found = _codes(quick, "normalization_scale")
    assert [p.location for p in found] == [f"manifest.json:normalization.animation.scale[{jaw}]"]
    assert not quick.valid and "not a power of two" in found[0].message


def test_validate_deep_recomputes_normalisation_and_channel_distributions(edited):
    _, deep, jaw, speaker = edited
    assert {p.location for p in _codes(deep, "normalization_mismatch")} == {
        f"manifest.json:normalization.animation.scale[{jaw}]",
        "manifest.json:normalization.features.fbank.mean[0]",
        f"manifest.json:normalization.pitch.speakers.{speaker}.std",
    }
    stats = _codes(deep, "stats_mismatch")
    assert [p.location for p in stats] == ["manifest.json:stats.train.channels.jawOpen.mean"], stats


# 5, 6, 9. messages; warnings once per kept take; a NaN neutral said


@pytest.fixture(scope="module")
def neutral_build(root) -> tuple[Path, dict]:
    """Takes with calibrated neutral poses (one of them NaN for jawOpen), built with --normalization
    neutral from two folders that both hold one flagged and clipped take."""
    for i in range(3):
        take = make_aligned_take(f"n{i}", 1.0, subject=f"s{i}", seed=20 + i, neutral=True)
        if i == 1:
            take.neutral[take.channel_index("jawOpen")] = np.nan
        write_take(take, root / "neutral")
    flagged = make_aligned_take("flagged", 1.0, subject="s0", seed=30, neutral=True)
    flagged.meta.extra["align"] |= {"flags": ["low_confidence", "clipped_audio"], "clipped_audio": 0.01}
    for copy in ("raw_copy", "aligned_copy"):  # as when raw takes and their aligned copies are given
        write_take(flagged, root / copy)
    ds = root / "ds_neutral"
    summary = _build(
        [root / "neutral", root / "raw_copy", root / "aligned_copy"], ds, "--normalization", "neutral", *QUICK
    )
    return ds, summary


def test_a_nan_neutral_pose_is_warned_about_and_neutral_statistics_validate(neutral_build):
    ds, summary = neutral_build
    said = [w for w in summary["warnings"] if "neutral pose" in w]
    assert len(said) == 1 and said[0].startswith("take n1:") and "jawOpen" in said[0], said
    assert validate(ds, deep=True).valid  # percentile offsets and RMS scales recomputed, no false alarm


def test_a_skipped_duplicate_does_not_repeat_its_twins_warnings(neutral_build):
    _, summary = neutral_build
    about = [w for w in summary["warnings"] if w.startswith("take flagged:")]
    assert len(about) == 2, about  # the align flags once, the clipping once
    assert sum("skipped as a duplicate" in w for w in summary["warnings"]) == 1


def test_mixed_frame_rates_name_a_take_of_each_rate(root):
    folder = root / "mixed"
    write_take(make_aligned_take("slow", 1.0, fps=30.0, seed=1), folder)
    write_take(make_aligned_take("fast", 1.0, fps=60.0, seed=2), folder)
    proc = run_here("dataset", "build", folder, "-o", root / "ds_mixed", *QUICK)
    _refused(proc, f"30 fps: {folder / 'slow'}", f"60 fps: {folder / 'fast'}")


@pytest.mark.parametrize(
    "option, value, named",
    [
        ("--shard-mb", "1e-9", "--shard-mb 1e-09 is under one byte"),
        ("--max-sample-s", "0", "--max-sample-s must be a positive number of seconds"),
    ],
)
def test_a_wrong_size_option_is_named_alone(takes, root, option, value, named):
    line = _refused(run_here("dataset", "build", takes, "-o", root / "ds_opt", option, value), named)
    others = {"--shard-mb", "--max-sample-s", "--jobs"} - {option}
    assert not any(o in line for o in others), line


def test_jobs_below_one_is_a_usage_error_as_in_align(takes, root):
    proc = run_here("dataset", "build", takes, "-o", root / "ds_opt", "--jobs", "0")
    assert proc.returncode == 2 and not (root / "ds_opt").exists()
    assert proc.stderr.splitlines()[-1] == "s2a-dataset build: error: argument -j/--jobs: must be at least 1"


def test_pins_that_leave_no_training_take_say_so(takes, root):
    proc = run_here("dataset", "build", takes, "-o", root / "ds_pins", "--test", "t0", "t1", *QUICK)
    _refused(proc, "--val/--test pin all 2 recording(s)", "none is left for the training split")
    proc = run_here(
        "dataset",
        "build",
        takes,
        "-o",
        root / "ds_pins",
        "--split-by",
        "speaker",
        "--test",
        "spk0",
        "SPK1",
        *QUICK,
    )
    _refused(proc, "pin all 2 speaker(s)")  # speakers match in any case, as the build merges them


def test_a_take_pin_in_the_wrong_case_gets_a_hint(takes, root):
    proc = run_here("dataset", "build", takes, "-o", root / "ds_pins", "--test", "T0", *QUICK)
    _refused(proc, "pinned take or speaker 'T0' is not among the inputs", "case included: 't0'?")


def test_assumed_speakers_differing_only_in_case_are_two_and_pinned_exactly(root):
    # subject-less takes: their speakers are the recording ids Take1_raw and take1_raw, two recordings
    folder = root / "case_ids"
    for i, tid in enumerate(("Take1", "take1", "other")):
        write_take(make_aligned_take(tid, 1.0, subject=None, seed=40 + i), folder)
    options = ("--split-by", "speaker", "--test", "Take1_raw", "--val-fraction", "0", "--test-fraction", "0")
    summary = _build(folder, root / "ds_case_ids", *options, *QUICK)
    assert not any("differ only in case" in w for w in summary["warnings"]), summary["warnings"]
    m = json.loads((root / "ds_case_ids" / "manifest.json").read_text())
    split_of = {src["take"]: (src["speaker"], src["split"]) for src in m["sources"]}
    assert split_of["Take1"] == ("Take1_raw", "test") and split_of["take1"] == ("take1_raw", "train")


# 7. malformed align metadata


@pytest.mark.parametrize(
    "field, value",
    [("flags", "low_confidence"), ("parent", {"id": 5}), ("parent", 7)],
)
def test_malformed_align_metadata_is_a_one_line_error(root, field, value):
    folder = root / f"malformed_{field}_{type(value).__name__}"
    take = make_aligned_take("odd", 1.0, seed=4)
    take.meta.extra["align"][field] = value
    write_take(take, folder)
    proc = run_here("dataset", "build", folder, "-o", root / "ds_malformed", "--skip-flagged", *QUICK)
    _refused(proc, str(folder / "odd" / "meta.json"), f"malformed metadata: extra.align.{field} must be")


# 8. a sample is at least one frame


def test_max_sample_s_below_one_frame_is_refused_naming_the_fps(takes, root):
    proc = run_here("dataset", "build", takes, "-o", root / "ds_tiny", "--max-sample-s", "0.001", *QUICK)
    _refused(proc, "--max-sample-s 0.001 is shorter than one frame at 60 fps")
