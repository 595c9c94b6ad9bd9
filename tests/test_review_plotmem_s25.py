"""Second review of ``s2a-view plot`` in bounded memory (the audio left in its file): a file rewritten
while it is plotted is said to be so, not taken for a detector that cannot run; ``align.recorded.recorded``
reads audio left in its file a block at a time."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf

from align.recorded import recorded
from capture import InputError, read_audio
from capture.audio_io import audio_left_in_files
from viewer.plot import speech_segments
from viewer.render import load_animation

PAIR = "paired/neurosync-trainer-lite-testset"


def _speech(samples, tmp_path):
    """The real speech as int16 (its samples, its rate) and a copy of it in ``tmp_path``."""
    speech, rate = sf.read(samples / PAIR / "audio.wav", dtype="int16")
    wav = tmp_path / "speech.wav"
    sf.write(wav, speech, rate)
    return speech, rate, wav


@pytest.mark.parametrize("method", ["webrtc", "silero"])
def test_audio_rewritten_while_plotted_is_said_to_have_changed(samples, tmp_path, method):
    """The plot's speech left in its file, then rewritten (same length, other samples) before the
    detector's passes read it: the error says the file changed. It said "--vad webrtc is not available
    here: ..." (the detector was fine)."""
    speech, rate, wav = _speech(samples, tmp_path)
    with audio_left_in_files():
        anim = load_animation(samples / PAIR / "testset.csv", wav, clamp=False)
    sf.write(wav, speech[::-1].copy(), rate)
    with pytest.raises(InputError) as caught:
        speech_segments(anim, method)
    message = str(caught.value)
    assert "changed since it was read" in message
    assert "not available" not in message


@pytest.mark.parametrize("method", ["webrtc", "silero"])
def test_audio_too_slow_for_speech_is_still_a_detector_that_cannot_run(tmp_path, samples, method):
    """4 kHz speech: --vad webrtc/silero cannot run on it (said so), --vad auto falls back to the energy
    threshold, as before (a guard: the rate is now checked before the audio is read)."""
    speech, rate, _ = _speech(samples, tmp_path)
    wav = tmp_path / "4k.wav"
    sf.write(wav, speech[::11], 4000)
    with audio_left_in_files():
        anim = load_animation(samples / PAIR / "testset.csv", wav, clamp=False)
    with pytest.raises(InputError, match=f"--vad {method} is not available here: .*too low for speech"):
        speech_segments(anim, method)
    segs, label = speech_segments(anim, "auto")
    assert label == "loud (energy threshold, fallback: no VAD model)" and segs


def test_recorded_reads_audio_left_in_its_file_a_block_at_a_time(samples, tmp_path):
    """``recorded`` of audio left in its file gives its samples block by block, never reading it whole
    (``_recorded`` in align.resample did; ``recorded`` itself read it all and kept it)."""
    speech, rate, wav = _speech(samples, tmp_path)
    with audio_left_in_files():
        left = read_audio(wav)
    blocks = list(recorded(left).blocks(10_000))
    assert max(len(b) for b in blocks) == 10_000
    np.testing.assert_array_equal(np.concatenate(blocks)[:, 0], speech)
    assert not left.held
