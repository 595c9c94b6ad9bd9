"""A stop (Ctrl-C, SIGTERM) met as libsndfile opens an import's scratch WAV of decoded audio: the stop was
held back until the open returned and met then, before the open file was kept, so it was never closed
with the scratch file; closed later by the garbage collector, it wrote its header into the file already
closed, printing "Exception ignored from cffi callback ... ValueError: seek of closed file" after
"s2a-capture: terminated (SIGTERM)" (a CI run of test_review_decoded_streaming)."""

from __future__ import annotations

import gc
import signal
import sys

import pytest
import soundfile as sf
from test_audio_decode_memory import _encoded

from capture import read_audio
from capture.audio_io import audio_left_in_files


class _StoppedAsOpened(sf.SoundFile):
    """A SoundFile that meets Ctrl-C while libsndfile opens it for writing."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.mode.startswith("w"):
            signal.raise_signal(signal.SIGINT)


@pytest.mark.parametrize("where", ["open", "close"])
def test_a_stop_as_the_scratch_file_opens_or_closes_leaves_nothing_open(tmp_path, monkeypatch, where):
    m4a = tmp_path / "take.m4a"
    m4a.write_bytes(_encoded("aac", "ipod", "fltp", 2, seconds=0.3))
    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    if where == "open":
        monkeypatch.setattr(sf, "SoundFile", _StoppedAsOpened)
    else:
        real_close = sf.SoundFile.close

        def close(self):  # Ctrl-C while libsndfile writes the header of the file it closes
            was_open = not self.closed
            real_close(self)
            if was_open and self.mode.startswith("w"):
                signal.raise_signal(signal.SIGINT)

        monkeypatch.setattr(sf.SoundFile, "close", close)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    scratch = tmp_path / "out"
    scratch.mkdir()
    with pytest.raises(KeyboardInterrupt), audio_left_in_files(scratch):
        read_audio(m4a)
    gc.collect()  # while the hook still records: an open file closed by the collector writes its header now
    monkeypatch.undo()
    assert [f"{u.object}: {u.exc_value!r}" for u in unraisable] == []
    assert list(scratch.iterdir()) == []
