"""The CSVs of a calibrated take given loose (``X_cal.csv``, ``X_raw.csv``, ``X_neutral.csv`` copied without
the take's ``.mov`` and ``take.json``) are imported as its take folder imports them: one take, of the cal CSV
unless ``--variant`` picks another, with ``X_neutral.csv`` as its neutral pose, never a take of its own
(they were three takes, the still face among them, and no neutral pose was kept). And align's warning for a
speech match outside ``--max-offset-ms`` says when that match is itself weak (another take's audio) rather
than only to widen the search."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import soundfile as sf
from conftest import run_here
from test_take_folder import make_take_folder, speech_like

from capture import read_take

PREFIX = "MySlate_166_iPhone"


def loose_copy(folder: Path, to: Path, prefix: str = PREFIX) -> Path:
    """The three CSVs of a calibrated take folder, copied alone into ``to`` (named for ``prefix``)."""
    to.mkdir(parents=True, exist_ok=True)
    for variant in ("cal", "raw", "neutral"):
        shutil.copy(folder / f"{PREFIX}_{variant}.csv", to / f"{prefix}_{variant}.csv")
    return to


def ids(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.is_dir())


def test_loose_csvs_of_a_calibrated_take_are_one_take_with_its_neutral_pose(tmp_path, samples):
    phone = make_take_folder(tmp_path / "phone", samples)
    loose = loose_copy(phone, tmp_path / "loose")
    loose_copy(phone, loose, "MySlate_167_iPhone")  # a second take's trio beside the first
    run_here("capture", "import", phone, "-o", tmp_path / "by_folder", check=True)
    proc = run_here("capture", "import", loose, "-o", tmp_path / "by_csvs", check=True)
    assert ids(tmp_path / "by_csvs") == ["MySlate_166_iPhone_cal", "MySlate_167_iPhone_cal"]
    for prefix in (PREFIX, "MySlate_167_iPhone"):
        assert (
            f"{prefix}_raw.csv: the raw CSV of its take, {prefix}_cal.csv read instead: skipped"
            in proc.stderr
        )
    (folder_take,) = [read_take(p) for p in (tmp_path / "by_folder").iterdir()]
    take = read_take(tmp_path / "by_csvs" / "MySlate_166_iPhone_cal")
    np.testing.assert_array_equal(take.values, folder_take.values)
    assert take.neutral is not None
    np.testing.assert_array_equal(take.neutral, folder_take.neutral)
    assert {"blendshapes_csv", "neutral_csv"} <= {s.role for s in take.meta.sources}

    # named one by one (a shell's *.csv), with --variant raw: the raw CSV, with the same neutral pose
    named = sorted(loose.glob(f"{PREFIX}_*.csv"))
    proc = run_here("capture", "import", *named, "-o", tmp_path / "raw", "--variant", "raw", check=True)
    assert ids(tmp_path / "raw") == ["MySlate_166_iPhone_raw"]
    assert "MySlate_166_iPhone_cal.csv: the cal CSV of its take, not --variant raw: skipped" in proc.stderr
    raw = read_take(tmp_path / "raw" / "MySlate_166_iPhone_raw")
    assert np.all(raw.channel("jawOpen") == 0.5)  # make_take_folder's raw CSV
    np.testing.assert_array_equal(raw.neutral, folder_take.neutral)


def test_loose_csvs_with_audio_are_the_one_source_audio_pairs_with(tmp_path, samples):
    loose = loose_copy(make_take_folder(tmp_path / "phone", samples), tmp_path / "loose")
    sf.write(tmp_path / "voice.wav", speech_like(16000, 2.0), 16000, subtype="PCM_16")
    named = sorted(loose.glob("*.csv"))
    # was: "--audio pairs with one source, but 3 were found"
    run_here(
        "capture", "import", *named, "--audio", tmp_path / "voice.wav", "-o", tmp_path / "out", check=True
    )
    take = read_take(tmp_path / "out" / "MySlate_166_iPhone_cal")
    assert take.audio is not None and take.neutral is not None


def test_a_lone_neutral_csv_imports_when_named_and_is_skipped_in_a_folder(tmp_path, samples):
    loose = loose_copy(make_take_folder(tmp_path / "phone", samples), tmp_path / "loose")
    (loose / f"{PREFIX}_cal.csv").unlink()
    (loose / f"{PREFIX}_raw.csv").unlink()
    neutral = loose / f"{PREFIX}_neutral.csv"
    # asked for by name: read as a take (its three still frames), as before
    proc = run_here("capture", "import", neutral, "-o", tmp_path / "named", "--json", check=True)
    assert [json.loads(line)["frames"] for line in proc.stdout.splitlines()] == [3]
    # found in a folder beside another take's CSV: no take of its own, said so
    shutil.copy(samples / "livelinkface/alexdjulin_S07/S07-001.csv", loose)
    proc = run_here("capture", "import", loose, "-o", tmp_path / "found", check=True)
    assert ids(tmp_path / "found") == ["S07-001"]
    assert f"{PREFIX}_neutral.csv: the neutral pose of a calibrated take (a still face)" in proc.stderr


def test_a_weak_match_outside_the_range_says_to_check_the_audio(tmp_path, samples):
    """The real calibrated take paired with another recording's speech (the NeuroSync test set's): the
    best match lies outside ±500 ms at confidence 0.12 (under --min-confidence 0.3): no far offset to widen
    the range for, but audio that is not this take's."""
    csv = samples / "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"
    wrong = samples / "paired/neurosync-trainer-lite-testset/audio.wav"
    run_here("capture", "import", csv, "--audio", wrong, "-o", tmp_path / "takes", check=True)
    proc = run_here("align", tmp_path / "takes", "-o", tmp_path / "aligned", "--json", "--vad", "none")
    report = json.loads(proc.stdout.splitlines()[-1])
    (content,) = [e for e in report["alternatives"] if e["source"] == "content"]
    assert content["detail"]["outside_confidence"] < 0.3 and "low_confidence" in report["flags"]
    (warning,) = [w for w in report["warnings"] if "outside the" in w]
    strength = f"{content['detail']['outside_confidence']:.2f}"
    weak = (
        f"could not confirm the offset, and that match is weak (confidence {strength}): check that the audio"
    )
    assert f"{weak} is this take's, or align again with --max-offset-ms" in warning
    assert "if the audio really started" not in warning


def test_a_credible_match_outside_the_range_still_says_to_widen_it(tmp_path, samples):
    """The NeuroSync take with its own speech 0.8 s late (silence before it): the match outside ±500 ms
    is credible, and the warning is as before."""
    folder = samples / "paired/neurosync-trainer-lite-testset"
    audio, rate = sf.read(folder / "audio.wav", dtype="int16")
    sf.write(tmp_path / "late.wav", np.concatenate([np.zeros(int(0.8 * rate), audio.dtype), audio]), rate)
    run_here(
        "capture", "import", folder / "testset.csv", "--audio", tmp_path / "late.wav", "-o", tmp_path / "t"
    )
    proc = run_here("align", tmp_path / "t", "-o", tmp_path / "aligned", "--json", "--vad", "none")
    report = json.loads(proc.stdout.splitlines()[-1])
    (content,) = [e for e in report["alternatives"] if e["source"] == "content"]
    assert content["detail"]["outside_confidence"] >= 0.3, content["detail"]
    (warning,) = [w for w in report["warnings"] if "outside the" in w]
    assert "could not confirm the offset; if the audio really started that far apart from the face" in warning
    assert "weak" not in warning
