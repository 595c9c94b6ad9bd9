"""MP3 import leftovers (``capture/audio_io.py``): damage running up to the tag of a file joined on in the
middle of an .mp3 was neither noted nor filled (the later file's sound came early); an Info frame counting
too few frames went unseen in a damaged file (FFmpeg stopped at the count: the audio short, the sound after
the damage early); a file name that is not UTF-8 was shown in warnings as ``\\udcff`` escapes. Found among
unseen MP3s: a VBRI frame was decoded as a frame of silence (the sound 36 ms late at 16 kHz), and the note of
a kept encoder priming said "up to ~50 ms late" at any rate (138 ms late at 8 kHz).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from conftest import run_cli
from test_audio_mp3_later_parts import lag, mp3_bytes, with_frame_count
from test_import_decoded_streaming import TAKE_CSV
from test_import_mp3_damage import _damaged, _lag, _mp3, _speech_like, _write
from test_mp3_leftovers_s23 import _adts

from capture import read_audio
from capture.audio_io import _file_header_frames, _mpeg_frame, _silent_frame, mpeg_runs

RATE = 16000


def _comment_tag(size: int) -> bytes:
    """An ID3v2.3 tag holding one comment of ``size`` printable characters (a tagger's notes)."""
    text = bytes(np.random.default_rng(5).integers(32, 127, size, dtype=np.uint8))
    frame = b"COMM" + (size + 5).to_bytes(4, "big") + b"\0\0" + b"\0eng\0" + text
    return b"ID3\3\0\0" + bytes(len(frame) >> shift & 0x7F for shift in (21, 14, 7, 0)) + frame


def _overwritten(data: bytes, start: int, stop: int) -> bytes:
    """``data`` with random bytes written over ``data[start:stop]`` (its length kept)."""
    return (
        data[:start]
        + np.random.default_rng(1).integers(0, 256, stop - start, np.uint8).tobytes()
        + data[stop:]
    )


def _joined(xing: str, comment: int = 0) -> tuple[bytes, np.ndarray, int]:
    """Two LAME files of 2 s at 16 kHz, 32 kbit/s (144 bytes a frame), with (``xing`` "1": Info) or without a
    LAME tag, the second's ID3v2 tag FFmpeg's (45 bytes) or a tagger's (a ``comment`` of that many bytes);
    the later file's signal, and where the first ends in the joined bytes."""
    first, later = _speech_like(2.0, RATE), _speech_like(2.0, RATE)[::-1].copy()
    one = mp3_bytes(first, RATE, 1, 32000, write_xing=xing)
    two = (_comment_tag(comment) if comment else b"") + mp3_bytes(
        later, RATE, 1, 32000, write_xing=xing, **({"id3v2_version": "0"} if comment else {})
    )
    return one + two, later, len(one)


def _later_at(later: np.ndarray, audio: np.ndarray) -> int:
    """Where the later file's sound starts in ``audio`` (about 2 s in)."""
    start = 2 * RATE - 3000
    return start + lag(later[:8000], audio[start:], 6000)


# damage from 500 bytes before the first file's end to where, from the second's tag (its 4 bytes: "ID3"
# and its version), and the second's tagger's comment, bytes
CASES = {"up_to_the_tag": (0, 0), "into_its_header": (4, 0), "a_big_tags_header": (4, 3000)}


@pytest.mark.parametrize("case", list(CASES))
def test_damage_up_to_a_joined_files_tag_is_put_back_as_silence(tmp_path, case):
    """Old: damage ending at the tag left the first file's last 3 frames out unnoted (the second file's
    sound 1425 samples early, the audio as short); damage wiping a big tag's header was estimated from all
    the tag's bytes as lost frames (32 frames, 1.15 s of silence put in: the sound after it that late).
    Now: as at a file's end, the frames lost counted from the first file's Info frame, put back as silence
    since sound follows: the same length and timing as undamaged."""
    into_tag, comment = CASES[case]
    data, later, end = _joined("1", comment)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    repairs: list = []
    audio = read_audio(
        _write(tmp_path / "damaged.mp3", _overwritten(data, end - 500, end + into_tag)), repairs
    )
    (note,) = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    assert note.endswith(
        "3 frame(s) lost there (1728 samples, 108 ms), put back as silence, so the sound after it "
        "keeps its time"
    )
    assert len(audio.mono_float()) == len(whole)
    assert _later_at(later, audio.mono_float()) == _later_at(later, whole)


def test_bytes_before_a_joined_file_that_start_no_frame_are_said_when_no_count_tells(tmp_path):
    """Without a LAME tag nothing tells whether bytes before a joined file that start no frame were frames
    (damage: here 3 frames overwritten) or a tag not known here: none are put back (a tag read as 1 lost
    frame would make the sound after it 36 ms late), and a note says how many frames they could hold, so
    how early the sound after them may be. Old: nothing said. (A Lyrics3 tag there, or an APE tag without
    a header: no note, test_review_mp3_s24.)"""
    data, later, end = _joined("0")
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    data, lost = _overwritten(data, end - 500, end), 3 * 576
    repairs: list = []
    audio = read_audio(_write(tmp_path / "joined.mp3", data), repairs).mono_float()
    (note,) = [r["message"] for r in repairs if r["kind"] == "bad_audio"]
    assert "and the file joined on after it: if they were frames, up to " in note
    most = int(note.split("up to ")[1].split(" frame")[0]) * 576
    early = _later_at(later, whole) - _later_at(later, audio)
    assert early == len(whole) - len(audio) == lost <= most


@pytest.mark.parametrize("rate, bit_rate", [(16000, 32000), (44100, 128000)])
def test_an_info_frame_counting_too_few_frames_of_a_damaged_file_is_corrected(tmp_path, rate, bit_rate):
    """LAME's Info frame declaring 5 frames fewer than the file holds, the file damaged twice: the frames
    found were fewer than the count, so ``mpeg_runs`` never saw it low, and the count, near enough the
    frames damaged, was trusted: FFmpeg stopped at it (16 kHz: 2880 samples short, the sound after the
    second damage 2880 samples early, noted as at most 216 ms off). Its bytes whole at its constant bit rate
    (Info, its byte count where it ends), the frames damaged are what their bytes hold: the count is low,
    corrected; the audio of the whole's length, on time. Damage to its end, its count low: noted (before,
    2 frames lost at 16 kHz unnoted, the bytes not starting as a frame does)."""
    data = mp3_bytes(_speech_like(3.0, rate), rate, 1, bit_rate)
    whole = read_audio(_write(tmp_path / "whole.mp3", data), []).mono_float()
    start = mpeg_runs(data)[0].start
    low = with_frame_count(data, _file_header_frames(data, start, _mpeg_frame(data, start)) - 5)
    repairs: list = []
    audio = read_audio(_write(tmp_path / "low.mp3", _damaged(low, (0.3, 600), (0.7, 1500))), repairs)
    samples = audio.mono_float()
    assert len(samples) == len(whole)
    assert _lag(whole, samples, int(len(whole) * 0.85), 2048, 3000) == 0
    assert [r["kind"] for r in repairs].count("bad_audio") >= 2
    cut = int(len(low) * 0.97)
    repairs = []
    short = read_audio(_write(tmp_path / "end.mp3", _overwritten(low, cut, len(low))), repairs).mono_float()
    (note,) = [r["message"] for r in repairs if "at its end" in r["message"]]
    ms = float(note.split("ends about ")[1].split(" ms")[0])
    assert ms > 0 and abs((len(whole) - len(short)) / rate * 1000 - ms) <= 1


def test_a_name_not_utf8_is_shown_with_its_bytes_escaped(tmp_path, samples):
    """``s2a-capture import`` of a take whose audio's name is Latin-1 (bytes not UTF-8): imported as
    before, its warnings (and meta.json's repairs) naming it ``caf\\xe9 \\xff.mp3`` as Python shows bytes,
    not ``caf\\udce9 \\udcff.mp3``."""
    csv = tmp_path / "S07-001.csv"
    csv.write_text("".join((samples / TAKE_CSV).read_text().splitlines(keepends=True)[:181]))
    mp3 = _write(
        tmp_path / os.fsdecode(b"caf\xe9 \xff.mp3"), _damaged(_mp3(44100, 1, 128000, True), (0.5, 600))
    )
    proc = run_cli("capture", "import", csv, "--audio", mp3, "-o", tmp_path / "out", check=True)
    assert "caf\\xe9 \\xff.mp3: damaged MPEG audio at 1.490 s" in proc.stderr
    assert "\\udc" not in proc.stderr
    (take,) = (tmp_path / "out").iterdir()
    (note,) = [r for r in json.loads((take / "meta.json").read_text())["repairs"] if r["kind"] == "bad_audio"]
    assert note["message"].startswith("caf\\xe9 \\xff.mp3: damaged MPEG audio at 1.490 s")


def _with_vbri(data: bytes) -> bytes:
    """``data`` (LAME's frames without a tag) after a VBRI frame as Fraunhofer's encoders write first: a
    frame of no sound holding at 36 "VBRI", its version, delay, quality, byte and frame counts."""
    (run,) = mpeg_runs(data)
    frame = bytearray(_silent_frame(data, run.start))
    counts = len(data).to_bytes(4, "big") + run.frames.to_bytes(4, "big")
    header = b"VBRI" + (1).to_bytes(2, "big") + (576).to_bytes(2, "big") + (75).to_bytes(2, "big") + counts
    frame[36 : 36 + len(header)] = header
    return bytes(frame) + data


@pytest.mark.parametrize("damage", [(), ((0.5, 600),)], ids=["whole", "damaged"])
def test_a_vbri_frame_is_not_decoded_as_sound(tmp_path, damage):
    """An .mp3 whose first frame is a VBRI header: libsndfile's decoder gave it as a frame of silence (576
    samples at 16 kHz, the sound 36 ms later than FFmpeg's read of it, or of the same frames without it);
    damaged (read by FFmpeg, which skips it), the note's time counted it: 36 ms late. Now read as FFmpeg
    reads it, the note on time."""
    signal = _speech_like(3.0, RATE)
    frames = mp3_bytes(signal, RATE, 1, 32000, write_xing="0", id3v2_version="0")
    vbri = _with_vbri(frames)
    plain, with_vbri = [], []
    audio = read_audio(_write(tmp_path / "vbri.mp3", _damaged(vbri, *damage)), with_vbri).mono_float()
    start = int(len(vbri) * damage[0][0]) - len(vbri) + len(frames) if damage else 0
    bare = _overwritten(frames, start, start + 600) if damage else frames  # the same frames damaged
    expected = read_audio(_write(tmp_path / "plain.mp3", bare), plain).mono_float()
    assert len(audio) == len(expected) and lag(signal[:RATE], audio) == lag(signal[:RATE], expected)
    assert [_said(r) for r in with_vbri] == [_said(r) for r in plain]  # what, and where: the same


def _said(repair: dict) -> str:
    """A repair's message without the file's name, up to how many frames were lost (VBRI counts them)."""
    return repair["message"].split(": ", 1)[1].split(" lost there")[0]


@pytest.mark.parametrize("rate", [8000, 16000, 44100])
@pytest.mark.parametrize("codec", ["aac", "mp3"])
def test_the_unknown_delay_note_says_how_late_at_the_files_rate(tmp_path, rate, codec):
    """Raw AAC and LAME's MP3 without its tag keep their priming, noted: "may start up to ~50 ms late",
    though it is as many samples at any rate: raw AAC at 8 kHz was 128 ms late, MP3 138 ms (16 kHz: 64, 69
    ms). The note now bounds it at the file's rate (~50 ms at 44.1 kHz still)."""
    signal = _speech_like(2.0, rate)
    data = _adts(signal, rate) if codec == "aac" else mp3_bytes(signal, rate, 1, write_xing="0")
    repairs: list = []
    audio = read_audio(_write(tmp_path / f"primed.{codec}", data), repairs).mono_float()
    (note,) = [r["message"] for r in repairs if r["kind"] == "encoder_delay_unknown"]
    bound_ms = float(note.split("up to ~")[1].split(" ms")[0])
    late_ms = 1000 * lag(signal[:rate], audio, 4000) / rate
    assert 0 < late_ms <= bound_ms and (bound_ms == 50) == (rate == 44100)
