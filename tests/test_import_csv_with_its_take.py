"""A Live Link Face CSV named alone is imported with its take's audio: the take folder's own CSV as the
folder, and the takes of a flat folder (each take's ``X.csv`` and ``X.mov`` gathered into one) each
with its own .mov's audio, placed by the .mov's timecode."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli

from capture import Take, read_take


@pytest.fixture(scope="module")
def two_takes(tmp_path_factory) -> list[Path]:
    """Two simulated take folders (take.json, frame_log.csv, .mov with audio, CSV), 2 s at 16 kHz."""
    root = tmp_path_factory.mktemp("sim")
    run_cli(
        "capture", "simulate", "-o", root, "--takes", 2, "--seconds", 2, "--mov", "--sample-rate", 16000,
        check=True,
    )  # fmt: skip
    return sorted(p for p in root.iterdir() if p.is_dir())


def the_csv(folder: Path) -> Path:
    (csv,) = [p for p in folder.glob("*.csv") if p.name != "frame_log.csv"]
    return csv


def imported(out: Path) -> dict[str, Take]:
    """The takes written to ``out``, by their ids (a take folder's name, a CSV's stem)."""
    return {folder.name: read_take(folder) for folder in sorted(p for p in out.iterdir() if p.is_dir())}


def assert_same_take(a: Take, b: Take) -> None:
    """Same frames, same audio samples, on the same clock."""
    np.testing.assert_array_equal(a.values, b.values)
    assert a.audio is not None and b.audio is not None
    np.testing.assert_array_equal(a.audio.samples, b.audio.samples)
    assert a.audio.sample_rate == b.audio.sample_rate
    assert a.meta.audio.start_s == pytest.approx(b.meta.audio.start_s, abs=1e-9)
    assert a.meta.audio.start_source == b.meta.audio.start_source


def test_take_folder_csv_named_alone_is_its_folder(two_takes, tmp_path):
    folder = two_takes[0]
    run_cli("capture", "import", folder, "-o", tmp_path / "by_folder", check=True)
    proc = run_cli("capture", "import", the_csv(folder), "-o", tmp_path / "by_csv", check=True)
    assert "0 repairs" in proc.stderr  # nothing to say: the folder's own take, read as the folder reads it
    (by_folder,) = imported(tmp_path / "by_folder").values()
    (by_csv,) = imported(tmp_path / "by_csv").values()
    assert by_csv.meta.audio.start_source == "frame_log_audio"  # the folder's timing, not the CSV's first row
    assert by_csv.meta.id == by_folder.meta.id
    assert_same_take(by_csv, by_folder)


def test_flat_folder_of_two_takes_imports_each_with_its_mov(two_takes, tmp_path):
    flat, originals = tmp_path / "gathered", tmp_path / "originals"
    flat.mkdir()
    for folder in two_takes:
        csv = the_csv(folder)
        shutil.copy2(csv, flat / csv.name)
        shutil.copy2(csv.with_suffix(".mov"), flat / csv.with_suffix(".mov").name)
        # the same take folder without frame_log.csv: its .mov's timecode places the audio, as it must in
        # the flat folder (whose app files would be nobody's in particular)
        shutil.copytree(folder, originals / folder.name, ignore=shutil.ignore_patterns("frame_log.csv"))
    run_cli("capture", "import", flat, "-o", tmp_path / "flat_out", check=True)
    run_cli("capture", "import", originals, "-o", tmp_path / "orig_out", check=True)
    flat_takes = imported(tmp_path / "flat_out")
    orig_takes = imported(tmp_path / "orig_out")
    assert len(flat_takes) == 2
    for folder in two_takes:
        by_csv = flat_takes[the_csv(folder).stem]
        assert by_csv.meta.audio.start_source == "mov_timecode"
        assert_same_take(by_csv, orig_takes[folder.name])
    # each take its own audio
    first, second = flat_takes.values()
    assert not np.array_equal(first.audio.samples[:1000], second.audio.samples[:1000])


def test_csv_without_a_mov_of_its_take_is_read_alone(two_takes, tmp_path):
    alone = tmp_path / "alone"
    alone.mkdir()
    csv = shutil.copy2(the_csv(two_takes[0]), alone)
    proc = run_cli("capture", "import", csv, "-o", tmp_path / "out", check=True)
    assert "0 repairs" in proc.stderr
    (take,) = imported(tmp_path / "out").values()
    assert take.audio is None and take.meta.audio is None
    assert take.meta.source_kind != "livelink_take_folder"


def test_a_flat_folder_gives_one_csv_per_take_of_the_variant_asked(two_takes, tmp_path):
    """A calibrated take's cal and raw CSVs are one performance: of a folder of such takes side by side,
    each take's cal CSV is imported (as its take folder would choose), or its raw one with --variant raw,
    never both (two takes of one performance would sit in a dataset's training and test splits)."""
    from capture.take_folder import takes_side_by_side

    flat = tmp_path / "flat"
    flat.mkdir()
    for folder in two_takes:
        csv = the_csv(folder)
        for variant in ("cal", "raw", "neutral"):
            shutil.copy(csv, flat / f"{csv.stem}_{variant}.csv")
        shutil.copy(csv.with_suffix(".mov"), flat / f"{csv.stem}.mov")
    stems = [the_csv(folder).stem for folder in two_takes]
    assert [p.name for p in takes_side_by_side(flat)] == [f"{s}_cal.csv" for s in stems]
    assert [p.name for p in takes_side_by_side(flat, "raw")] == [f"{s}_raw.csv" for s in stems]
    proc = run_cli("capture", "import", flat, "-o", tmp_path / "out", "--variant", "raw", check=True)
    assert sorted(imported(tmp_path / "out")) == sorted(f"{s}_raw" for s in stems), proc.stderr
