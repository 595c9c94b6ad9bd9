"""Review of align reading a raw take's audio from its file block by block (``align.recorded``): a take
whose audio.wav is no regular file (a named pipe) gets the whole read's one-line error instead of
waiting forever, a take of more than 64 channels (``MAX_AUDIO_CHANNELS``) that is silent or holds
nothing but timecode gets the same verdict as when its audio is read whole, and a file rewritten in
place between the passes through it is an error, not one result made of two recordings."""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from align import AlignOptions, align_folder, align_with_report
from align.recorded import RecordedAudio
from capture import Audio, InputError, read_livelink_csv, read_take, write_take
from capture.take import AudioInfo

OPTIONS = AlignOptions(vad="webrtc")


def _raw_take(samples: Path, root: Path, name: str, audio: Audio) -> Path:
    """The real NeuroSync take's frames with ``audio``, written as a raw take folder."""
    take = read_livelink_csv(samples / "paired" / "neurosync-trainer-lite-testset" / "testset.csv")
    take.meta.id = name
    take.attach_audio(audio, 0.0, "paired_frame_convention")
    return write_take(take, root)


@pytest.mark.skipif(sys.platform == "win32", reason="named pipes are POSIX")
def test_audio_that_is_a_named_pipe_is_an_error_not_a_hang(samples, tmp_path):
    folder = _raw_take(samples, tmp_path, "pipe", Audio(np.zeros((16000, 1), np.int16), 16000, "PCM_16"))
    fifo = folder / "audio.wav"
    fifo.unlink()
    os.mkfifo(fifo)
    got: dict = {}
    worker = threading.Thread(target=lambda: got.update(align_folder(folder, tmp_path / "out", OPTIONS)))
    worker.start()
    worker.join(10)
    hung = worker.is_alive()
    if hung:  # a writer opening the pipe and closing it lets the stuck open return
        with open(fifo, "wb"):
            pass
        worker.join(30)
    assert not hung, "align waited on the named pipe"
    assert "not a regular file" in got["error"]


def test_silent_take_of_many_channels_says_silent(samples, tmp_path):
    audio = Audio(np.zeros((16000, 65), np.int16), 16000, "PCM_16")
    folder = _raw_take(samples, tmp_path, "many", audio)
    with pytest.raises(InputError) as whole:
        align_with_report(read_take(folder), OPTIONS)
    report = align_folder(folder, tmp_path / "out", OPTIONS)
    assert "silent" in str(whole.value)
    assert report["error"] == str(whole.value)


def test_audio_rewritten_in_place_while_aligned_is_an_error(tmp_path):
    """The passes through a take's audio file (channel levels, then the mix, then clipping) must read one
    recording: a file an editor saves over (same size, other samples) during a pass makes that pass an
    error, not a result deciding on one recording and mixing another."""
    first = np.zeros((40000, 2), np.int16)
    first[:, 0] = 1000
    second = first[:, ::-1].copy()  # the loud channel is now the other one
    path = tmp_path / "audio.wav"
    sf.write(path, first, 16000, subtype="PCM_16")
    sf.write(tmp_path / "other.wav", second, 16000, subtype="PCM_16")
    info = AudioInfo("audio.wav", 16000, 2, 40000, "PCM_16")
    held = RecordedAudio.from_take_file(path, info)
    assert held is not None
    try:
        assert sum(int(b[:, 0].sum()) for b in held.blocks(8192)) == 40000 * 1000  # unchanged: no error
        passing = held.blocks(8192)
        next(passing)
        before = os.stat(path)
        with open(path, "r+b") as f:  # in place: the open file sees the new samples
            f.write((tmp_path / "other.wav").read_bytes())
        # a later mtime whatever the file system's clock granularity
        os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns + 10**9))
        with pytest.raises(InputError, match="changed while it was read"):
            for _ in passing:
                pass
    finally:
        held.close()
