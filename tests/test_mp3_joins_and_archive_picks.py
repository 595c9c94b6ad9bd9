"""Found by review: an MP3 whose Info frame undercounts its frames is no join, and is read whole (libsndfile
stopped at the count); archive members named in another case or Unicode form, and a forked child's
clean-up, in s2a-view's picks."""

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


def ffmpeg_decoded(path: Path) -> np.ndarray:
    """What FFmpeg decodes from ``path``: its encoder delay and padding dropped (its LAME tag)."""
    with av.open(str(path)) as container:
        return np.concatenate([f.to_ndarray().T for f in container.decode(audio=0)])


def test_an_mp3_whose_info_frame_undercounts_its_frames_is_read_whole_not_split(tmp_path):
    # a file edited after encoding declares one or more frames fewer than it holds: the frames past the
    # count continue its bit reservoir, they are no file of their own (split there, the part after was
    # decoded without the bytes its first frame's sound begins in: a click of 0.3 full scale). libsndfile
    # stopped at the count: the last 1152 samples lost per frame uncounted (2304 of 57330 for 2)
    right = lame_mp3(tmp_path / "a.mp3")
    data = right.read_bytes()
    whole = ffmpeg_decoded(right)  # the same file with its right count
    assert len(whole) == len(sf.read(str(right))[0]) == 57330
    # the last frame alone past the count, before an ID3v1 tag: the file's too
    id3v1 = b"TAG" + bytes(125)
    for delta, tail in ((-1, b""), (-1, id3v1), (-2, b""), (-3, b""), (-20, id3v1)):
        path = tmp_path / f"count{delta}.mp3"
        path.write_bytes(with_frame_count(data, delta) + tail)
        runs = mpeg_runs(path.read_bytes())
        assert len(runs) == 1 and runs[0].count_low
        audio = read_audio(path, repairs := [])
        assert np.array_equal(audio.samples, whole) and repairs == []


def test_an_mp3_whose_info_frame_counts_right_reads_as_libsndfile_does(tmp_path):
    # its count met, a whole frame more is not there: nothing corrected, read as libsndfile reads it
    path = lame_mp3(tmp_path / "a.mp3", seconds=0.7)
    for tail in (b"", b"TAG" + bytes(125)):
        path.write_bytes(path.read_bytes() + tail)
        assert [run.count_low for run in mpeg_runs(path.read_bytes())] == [False]
        expected, _ = sf.read(str(path), dtype="float32", always_2d=True)
        assert np.array_equal(read_audio(path).samples, expected)


def as_vbri(data: bytes, count: int) -> bytes:
    """``data`` whose Info frame is made a VBRI frame (Fraunhofer's) declaring ``count`` frames."""
    _mpeg_frame_table()
    pos = _tag_bytes(data, 0)
    frame = _mpeg_frame(data, pos)
    assert frame is not None
    # version 1, delay 0, quality 75, the bytes and frames, then an empty table of contents
    fields = [(1, 2), (0, 2), (75, 2), (len(data) - pos, 4), (count, 4), (0, 2), (1, 2), (2, 2), (0, 2)]
    body = b"VBRI" + b"".join(value.to_bytes(size, "big") for value, size in fields)
    head = bytes(36) + body + bytes(frame[0] - 40 - len(body))
    return data[: pos + 4] + head + data[pos + frame[0] :]


def test_an_mp3_whose_vbri_frame_undercounts_its_frames_reads_as_libsndfile_does(tmp_path):
    # libsndfile reads past a VBRI frame's count to the last frame: nothing lost, nothing to correct
    data = lame_mp3(tmp_path / "a.mp3", seconds=0.7).read_bytes()
    count = _file_header_frames(data, _tag_bytes(data, 0), _mpeg_frame(data, _tag_bytes(data, 0)))
    right = tmp_path / "right.mp3"
    right.write_bytes(as_vbri(data, count))
    expected, _ = sf.read(str(right), dtype="float32", always_2d=True)
    path = tmp_path / "undercount.mp3"
    path.write_bytes(as_vbri(data, count - 2))
    assert [run.count_low for run in mpeg_runs(path.read_bytes())] == [False]
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
