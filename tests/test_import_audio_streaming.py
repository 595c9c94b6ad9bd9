"""``s2a-capture import`` copies a take's recorded audio (a WAV, FLAC, ... that libsndfile reads to its end)
into the take's audio.wav a block at a time, checked a block at a time as it was read, instead of holding
it whole (317 MB for an hour at 44.1 kHz int16 mono). Each test imports real speech (the NeuroSync test
set's) and compares the take folder with the one the whole-array way writes (``read_csv_with_audio``
called directly: ``read_audio`` outside an import), to the byte. Only the import command leaves audio in
its files (``audio_left_in_files``): ``import_source`` called by other code holds it as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from test_long_take_memory import _traced_peak

from capture import InputError, audio_io, read_audio, write_take
from capture.importer import import_source
from capture.take_folder import read_csv_with_audio

TESTSET = Path("paired") / "neurosync-trainer-lite-testset"


@pytest.fixture(scope="module")
def speech(samples) -> np.ndarray:
    """The test set's speech as recorded: 44.1 kHz int16 mono, 20 s."""
    return read_audio(samples / TESTSET / "audio.wav").samples


def _csv_of(samples: Path, folder: Path, seconds: int) -> Path:
    """The test set's CSV rows repeated for ``seconds`` at 60 fps, timecodes running on."""
    lines = (samples / TESTSET / "testset.csv").read_text().splitlines()
    rows = [line.split(",", 1)[1] for line in lines[1:]]
    out = [lines[0]]
    for i in range(seconds * 60):
        s = 10 * 3600 + i // 60
        out.append(f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}:{i % 60:02d}.000,{rows[i % len(rows)]}")
    path = folder / "take.csv"
    path.write_text("\n".join(out) + "\n")
    return path


def _imported(*args):
    """``import_source`` as ``s2a-capture import`` calls it: recorded audio left in its file."""
    with audio_io.audio_left_in_files():
        return import_source(*args)


def _same_folders(new: Path, whole: Path) -> None:
    for name in ("audio.wav", "meta.json", "frames.npz"):
        assert (new / name).read_bytes() == (whole / name).read_bytes(), name


def test_import_never_holds_the_recorded_audio_whole(samples, speech, tmp_path):
    """Two minutes of int16 speech (10 MB) with a CSV as long: the whole-array import held the samples
    from the read to the end of the write; now a block of them, and the take folder is the same."""
    csv = _csv_of(samples, tmp_path, 120)
    wav = tmp_path / "speech.wav"
    sf.write(wav, np.tile(speech, (6, 1))[: 120 * 44100], 44100, subtype="PCM_16")
    recorded_bytes = 120 * 44100 * 2
    write_take(_imported(csv, wav), tmp_path / "first")  # what a first import loads once is no sample
    whole, whole_peak = _traced_peak(lambda: write_take(read_csv_with_audio(csv, wav), tmp_path / "whole"))
    new, peak = _traced_peak(lambda: write_take(_imported(csv, wav), tmp_path / "new"))
    assert peak < whole_peak - 0.8 * recorded_bytes, (
        f"traced peak {peak / 2**20:.1f} MB, whole {whole_peak / 2**20:.1f} MB, "
        f"recorded audio {recorded_bytes / 2**20:.1f} MB"
    )
    _same_folders(new, whole)


def _stereo(speech: np.ndarray) -> np.ndarray:
    """Two channels of float speech in [-1, 1): as recorded, and reversed 6 dB down."""
    x = speech.astype(np.float32) / 32768
    return np.hstack([x, x[::-1] * 0.5])


def _cut(path: Path, share: float) -> Path:
    """``path`` cut to ``share`` of its bytes (an odd count: a partial sample at the end), as a copy."""
    data = path.read_bytes()
    cut = path.with_name("cut-" + path.name)
    cut.write_bytes(data[: int(len(data) * share) | 1])
    return cut


def _nan(x: np.ndarray) -> np.ndarray:
    x = x.copy()
    x[1000, 0], x[5000:5010, 1], x[70_000, 0] = np.nan, np.inf, -np.inf
    return x


def _spike(x: np.ndarray) -> np.ndarray:
    x = x.copy()
    x[30_000, 0] = 40.0  # a damaged sample: repaired on the whole channel, read whole as before
    return x


CASES = {
    # name: (samples of the speech, rate, subtype, format, cut to this share of the bytes, left in the file)
    "int16 mono 44.1 kHz": (lambda s: s, 44100, "PCM_16", "WAV", None, True),
    "int24 stereo 48 kHz": (_stereo, 48000, "PCM_24", "WAV", None, True),
    "float stereo 16 kHz, NaN and inf": (lambda s: _nan(_stereo(s)), 16000, "FLOAT", "WAV", None, True),
    "int16 mono cut short": (lambda s: s, 22050, "PCM_16", "WAV", 0.6, True),
    "float stereo cut short": (_stereo, 48000, "FLOAT", "WAV", 0.45, True),
    "flac stereo 24-bit": (_stereo, 44100, "PCM_24", "FLAC", None, True),
    "float past full scale": (lambda s: _spike(_stereo(s)), 44100, "FLOAT", "WAV", None, True),
}


@pytest.mark.parametrize("case", CASES)
def test_import_writes_the_take_of_the_whole_array_way(samples, speech, tmp_path, case):
    """Mono and stereo, 16/24-bit and float, 16-48 kHz, WAVs cut short (repair ``truncated_audio``), NaN
    and infinite samples (set to 0: repair ``bad_audio``): the same audio.wav and meta.json, to the byte.
    A file whose float samples go past full scale stays in its file too (its damaged samples are found
    in passes over it); the samples of audio left in its file read on demand are those read whole."""
    make, rate, subtype, fmt, cut, left = CASES[case]
    audio = tmp_path / f"speech.{fmt.lower()}"
    sf.write(audio, make(speech)[: 3 * 44100], rate, subtype=subtype, format=fmt)
    if cut is not None:
        audio = _cut(audio, cut)
    csv = samples / TESTSET / "testset.csv"
    take = _imported(csv, audio)
    assert isinstance(take.audio, audio_io.FileAudio) == left
    whole = read_csv_with_audio(csv, audio)
    _same_folders(write_take(take, tmp_path / "new"), write_take(whole, tmp_path / "whole"))
    assert take.audio.samples.tobytes() == whole.audio.samples.tobytes()


def test_audio_changed_before_the_take_is_written_is_an_error(samples, speech, tmp_path):
    """Audio left in its file is the file as it was checked: replaced or removed before the take is
    written, the write is one clear error, and no take folder is left."""
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, 44100, subtype="PCM_16")
    csv = samples / TESTSET / "testset.csv"
    take = _imported(csv, wav)
    sf.write(wav, speech[::-1], 44100, subtype="PCM_16")
    with pytest.raises(InputError, match="changed since it was read"):
        write_take(take, tmp_path / "out")
    take = _imported(csv, wav)
    wav.unlink()
    with pytest.raises(InputError, match="cannot be read again"):
        write_take(take, tmp_path / "out")
    assert not list((tmp_path / "out").iterdir())
