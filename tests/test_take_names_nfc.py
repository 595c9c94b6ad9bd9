"""The files of one take whose names are spelled in two Unicode normalisations (a take copied from a Mac,
whose HFS+ writes names decomposed, NFD, beside files named on Linux, NFC: ``Café_3``) pair as that
take's, in take folders, flat folders of takes and the viewer's archives; and the viewer unpacks a zipped
take's ``.wav`` only when its ``.mov`` holds no audio track, the only case its reader reads it."""

from __future__ import annotations

import os
import unicodedata
import zipfile
from pathlib import Path

import numpy as np
import pytest

from capture import Audio, read_audio, write_reference_mov
from capture.importer import find_sources
from capture.take import safe_id
from capture.take_folder import read_take_folder, reads_as_take, takes_side_by_side
from viewer.inputs import archives_unpacked, read_input

NFC = unicodedata.normalize("NFC", "Café_3")
NFD = unicodedata.normalize("NFD", "Café_3")
CSV = "livelinkface/neurosync_MySlate_166/MySlate_166_iPhone_cal.csv"
RATE = 16000


def write_csv(samples: Path, path: Path, rows: int = 90) -> Path:
    """The first ``rows`` rows of a real Live Link Face CSV."""
    lines = (samples / CSV).read_text().splitlines(keepends=True)
    path.write_text("".join(lines[: rows + 1]))
    return path


def tone(hz: float, seconds: float = 0.5) -> Audio:
    t = np.arange(int(RATE * seconds)) / RATE
    return Audio((8000 * np.sin(2 * np.pi * hz * t)).astype(np.int16)[:, None], RATE, "PCM_16")


def write_mov(path: Path, audio: Audio | None) -> Path:
    """A tiny ``.mov`` as the app writes it (two video frames, timecode), with ``audio`` or without any."""
    return write_reference_mov(path, 60, 2, audio, timecode="19:18:11:10", size=(16, 16))


def write_wav(path: Path, audio: Audio) -> Path:
    import soundfile

    soundfile.write(path, audio.samples, audio.sample_rate, subtype="PCM_16")
    return path


def names_on_disk(folder: Path) -> set[str]:
    return set(os.listdir(folder))


def test_takes_side_by_side_pair_names_of_both_spellings(samples, tmp_path):
    """A flat folder of two takes: Café_3's CSVs named on Linux (NFC) and on a Mac (NFD), its .mov and
    neutral pose from a Mac: one take, read with its .mov's audio and its neutral pose, its files' names
    recorded as found."""
    flat = tmp_path / "flat"
    flat.mkdir()
    write_csv(samples, flat / f"{NFC}_cal.csv")
    write_csv(samples, flat / f"{NFD}_raw.csv")
    write_csv(samples, flat / f"{NFD}_neutral.csv", rows=3)
    write_mov(flat / f"{NFD}.mov", tone(440))
    write_csv(samples, flat / "Take_2.csv")
    write_mov(flat / "Take_2.mov", tone(660))
    assert {f"{NFC}_cal.csv", f"{NFD}_raw.csv", f"{NFD}.mov"} <= names_on_disk(flat)  # two spellings

    assert takes_side_by_side(flat) == [flat / f"{NFC}_cal.csv", flat / "Take_2.csv"]
    assert takes_side_by_side(flat, "raw") == [flat / f"{NFD}_raw.csv", flat / "Take_2.csv"]
    assert find_sources([flat]) == [flat / f"{NFC}_cal.csv", flat / "Take_2.csv"]  # what import reads
    assert reads_as_take(flat / f"{NFC}_cal.csv")

    take = read_take_folder(flat, csv=flat / f"{NFC}_cal.csv")
    assert take.audio is not None and take.meta.audio.start_source == "mov_timecode"
    np.testing.assert_array_equal(take.audio.samples, tone(440).samples)  # its own .mov's, not Take_2's
    assert take.neutral is not None
    roles = {s.role: Path(s.path).name for s in take.meta.sources}
    assert roles["reference_video"] == f"{NFD}.mov" and roles["neutral_csv"] == f"{NFD}_neutral.csv"
    assert take.meta.extra["reference_video"] == f"{NFD}.mov"  # as found, not renormalised


def test_a_take_folder_finds_its_csv_and_mov_across_spellings(samples, tmp_path):
    """A take folder from a Mac (its folder and .mov named NFD) holding its CSV re-downloaded on Linux
    (NFC) and the copy a second download left, and a second .mov that sorts first: the CSV named after
    the take is read, with the audio of the .mov named as it."""
    folder = tmp_path / f"20241204_{NFD}"
    folder.mkdir()
    write_csv(samples, folder / f"{NFC}.csv")
    write_csv(samples, folder / f"{NFC} (1).csv", rows=40)
    write_mov(folder / f"{NFD}.mov", tone(440))
    write_mov(folder / "B-roll.mov", tone(660))
    take = read_take_folder(folder)
    assert take.values.shape[0] == 90  # the take's CSV, not the copy
    np.testing.assert_array_equal(take.audio.samples, tone(440).samples)
    assert take.meta.extra["reference_video"] == f"{NFD}.mov"
    assert take.meta.id == safe_id(folder.name)

    # take.json's identifier, written NFC, names the CSV a Mac wrote NFD among two
    other = tmp_path / "take"
    other.mkdir()
    write_csv(samples, other / f"{NFD}.csv")
    write_csv(samples, other / "Other.csv", rows=40)
    write_mov(other / "clip.mov", tone(440))
    (other / "take.json").write_text(f'{{"identifier": "{NFC}"}}', encoding="utf-8")
    assert read_take_folder(other).values.shape[0] == 90


def zip_folder(folder: Path, archive: Path, inside: str = "") -> Path:
    """``folder``'s files zipped (under ``inside/`` when given), their names as found on disk."""
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.iterdir()):
            z.write(p, f"{inside}/{p.name}" if inside else p.name)
    return archive


def unpacked(tmp: Path) -> tuple[list[str], int]:
    """The files unpacked into ``tmp`` (names) and the bytes written."""
    files = [p for p in tmp.rglob("*") if p.is_file()]
    return sorted(p.name for p in files), sum(p.stat().st_size for p in files)


def assert_same_view(got, want) -> None:
    """``read_input``'s take, warnings and speech file: the same frames, speech and clock."""
    (a, a_warnings, a_speech), (b, b_warnings, b_speech) = got, want
    assert np.array_equal(a.values, b.values, equal_nan=True) and np.array_equal(a.time, b.time)
    assert a.audio is not None and b.audio is not None
    np.testing.assert_array_equal(a.audio.samples, b.audio.samples)
    assert (
        a.meta.audio.start_s == b.meta.audio.start_s
        and a.meta.audio.start_source == b.meta.audio.start_source
    )
    assert a_speech.name == b_speech.name and len(a_warnings) == len(b_warnings)


def test_a_zipped_csv_of_a_flat_folder_finds_its_mov_across_spellings(samples, tmp_path, unpack_tmp):
    flat = tmp_path / "export"
    flat.mkdir()
    write_csv(samples, flat / f"{NFC}.csv")
    write_mov(flat / f"{NFD}.mov", tone(440))
    write_csv(samples, flat / "Take_2.csv")
    write_mov(flat / "Take_2.mov", tone(660))
    archive = zip_folder(flat, tmp_path / "export.zip")
    want = read_input(flat / f"{NFC}.csv", "one")
    with archives_unpacked():
        got = read_input(archive / f"{NFC}.csv", "one")
        files, written = unpacked(unpack_tmp)
        assert_same_view(got, want)
    assert files == sorted([f"{NFC}.csv", f"{NFD}.mov"])  # not the other take's .mov
    assert written == (flat / f"{NFC}.csv").stat().st_size + (flat / f"{NFD}.mov").stat().st_size
    assert want[2] == flat / f"{NFD}.mov"  # its .mov's audio, not read alone and silent
    np.testing.assert_array_equal(got[0].audio.samples, tone(440).samples)
    assert unpacked(unpack_tmp) == ([], 0)


@pytest.mark.parametrize("mov_audio", [True, False], ids=["mov_with_audio", "silent_mov"])
def test_a_zipped_take_unpacks_its_wav_only_when_its_mov_holds_no_audio(
    samples, tmp_path, unpack_tmp, mov_audio
):
    """A take folder zipped with its .mov and a .wav (speech recorded apart, as large as a take's audio):
    the .wav is unpacked only where the take reader reads it, the .mov holding no audio track; the take
    is shown as from the folder unzipped, whether the archive, its folder or its CSV is named."""
    folder = tmp_path / "T"
    folder.mkdir()
    write_csv(samples, folder / "T.csv")
    write_mov(folder / "T.mov", tone(440) if mov_audio else None)
    write_wav(folder / "T.wav", tone(660, seconds=2.0))
    archive = zip_folder(folder, tmp_path / "take.zip", inside="T")
    sizes = {p.name: p.stat().st_size for p in folder.iterdir()}
    needed = ["T.csv", "T.mov"] if mov_audio else ["T.csv", "T.mov", "T.wav"]
    want = read_input(folder, "one")
    assert want[2].name == ("T.mov" if mov_audio else "T.wav")
    for named in (archive, archive / "T", archive / "T" / "T.csv"):
        with archives_unpacked():  # a WAV's samples are read from its file: compared while it is there
            got = read_input(named, "one")
            files, written = unpacked(unpack_tmp)
            assert_same_view(got, want)
            speech = tone(440) if mov_audio else read_audio(folder / "T.wav")
            np.testing.assert_array_equal(got[0].audio.samples, speech.samples)
        assert files == needed, named
        assert written == sum(sizes[n] for n in needed)
        assert got[2] == archive / "T" / want[2].name  # named as the member
    assert unpacked(unpack_tmp) == ([], 0)
