"""Memory of import and align on long takes: ``s2a-align`` reads a raw take's recorded audio from its file
a block at a time (``align.recorded.RecordedAudio``) for the 16 kHz copy and the clipping check, instead of
holding all of it (317 MB for an hour at 44.1 kHz int16 mono, 635 MB stereo) through the alignment; a
take's float audio is checked for NaN a block at a time. Each test compares the traced peak of the new
way with the whole-array way on the real NeuroSync take, and the results to the bit."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import parselmouth  # noqa: F401  imported before any peak is traced: a module's objects are no samples
import pytest
import scipy.signal  # noqa: F401
import soundfile as sf
import soxr  # noqa: F401
from test_long_take_memory import _traced_peak

from align import AlignOptions, align_folder, align_with_report
from align.clipping import clipped_share
from align.recorded import RecordedAudio
from align.resample import TARGET_RATE, remove_rumble, to_16k_mono
from capture import Audio, InputError, Take, read_audio, read_livelink_csv, read_meta, read_take, write_take
from capture.take import AudioInfo, TakeMeta

OPTIONS = AlignOptions(vad="webrtc")


@pytest.fixture(scope="module")
def raw_takes(samples, tmp_path_factory) -> dict[str, Path]:
    """The real NeuroSync take (44.1 kHz int16 speech, frame i <-> audio i/60 s) written as raw take
    folders: mono as recorded, and stereo (a second microphone 3 dB down)."""
    pair = samples / "paired" / "neurosync-trainer-lite-testset"
    root = tmp_path_factory.mktemp("raw")
    speech = read_audio(pair / "audio.wav")
    second = np.round(speech.samples * 0.7).astype(np.int16)
    folders = {}
    for name, audio in (
        ("mono", speech),
        ("stereo", Audio(np.hstack([speech.samples, second]), speech.sample_rate, "PCM_16")),
    ):
        take = read_livelink_csv(pair / "testset.csv")
        take.meta.id = name
        take.attach_audio(audio, 0.0, "paired_frame_convention")
        folders[name] = write_take(take, root)
    return folders


def _same_segments(folder: Path, out: Path, report: dict) -> None:
    """The aligned takes ``align_folder`` wrote are those of aligning the take read whole, to the bit."""
    segments, whole_report = align_with_report(read_take(folder), OPTIONS)
    assert report["offset_s"] == whole_report["offset_s"] and report["flags"] == whole_report["flags"]
    assert report["clipped_audio"] == whole_report["clipped_audio"]
    assert len(report["outputs"]) == len(segments) > 0
    for path, seg in zip(map(Path, report["outputs"]), segments):
        got = read_take(path)
        assert got.audio.samples.tobytes() == seg.audio.samples.tobytes()
        assert np.array_equal(got.values, seg.values, equal_nan=True) and np.array_equal(got.time, seg.time)


@pytest.mark.parametrize("name", ["mono", "stereo"])
def test_align_never_holds_the_recorded_audio_whole(raw_takes, tmp_path, name):
    """The take read whole held its recorded samples from the start to the end of the alignment, at
    every peak; read from the file, mono is never whole in memory at its rate, and several channels
    only while they are mixed (before the alignment's own peaks): the peak is lower by about the
    recorded samples' size, the aligned takes the same."""
    folder = raw_takes[name]
    recorded_bytes = read_audio(folder / "audio.wav").samples.nbytes
    _, whole_peak = _traced_peak(lambda: align_with_report(read_take(folder), OPTIONS))
    report, peak = _traced_peak(align_folder, folder, tmp_path, OPTIONS, force=True)
    assert "error" not in report, report
    assert peak < whole_peak - 0.7 * recorded_bytes, (
        f"traced peak {peak / 2**20:.1f} MB, whole {whole_peak / 2**20:.1f} MB, "
        f"recorded audio {recorded_bytes / 2**20:.1f} MB"
    )
    _same_segments(folder, tmp_path, report)


def test_clipping_and_mix_read_from_the_file_match_the_whole(raw_takes, tmp_path):
    """Clipped runs across a block's end counted from the file's blocks are those of the samples in
    memory, and the 16 kHz mix of two channels made from them is the whole-array mix's, to the bit, with
    a few blocks in memory at a time. A file cut while it is read is one clear error; a float file
    holding NaN is left to ``read_take``, which refuses it by name as it did."""
    x = np.tile(read_audio(raw_takes["stereo"] / "audio.wav").samples, (6, 1))  # two minutes
    edge = 1 << 18  # the blocks' end
    x[edge - 2 : edge + 2, 0] = x[:, 0].max()
    x[5000:5004, 1] = x[:, 1].min()
    audio = Audio(x, 44100, "PCM_16")
    folder = write_take(_take_of("clipped", audio), tmp_path)
    file = RecordedAudio.from_take_file(folder / "audio.wav", read_meta(folder).audio)
    assert file is not None
    try:
        share, peak = _traced_peak(clipped_share, file)
        assert share == clipped_share(audio) > 0
        assert peak < x.nbytes / 2, f"traced peak {peak / 2**20:.1f} MB for {x.nbytes / 2**20:.1f} MB"
        # the channels measured and mixed block by block: the whole-array mix held a float32 copy of
        # each channel and of the mix (104 MB traced here, besides the 21 MB of samples)
        y, peak = _traced_peak(to_16k_mono, file)
        assert peak < 2 * x.nbytes, f"traced peak {peak / 2**20:.1f} MB for {x.nbytes / 2**20:.1f} MB"
        f = x.astype(np.float32) / 32768
        mix = f[:, 0].copy()
        mix += f[:, 1]
        mix /= 2
        mix -= np.float32(np.sum(mix, dtype=np.float64) / mix.size)
        assert y.tobytes() == remove_rumble(soxr.resample(mix, 44100, TARGET_RATE, quality="VHQ")).tobytes()
    finally:
        file.close()
    file = RecordedAudio.from_take_file(folder / "audio.wav", read_meta(folder).audio)
    assert file is not None
    os.truncate(folder / "audio.wav", (folder / "audio.wav").stat().st_size // 2)  # cut while it is open
    with pytest.raises(InputError, match="ends after .* of its 5391360 samples"):
        clipped_share(file)
    file.close()
    bad = np.zeros((44100, 2), np.float32)
    bad[100] = np.nan
    sf.write(folder / "audio.wav", bad, 44100, subtype="FLOAT")
    info = AudioInfo("audio.wav", 44100, 2, 44100, "FLOAT")
    assert RecordedAudio.from_take_file(folder / "audio.wav", info) is None


def _take_of(name: str, audio: Audio) -> Take:
    """A take of one tracked frame a second carrying ``audio``."""
    n = max(2, int(audio.duration_s))
    meta = TakeMeta(id=name, source_kind="test", fps=1.0, channels=["JawOpen"])
    take = Take(meta, np.arange(n, dtype=np.float64), np.zeros((n, 1), np.float32), np.zeros(n, np.uint8))
    take.attach_audio(audio)
    return take


def test_float_audio_is_checked_for_nan_a_block_at_a_time():
    """A take's float samples were checked with a boolean mask of all of them (58 MB for an hour
    of 16 kHz audio, on each segment align writes): now a block's, and NaN is still refused."""
    x = np.random.default_rng(0).normal(0, 0.1, 2 * 60 * 16000).astype(np.float32)
    take, peak = _traced_peak(_take_of, "f", Audio(x, 16000, "FLOAT"))
    assert peak < x.nbytes / 8, f"traced peak {peak / 2**20:.1f} MB for {x.nbytes / 2**20:.1f} MB"
    x[x.size - 3] = np.inf
    with pytest.raises(Exception, match="1 NaN or infinite"):
        take.attach_audio(Audio(x, 16000, "FLOAT"))


def test_a_take_s_audio_is_written_without_a_copy_of_all_its_samples(tmp_path):
    """soundfile hands each buffer libsndfile writes to its file callback as a copy in bytes, and for a
    same-format write libsndfile hands over the whole array: written a block at a time, the peak of
    ``write_audio`` stays a small share of the samples (it was their size again), and the file holds them
    to the bit."""
    from capture.audio_io import write_audio

    rng = np.random.default_rng(7)
    audio = Audio(rng.standard_normal((120 * 16000, 1), dtype=np.float32) * 0.1, 16000, "FLOAT")
    _, peak = _traced_peak(write_audio, tmp_path / "audio.wav", audio)
    assert peak < audio.samples.nbytes / 4, (peak, audio.samples.nbytes)
    back, rate = sf.read(tmp_path / "audio.wav", dtype="float32", always_2d=True)
    assert rate == 16000 and np.array_equal(back, audio.samples)
