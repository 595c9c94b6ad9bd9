"""Review of the .mp3 damage change: the frame scan reads the file a block at a time, not mapped (a file
another program cuts short while it is mapped killed the process with SIGBUS: no message, nothing kept),
a Xing/Info frame count far beyond the frames there (2**32 - 1) is read, not a MemoryError, and a damaged
file filled with silent frames declares its new byte count (FFmpeg kept its padding: samples too many,
the note saying its count was exact)."""

from __future__ import annotations

import numpy as np
from conftest import run_python
from test_audio_mp3_later_parts import mp3_bytes
from test_import_mp3_damage import _damaged, _lag, _mp3, _speech_like, _write

from capture import read_audio
from capture.audio_io import _mpeg_frame, _xing_at, mpeg_runs


def test_an_mp3_cut_short_by_another_program_while_scanned_is_an_error_not_a_crash(tmp_path):
    """The file is opened for the scan, then cut to 1000 bytes (another program writing it) before the
    scan reads on: a one-line ``InputError`` saying so, in a process that lives on (mapped: SIGBUS)."""
    path = _write(tmp_path / "growing.mp3", _mp3(44100, 1, 128000, True))
    code = (
        "import os, sys\nfrom pathlib import Path\nimport capture.audio_io as aio\n"
        "path = Path(sys.argv[1])\nopened = getattr(aio, '_FileBytes', None) or aio._MappedFile\n"
        "with opened.of(path) as data:\n    os.truncate(path, 1000)\n"
        "    try:\n        aio.mpeg_runs(data)\n    except aio.InputError as exc:\n        print(exc)\n"
    )
    proc = run_python(code, str(path))
    assert proc.returncode == 0, proc.returncode  # -7: SIGBUS
    assert "got shorter while it was read" in proc.stdout and "another program" in proc.stdout


def test_an_mp3_whose_frame_count_is_2_to_the_32_is_read_on_time(tmp_path):
    """An Info frame declaring 2**32 - 1 frames (3 s held): libsndfile's read asked for a 9 TiB array
    (MemoryError); FFmpeg decodes the frames there, the same samples, its padding kept (under a frame)."""
    data = _mp3(44100, 1, 128000, True)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).samples
    (run,) = mpeg_runs(data)
    at = _xing_at(data, run.start, _mpeg_frame(data, run.start)) + 8
    assert data[at - 8 : at - 4] == b"Info" and data[at - 1] & 1  # its frame count follows
    wrong = data[:at] + (2**32 - 1).to_bytes(4, "big") + data[at + 4 :]
    got = read_audio(_write(tmp_path / "count.mp3", wrong), []).samples
    assert len(whole) <= len(got) < len(whole) + 1152
    assert np.abs(got[: len(whole)] - whole).max() < 1e-5


def test_a_damaged_mp3_filled_with_frames_of_its_header_s_size_keeps_its_length(tmp_path):
    """1 s at 32 kbit/s (104-byte frames, its Info frame 182 bytes): the 6 frames lost at 600 damaged bytes
    (627 to the next frame) are filled with silent frames of the Info frame's size, 1092 bytes: 4827 bytes
    where its Info frame declares 4362, over 1/16 more, so FFmpeg trimmed none of its padding (875 samples
    more, the note saying the count was exact). Its declared byte count follows the fill: the whole
    file's length, on time."""
    data = mp3_bytes(_speech_like(1.0, 44100), 44100, 1, 32000)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    got = read_audio(_write(tmp_path / "damaged.mp3", _damaged(data, (0.4, 600))), repairs).mono_float()
    assert len(got) == len(whole)
    assert _lag(whole, got, 30000, 4096, 3000) == 0
    (note,) = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    assert "6 frame(s) lost" in note and "shifted" not in note


def test_a_layer_ii_header_in_damaged_bytes_is_damage_not_a_file_of_another_rate(tmp_path):
    """A frame header of layer II at 32 kHz written over one of a 22.05 kHz layer III file (damage): with
    no frame of its format after it, it is stray bytes, its frame filled with silence (it was taken for a
    file of another layer joined on: the file refused, its sample rate "changing" to 32000 Hz)."""
    data = _mp3(22050, 1, 64000, True)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    (run,) = mpeg_runs(data)
    pos = run.start
    while pos < len(data) // 2:
        pos += _mpeg_frame(data, pos)[0]
    damaged = data[:pos] + b"\xff\xfd\x88\xc0" + data[pos + 4 :]  # 128 kbit/s, 32 kHz, mono: 576 bytes
    repairs: list = []
    got = read_audio(_write(tmp_path / "damaged.mp3", damaged), repairs).mono_float()
    assert len(got) == len(whole) and _lag(whole, got, len(whole) * 3 // 4, 2048, 2000) == 0
    assert any("1 frame(s) lost" in r["message"] for r in repairs if r["kind"] == "bad_audio")


def test_damage_with_a_lone_header_of_another_format_in_it_is_filled_once(tmp_path):
    """A frame of a 22.05 kHz file without a frame count overwritten by zeros and, 12 bytes before the
    last frame, a 320 kbit/s 32 kHz stereo header (a 1440-byte frame past the end of the file): the scan
    resyncs at that header, finds it stray, and resyncs on to the last frame; one damage of one frame
    (noted twice, from the same start: 2 frames filled, the last frame 26 ms late)."""
    data = _mp3(22050, 1, 64000, False)
    (run,) = mpeg_runs(data)
    frames = [run.start]
    while frames[-1] + _mpeg_frame(data, frames[-1])[0] < run.end:
        frames.append(frames[-1] + _mpeg_frame(data, frames[-1])[0])
    lost, last = frames[-3], frames[-2]
    damaged = data[:lost] + bytes(last - lost - 8) + b"\xff\xfb\xe8\x00" + bytes(4) + data[last:]
    (loss,) = mpeg_runs(damaged)[0].losses
    assert (loss.start, loss.end, loss.frames) == (lost, last, 1)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), [])
    assert read_audio(_write(tmp_path / "damaged.mp3", damaged), []).frames == whole.frames
