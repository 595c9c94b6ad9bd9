"""Found by review: an MP3 whose Info frame undercounts its frames is no join; archive members named in
another case or Unicode form, and a forked child's clean-up, in s2a-view's picks."""

from __future__ import annotations

import subprocess
import sys
import unicodedata
import zipfile
from pathlib import Path

import av
import numpy as np
import soundfile as sf
from conftest import ROOT

from capture import read_audio
from capture.audio_io import _file_header_frames, _mpeg_frame, _mpeg_frame_table, _tag_bytes, mpeg_runs
from viewer.inputs import archives_unpacked, unpacked_input

RATE = 44100


def lame_mp3(path: Path, seconds: float = 1.3) -> Path:
    """A stereo tone encoded by LAME (through FFmpeg): ID3v2 tag, Info frame with its frame count."""
    with av.open(str(path), "w", format="mp3") as container:
        stream = container.add_stream("libmp3lame", rate=RATE, layout="stereo")
        t = np.arange(int(RATE * seconds)) / RATE
        tone = (0.3 * np.sin(2 * np.pi * 440 * t)).astype(np.float32)
        frame = av.AudioFrame.from_ndarray(np.tile(tone, (2, 1)), format="fltp", layout="stereo")
        frame.sample_rate = RATE
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return path


def with_frame_count(data: bytes, delta: int) -> bytes:
    """``data`` with the frame count its Info frame declares changed by ``delta``."""
    _mpeg_frame_table()
    pos = _tag_bytes(data, 0)
    frame = _mpeg_frame(data, pos)
    assert frame is not None
    count = _file_header_frames(data, pos, frame)
    assert count > 0
    at = pos + frame[5][data[pos + 3] >= 0xC0] + 8
    return data[:at] + (count + delta).to_bytes(4, "big") + data[at + 4 :]


def test_an_mp3_whose_info_frame_undercounts_its_frames_reads_as_before_not_split(tmp_path):
    # a file edited after encoding declares two or three frames fewer than it holds: the frames past
    # the count continue its bit reservoir, they are no file of their own; split there, the part after
    # was decoded without the bytes its first frame's sound begins in (a click of 0.3 full scale)
    data = lame_mp3(tmp_path / "a.mp3").read_bytes()
    for delta in (-2, -3):
        path = tmp_path / f"count{delta}.mp3"
        path.write_bytes(with_frame_count(data, delta))
        assert len(mpeg_runs(path.read_bytes())) == 1
        expected, _ = sf.read(str(path), dtype="float32", always_2d=True)
        assert np.array_equal(read_audio(path).samples, expected)


def test_a_member_named_in_another_case_or_unicode_form_is_the_archives_own(tmp_path):
    # Finder writes names decomposed (NFD), a shell types them composed; macOS's file system took either
    # spelling (and either case) when the whole archive was unpacked: the pick must find the member too
    decomposed = unicodedata.normalize("NFD", "Café")
    archive = tmp_path / "takes.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr(f"{decomposed}/T.csv", "a\n")
        zf.writestr(f"{decomposed}/T.wav", "b")
        zf.writestr("Other/O.csv", "c\n")
    for typed in ("Café/T.csv", "café/t.CSV"):
        with archives_unpacked():
            place = unpacked_input(archive / typed)
            assert place is not None
            target, _ = place
            assert target.is_file() and target.name == "T.csv"
            assert (target.parent / "T.wav").is_file()  # its audio beside it, unpacked with it
            assert not (target.parent.parent / "Other").exists()


FORKED = """
import os, sys
from pathlib import Path
from viewer.inputs import archives_unpacked, unpacked_input
with archives_unpacked():
    target, _ = unpacked_input(Path(sys.argv[1]))
    child = os.fork()
    if child == 0:
        sys.exit(0)  # a child ending normally runs the interpreter's atexit handlers
    os.waitpid(child, 0)
    print(target.is_file())
"""


def test_a_forked_child_ending_leaves_its_parents_unpacked_files(tmp_path):
    archive = tmp_path / "takes.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr("T/T.csv", "a\n")
    done = subprocess.run(
        [sys.executable, "-c", FORKED, str(archive / "T" / "T.csv")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"
