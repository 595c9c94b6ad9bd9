"""Review of ``s2a-capture import``'s audio left in its file (``audio_left_in_files``, ``FileAudio``): for
every format libsndfile reads the take folder is the one the whole-array way writes (``read_audio``
outside an import), to the byte; a source whose samples change between the check and the copy (also in
place, to the same size and modification time, or while it is copied) is one clear error and no take,
never other audio than the one checked; a source only touched, or replaced by a copy of the same
samples, is imported as it was."""

from __future__ import annotations

import os
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from conftest import run_here
from test_import_audio_streaming import TESTSET, _imported

from capture import InputError, audio_io, read_audio, write_take
from capture.audio_io import WRITE_FRAMES, audio_left_in_files, write_audio
from capture.take_folder import read_csv_with_audio


@pytest.fixture(scope="module")
def speech(samples) -> np.ndarray:
    """The test set's speech as recorded: 44.1 kHz int16 mono, 20 s."""
    return read_audio(samples / TESTSET / "audio.wav").samples


def _rewrite_in_place(path: Path, samples: np.ndarray) -> None:
    """Other samples written over ``path``'s own, in place: same inode, same size, and its modification
    time set back to what it was (a copy keeping times, or a rewrite within the clock's tick)."""
    st = os.stat(path)
    sf.write(path, samples, 44100, subtype="PCM_16")
    assert os.stat(path).st_size == st.st_size
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_source_rewritten_in_place_to_the_same_size_and_time_is_an_error(samples, speech, tmp_path):
    """The stamp (size, time, inode) of the file told nothing: the take was written with the new
    samples, not those checked. Now the samples' CRC-32 tells it: one error, no take folder."""
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, 44100, subtype="PCM_16")
    take = _imported(samples / TESTSET / "testset.csv", wav)
    _rewrite_in_place(wav, -speech)
    with pytest.raises(InputError, match=r"changed since it was read \(.*\): run the command again"):
        write_take(take, tmp_path / "out")
    assert not list((tmp_path / "out").iterdir())


def test_source_changed_while_it_is_copied_is_an_error(speech, tmp_path):
    """A program writing the file while the import copies it (after its first block): the copy's end
    tells it, before the write completes."""
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, 44100, subtype="PCM_16")
    with audio_left_in_files():
        audio = read_audio(wav, [])
    blocks = audio.blocks(WRITE_FRAMES)
    first = next(blocks)
    assert first.tobytes() == speech[:WRITE_FRAMES].tobytes()
    with open(wav, "r+b") as f:  # the last samples, in place: size and frames as they were
        f.seek(-1000, os.SEEK_END)
        f.write(bytes(range(200)) * 5)
    with pytest.raises(InputError, match="changed since it was read"):
        list(blocks)


def test_source_touched_or_replaced_by_the_same_samples_is_imported(samples, speech, tmp_path):
    """A sync client or backup touching the file, or replacing it with an identical copy (a new inode):
    the samples checked are those copied, so the take is written, as the whole-array way writes it
    (it was an error: the file's time or inode had changed)."""
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, 44100, subtype="PCM_16")
    csv = samples / TESTSET / "testset.csv"
    whole = write_take(read_csv_with_audio(csv, wav), tmp_path / "whole")
    touched = _imported(csv, wav)
    os.utime(wav, ns=(0, 1_600_000_000 * 10**9))
    replaced = _imported(csv, wav)
    shutil.copyfile(wav, tmp_path / "copy.wav")
    os.replace(tmp_path / "copy.wav", wav)
    for name, take in (("touched", touched), ("replaced", replaced)):
        folder = write_take(take, tmp_path / name)
        assert (folder / "audio.wav").read_bytes() == (whole / "audio.wav").read_bytes(), name


def test_source_removed_or_cut_is_one_clear_error(samples, speech, tmp_path):
    """Removed: the system's words; cut short: changed. No take folder either way."""
    csv = samples / TESTSET / "testset.csv"
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, 44100, subtype="PCM_16")
    take = _imported(csv, wav)
    wav.unlink()
    with pytest.raises(InputError, match=r"cannot be read again: No such file or directory$"):
        write_take(take, tmp_path / "out")
    sf.write(wav, speech, 44100, subtype="PCM_16")
    take = _imported(csv, wav)
    os.truncate(wav, wav.stat().st_size // 2)
    with pytest.raises(InputError, match="changed since it was read"):
        write_take(take, tmp_path / "out")
    assert not list((tmp_path / "out").iterdir())


def _riff_sized(data: bytes) -> bytes:
    return data[:4] + struct.pack("<I", len(data) - 8) + data[8:]


def _data_size(data: bytes, size: int) -> bytes:
    at = data.find(b"data")
    return data[: at + 4] + struct.pack("<I", size) + data[at + 8 :]


def _formats(speech: np.ndarray, folder: Path) -> list[Path]:
    """Real speech (70 000 frames: two blocks) in the formats and layouts an import meets."""
    x = speech[:70_000].astype(np.float32) / 32768
    many = np.hstack([x * (0.9 - 0.1 * c) for c in range(8)])
    out = []
    for name, data, rate, fmt, subtype in (
        ("u8.wav", x, 8000, "WAV", "PCM_U8"),
        ("i24.wav", np.hstack([x, -x]), 96000, "WAV", "PCM_24"),
        ("i32.wav", x, 44100, "WAV", "PCM_32"),
        ("f64.wav", x, 44100, "WAV", "DOUBLE"),
        ("ulaw.wav", x, 8000, "WAV", "ULAW"),
        ("alaw.wav", x, 8000, "WAV", "ALAW"),
        ("adpcm.wav", x, 22050, "WAV", "IMA_ADPCM"),
        ("ext.wav", many[:, :3], 48000, "WAVEX", "PCM_16"),
        ("rf64.wav", x, 44100, "RF64", "FLOAT"),
        ("w64.w64", x, 44100, "W64", "PCM_24"),
        ("s8.aiff", x, 22050, "AIFF", "PCM_S8"),
        ("f.aifc", x, 22050, "AIFF", "FLOAT"),
        ("i16.flac", x, 16000, "FLAC", "PCM_16"),
        ("i24.flac", x, 192000, "FLAC", "PCM_24"),
        ("v.ogg", x, 44100, "OGG", "VORBIS"),
        ("eight.wav", many, 48000, "WAV", "PCM_16"),
        ("one.wav", x[:1], 44100, "WAV", "PCM_16"),
    ):
        out.append(folder / name)
        sf.write(out[-1], data, rate, format=fmt, subtype=subtype)
    denormal = x.copy()
    denormal[::7] = 1e-42
    denormal[5, 0], denormal[66_000, 0] = np.nan, -np.inf
    out.append(folder / "denormal-nan.wav")
    sf.write(out[-1], denormal, 44100, subtype="FLOAT")
    wav = (folder / "eight.wav").read_bytes()
    for name, data in (
        ("list-after.wav", _riff_sized(wav + b"LIST" + struct.pack("<I", 12) + b"INFOISFT" + bytes(4))),
        ("bext-after.wav", _riff_sized(wav + b"bext" + struct.pack("<I", 602) + bytes(602))),
        ("cut-odd.wav", wav[: len(wav) // 2 + 1]),
        ("data-too-big.wav", _data_size(wav, 0xFFFFFFF0)),
        ("data-too-small.wav", _data_size(wav, 16 * 3001 + 1)),
    ):
        out.append(folder / name)
        out[-1].write_bytes(data)
    return out


def test_every_format_writes_the_audio_of_the_whole_array_way(speech, tmp_path):
    """PCM 8/24/32-bit, double, u-law/A-law, ADPCM, WAVE_FORMAT_EXTENSIBLE, RF64, W64, AIFF/AIFF-C,
    FLAC, Vorbis, 1 to 8 channels at 8-192 kHz, one frame, denormal/NaN/inf floats, chunks after the
    data, a data size past the file's end or short of it, an odd byte count: left in the file, the
    same audio.wav and repairs as read whole."""
    for path in _formats(speech, tmp_path):
        whole_repairs, left_repairs = [], []
        whole = read_audio(path, whole_repairs)
        with audio_left_in_files():
            left = read_audio(path, left_repairs)
        assert isinstance(left, audio_io.FileAudio), path.name
        write_audio(tmp_path / "whole.wav", whole)
        write_audio(tmp_path / "left.wav", left)
        assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes(), path.name
        assert left_repairs == whole_repairs, path.name


def test_import_of_one_wav_beside_two_csvs_writes_each_take_as_read_whole(samples, speech, tmp_path):
    """``--pair-audio`` with the only audio file of a folder (a name with a space and Unicode) paired
    with two CSVs: each take's audio.wav is the file's samples as read whole."""
    folder = tmp_path / "séance 1"
    folder.mkdir()
    for name in ("a.csv", "b.csv"):
        shutil.copyfile(samples / TESTSET / "testset.csv", folder / name)
    sf.write(folder / "only one.wav", speech[: 5 * 44100], 44100, subtype="PCM_16")
    run_here("capture", "import", folder, "--pair-audio", "-o", tmp_path / "out", check=True)
    write_audio(tmp_path / "whole.wav", read_audio(folder / "only one.wav"))
    for take in ("a", "b"):
        got = (tmp_path / "out" / take / "audio.wav").read_bytes()
        assert got == (tmp_path / "whole.wav").read_bytes(), take


def test_repr_of_audio_left_in_its_file_reads_no_sample(speech, tmp_path):
    """repr (a traceback's locals, a log line, a debugger) names the file: it read every sample (the
    dataclass's repr of ``samples``), and of a file removed since it was an error itself."""
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, 44100, subtype="PCM_16")
    with audio_left_in_files():
        audio = read_audio(wav, [])
    wav.unlink()
    shown = repr(audio)
    assert not audio.held
    assert "speech.wav" in shown and f"{len(speech)} frames, 1 channel(s), 44100 Hz, PCM_16" in shown


def test_audio_named_relative_to_the_working_folder_is_read_from_where_it_was(speech, tmp_path, monkeypatch):
    """A file named relative to the working folder, which a program calling the import changes before
    the take is written: the file read is the one checked (it was looked for in the new folder)."""
    (tmp_path / "rec").mkdir()
    sf.write(tmp_path / "rec" / "speech.wav", speech, 44100, subtype="PCM_16")
    monkeypatch.chdir(tmp_path / "rec")
    with audio_left_in_files():
        audio = read_audio("speech.wav", [])
    monkeypatch.chdir(tmp_path)
    write_audio(tmp_path / "left.wav", audio)
    write_audio(tmp_path / "whole.wav", read_audio(tmp_path / "rec" / "speech.wav"))
    assert (tmp_path / "left.wav").read_bytes() == (tmp_path / "whole.wav").read_bytes()
    assert str(audio.path) == "speech.wav"  # named as given


def test_file_replaced_between_its_header_and_its_check_is_read_whole(speech, tmp_path):
    """``read_audio`` reads the header (``sf.info``), then checks the samples: a file replaced between
    the two by one of another layout (stereo 48 kHz for mono 44.1 kHz) was left in its file with the
    first one's rate and channels and the second one's samples. Now it is read whole, as it is then."""
    mono, stereo = tmp_path / "mono.wav", tmp_path / "stereo.wav"
    sf.write(mono, speech[:80_000], 44100, subtype="PCM_16")
    sf.write(stereo, np.hstack([speech[:50_000], speech[:50_000]]), 48000, subtype="PCM_16")
    header = sf.info(str(stereo))
    assert audio_io._left_in_file(mono, header, "int16", "PCM_16", []) is None
    left = audio_io._left_in_file(mono, sf.info(str(mono)), "int16", "PCM_16", [])
    assert (left.frames, left.channels, left.sample_rate) == (80_000, 1, 44100)
