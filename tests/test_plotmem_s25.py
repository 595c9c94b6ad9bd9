"""``s2a-view plot`` of long recordings in bounded memory: the audio is left in its file and read a block at
a time, align's 16 kHz audio is made a block at a time (``to_16k_passes``: the zero-phase rumble filter's
backward pass run over each block and a margin after it) and fed to the detectors so. Before, a 2 h take
at 48 kHz peaked at 1.3 GB (``--vad webrtc``) and 1.6 GB (silero), now at 230 and 470 MB; the figure is
the same."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import soundfile as sf
from conftest import run_python

from align.resample import (
    _CHUNK,
    RUMBLE_MARGIN,
    remove_rumble,
    rumble_removed,
    to_16k_mono,
    to_16k_passes,
)
from align.vad import in_blocks, speech_level_dbfs, speech_segments, vad_gain
from capture import read_audio
from capture.audio_io import audio_left_in_files

PAIR = "paired/neurosync-trainer-lite-testset"


def _joined(blocks) -> np.ndarray:
    return np.concatenate([np.zeros(0, np.float32), *blocks])


@pytest.mark.parametrize(
    "n", [0, 1, 63, 64, 65, 5000, _CHUNK, _CHUNK + RUMBLE_MARGIN, _CHUNK + RUMBLE_MARGIN + 1, 3 * _CHUNK + 77]
)
def test_the_rumble_filter_block_by_block_is_the_whole_arrays(n):
    """Noise on a DC offset and a low hum, cut into blocks of several lengths: the samples of the
    whole-array filter to float precision, the last block and its margin exactly, one block of output
    at a time."""
    rng = np.random.default_rng(n)
    t = np.arange(n) / 16000
    x = (0.1 * rng.standard_normal(n) + 0.3 + 0.2 * np.sin(2 * np.pi * 8 * t)).astype(np.float32)
    whole = remove_rumble(x)
    for size in (7 if n < 10_000 else 4093, 1000, 100_003, _CHUNK):
        out = list(rumble_removed(in_blocks(x, size)))
        assert all(b.size == _CHUNK for b in out[:-1]), [b.size for b in out]
        got = _joined(out)
        assert got.dtype == np.float32 and got.size == n
        np.testing.assert_allclose(got, whole, rtol=0, atol=1e-7)
        tail = (n - 1) // _CHUNK * _CHUNK if n > _CHUNK + RUMBLE_MARGIN else 0
        np.testing.assert_array_equal(got[tail:], whole[tail:])


def _stereo(samples, tmp_path):
    """The real speech as a stereo 48 kHz WAV (a channel at -3 dB, a DC offset), 100 s long."""
    speech, _ = sf.read(samples / PAIR / "audio.wav", dtype="float32")
    left = np.resize(speech, 100 * 48000)
    both = np.stack([left, left * 0.7 + 0.01], axis=1)
    path = tmp_path / "stereo.wav"
    sf.write(path, (both * 32767).astype(np.int16), 48000, subtype="PCM_16")
    return path


@pytest.mark.parametrize("which", ["speech", "stereo", "16k"])
def test_align_audio_block_by_block_is_to_16k_mono(samples, tmp_path, which):
    """The 16 kHz audio given in passes of blocks, read from the file left unread: to_16k_mono's samples to
    float precision, the same speech level, gain and speech segments."""
    if which == "speech":
        path = samples / PAIR / "audio.wav"
    elif which == "stereo":
        path = _stereo(samples, tmp_path)
    else:
        path = tmp_path / "16k.wav"
        sf.write(path, np.resize(sf.read(samples / PAIR / "audio.wav")[0], 16000 * 33 + 5), 16000)
    whole = to_16k_mono(read_audio(path))
    with audio_left_in_files():
        left = read_audio(path)
    passes = to_16k_passes(left)
    got = _joined(passes())
    assert got.size == whole.size
    np.testing.assert_allclose(got, whole, rtol=0, atol=1e-6)
    assert speech_level_dbfs(passes()) == speech_level_dbfs(whole)
    gain = vad_gain(passes())
    assert gain == vad_gain(whole)
    assert speech_segments(passes(), "webrtc", gain) == speech_segments(whole, "webrtc")
    assert speech_segments(passes(), "none", gain) == speech_segments(whole, "none")
    assert not left.held  # never read whole


def test_quiet_audio_given_in_blocks_is_raised_as_the_whole_array(samples):
    """Speech 50 dB down, in blocks that do not fall on the detectors' blocks: the level, the gain and the
    segments of both detectors are those of the array."""
    x = np.resize(to_16k_mono(read_audio(samples / PAIR / "audio.wav")), 3 * 512 * 512 + 1234)
    x *= np.float32(10 ** (-50 / 20))
    gain = vad_gain(in_blocks(x, 99_991))
    assert gain == vad_gain(x) > 1
    for method in ("webrtc", "silero"):
        assert speech_segments(in_blocks(x, 99_991), method, gain) == speech_segments(x, method)


def _tiled(samples, tmp_path, minutes: int) -> str:
    """The real speech tiled to ``minutes`` at 22.05 kHz int16."""
    speech, _ = sf.read(samples / PAIR / "audio.wav", dtype="int16")
    path = tmp_path / f"{minutes}min.wav"
    with sf.SoundFile(path, "w", 22050, 1, "PCM_16") as f:
        n = minutes * 60 * 22050
        for lo in range(0, n, speech.size):
            f.write(speech[: min(speech.size, n - lo)])
    return str(path)


# A fresh launcher (a few MB) runs the command and prints its child's peak resident memory, in kB.
CHILD_PEAK = (
    "import resource, subprocess, sys\n"
    "proc = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
    "assert proc.returncode == 0, proc.stderr\n"
    "print(proc.stdout.strip().replace(chr(10), ' '))\n"
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
)


def _plot(samples, wav: str, out, vad_method: str) -> tuple[dict, int]:
    """``s2a-view plot`` of the real CSV with ``wav`` as its speech: its JSON summary and peak RSS (kB)."""
    cmd = [sys.executable, "-m", "viewer", "plot", str(samples / PAIR / "testset.csv"), "--audio", wav]
    proc = run_python(CHILD_PEAK, *cmd, "-o", str(out), "--vad", vad_method, "--json", timeout=600)
    assert proc.returncode == 0, proc.stderr
    summary, peak = proc.stdout.strip().splitlines()
    return json.loads(summary), int(peak)


def test_a_long_plots_memory_does_not_grow_with_the_recording(samples, tmp_path):
    """10 and 40 min of speech at 22.05 kHz, ``--vad webrtc``: the whole-array code held the recorded
    samples, their float copy and the 16 kHz audio (+188 MB for the 30 min more); now a few blocks
    (+2 MB). The 30 min more hold 79 MB of int16 samples: the bound is a third of that."""
    peaks = {}
    for minutes in (10, 40):
        wav = _tiled(samples, tmp_path, minutes)
        summary, peaks[minutes] = _plot(samples, wav, tmp_path / f"{minutes}.png", "webrtc")
        assert summary["duration_s"] > minutes * 60 - 1
        assert summary["speech_segments"]
    more_kb = 30 * 60 * 22050 * 2 // 1024
    assert peaks[40] - peaks[10] < more_kb / 3, f"+{(peaks[40] - peaks[10]) // 1024} MB for 30 min more"


@pytest.mark.parametrize("method", ["webrtc", "silero"])
def test_the_plots_segments_are_the_whole_audios(samples, tmp_path, method):
    """The segments a plot draws are the detector's on the whole 16 kHz array (the code before)."""
    wav = _tiled(samples, tmp_path, 1)
    summary, _ = _plot(samples, wav, tmp_path / "plot.png", method)
    whole = speech_segments(to_16k_mono(read_audio(wav)), method)
    assert summary["speech_segments"] == [[round(a, 4), round(b, 4)] for a, b in whole]
    assert summary["vad"] == f"speech ({method} VAD)"
